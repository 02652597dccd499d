"""Numerical analysis (Sec 4.4) and study statistics (Sec 7)."""
