"""dynamics core (no Drake)."""
