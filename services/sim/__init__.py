"""Sim service: a synthetic participant that publishes what vision would."""
