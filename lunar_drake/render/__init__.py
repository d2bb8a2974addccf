"""render core (no Drake)."""
