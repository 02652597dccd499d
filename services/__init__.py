"""nod-hri: a human-robot consensus experiment as Zenoh-distributed services."""
