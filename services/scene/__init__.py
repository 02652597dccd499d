"""The synthetic camera: rendered frames of the rig for the sim service, vision and tests."""
