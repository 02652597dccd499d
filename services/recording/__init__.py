"""Recordings of a rig: `nod record` writes every key to MCAP, `nod replay` plays it back.

`mcap_io` is the file format (channels, schemas, metadata; a reader that also reads a file cut
short by a crash), `record` the recorder, `replay` the player and the offline re-run of the
decision model on a recording (`--through decision`).
"""
