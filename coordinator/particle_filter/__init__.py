"""The particle filter over the objects' unknown properties L (issues 24, 37).

One object, ``ParticleFilter``, with one update per real step (``filter``); the modules
below are its parts, each one concept:

- ``belief``: the weighted particle set over L, resampling, the symbolic match model;
- ``likelihood``: the measurement channels' robust likelihood and its constants;
- ``model_error``: the simulator's error on each channel, from centred innovations;
- ``reweighting``: one step's weighing (per block group), the kernel and the monitor;
- ``block_weights``: weights per block when L is per block;
- ``rejuvenation``: the Liu-West / regularised kernel, the lock-in monitor;
- ``resample_move``: the Metropolis-Hastings moves: over the last real steps when the
  monitor fires, and after a sharp step (``move_after_resample``);
- ``particle_budget``: KLD-sampling's count for the next action.

It imports no world and no planner: the particle worlds reach it as a callable.
"""
from __future__ import annotations

from .belief import Belief
from .filter import FilterUpdate, ParticleFilter
from .resample_move import MOVE_WINDOW, RealStep
from .reweighting import Reweighting

__all__ = ["Belief", "FilterUpdate", "MOVE_WINDOW", "ParticleFilter", "RealStep", "Reweighting"]
