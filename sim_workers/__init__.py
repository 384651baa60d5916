"""sim_workers package of the TMOC service."""
