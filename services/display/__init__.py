"""The participant's screen: a web page on the rig with the countdown, go and points."""
