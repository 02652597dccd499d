"""Actuation service: Algorithm 2 behaviour and arm drivers."""
