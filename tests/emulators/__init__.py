"""Byte-level emulators of the rig's serial devices, each on a real pseudo-terminal."""
