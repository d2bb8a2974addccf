"""autonomy core (no Drake)."""
