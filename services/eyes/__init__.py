"""Eyes service: gaze cues (Section 5) to pan/tilt servo targets through servo drivers."""
