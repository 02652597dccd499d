"""`nod fit`: each participant's model parameters from their trials, and a recovery study."""
