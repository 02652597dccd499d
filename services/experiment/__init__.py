"""Experiment service: the 8-trial protocol, outcome classification, scoring and the store."""
