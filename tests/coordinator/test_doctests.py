"""The runnable examples in the docstrings of the small public units (belief, transition
model, the shard pool in-process), run against the installed package.

Why not ``--doctest-modules``: it collects from the source tree, which the suite refuses
(tests/conftest.py); ``doctest.testmod`` runs the imported, installed module instead.
"""
from __future__ import annotations

import doctest
import importlib

import pytest

MODULES = ("coordinator.particle_filter.belief", "coordinator.particle_filter.likelihood",
           "coordinator.particle_filter.rejuvenation",
           "coordinator.transition.transition_model", "coordinator.transition.counterfactual",
           "coordinator.distributed.fanout")


@pytest.mark.parametrize("name", MODULES)
def test_the_docstring_examples_run(name):
    module = importlib.import_module(name)
    result = doctest.testmod(module, optionflags=doctest.ELLIPSIS, verbose=False)
    assert result.attempted > 0, f"{name}: no examples found"
    assert result.failed == 0, f"{name}: {result.failed} of {result.attempted} examples failed"
