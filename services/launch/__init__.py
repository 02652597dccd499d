"""Launching a rig: the rig file, supervised service processes, `nod up`."""
