"""Monitor: a Rerun bridge for every key of a rig."""
