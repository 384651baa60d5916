"""The block-world toolkit of the task half: the public pieces the built-in block domains
(container, stack_and_push) plan with, so that they are siblings and neither imports the
other.

- ``model``: T and costs validated, and what each action of a trip is worth (attempts
  until success, a push repeated until it delivers), ``simulate_plan``;
- ``trips``: the clingo search over trips on a domain's encoding (integer weights,
  multi-shot horizons, the stopping rule).
"""
