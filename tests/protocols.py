"""Short protocols in the params file's TOML, for tests that run whole sessions in seconds.

One home for each text, so that the tests of several files run the same sessions and a change
of the protocol's form is made once.
"""

from __future__ import annotations

# Two trials: one control trial, one consensus trial.
TWO_TRIALS = """
[[protocol.trials]]
index = 1
mode = "dissensus"
[[protocol.trials]]
index = 2
mode = "consensus"
option = "red"
gaze_level = "low"
"""
# Three trials (one control trial, two consensus ones): TWO_TRIALS and a consensus trial on blue.
SHORT = TWO_TRIALS + """[[protocol.trials]]
index = 3
mode = "consensus"
option = "blue"
gaze_level = "significant"
"""
