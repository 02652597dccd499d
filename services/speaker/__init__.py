"""The participant's audio cue: a tone for each countdown word and a distinct go tone."""
