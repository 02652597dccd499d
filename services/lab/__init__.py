"""Tools for running a lab's rig: `nod lab secure` (mutual TLS and access control)."""
