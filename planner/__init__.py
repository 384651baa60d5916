"""planner package of the TMOC service."""
