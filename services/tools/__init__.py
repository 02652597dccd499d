"""Operator's tools that look at a rig without being part of it: `nod topic`, `nod ports`."""
