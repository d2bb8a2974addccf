"""ephemeris core (no Drake)."""
