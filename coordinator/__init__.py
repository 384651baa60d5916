"""coordinator package of the TMOC service."""
