"""The TMOC loop (Algorithm 1 of Ding et al. 2022): the session that plans, grounds, executes and learns, the
episode's accounting, the runner that drives a session against a reality, and the reality itself."""
