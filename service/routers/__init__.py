"""One router module per resource: maps (and their build jobs), sessions."""
