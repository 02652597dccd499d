"""Safety: staleness / liveliness / e-stop watchdog shared by actuation and eyes."""
