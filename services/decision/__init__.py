"""Decision service: opinion dynamics (eqs 1-2), human observer (eq 7), bias controller (eq 6)."""
