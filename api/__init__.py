"""api package of the TMOC service."""
