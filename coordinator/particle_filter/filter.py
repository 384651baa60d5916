"""The particle filter over L as one object with one update: what a real step does to the
belief once the particle worlds have replayed it.

``ParticleFilter.update`` runs, in order (docs/LOOP.md, "The filter under a judge"):

1. **weigh**: the step's whole likelihood (symbolic outcome times the measurement
   channels' robust likelihood, model error included), per block group where L is per
   block (``Reweighting.weigh``);
2. **remember** the step for the resample-move window (the episode's last
   ``MOVE_WINDOW`` real steps);
3. **resample** with the Liu-West kernel where the effective sample size asks for it
   (``Reweighting.resample``);
4. **move**: one Metropolis-Hastings step per row against the window if the lock-in
   monitor or the innovation bias test asked for one (``resample_move.mh_move``;
   ``first_window_sweeps`` while the window reaches back to the prior); else,
   with ``move_after_resample`` (off by default: docs/LOOP.md), after a resample or a
   step no row explained, Gilks and Berzuini's resample-move:
   sweeps against the belief before the step times the step's likelihood
   (``resample_move.resample_move``), so that a step sharper than the particles' spacing
   leaves a set that represents the posterior, not the one or two rows that happened to
   lie near it (or, with every row beyond the outlier floor, none);
5. **resize**: the next action's particle count by KLD-sampling (``particle_budget``),
   when the run's budget is ``kld``.

The filter sees the particle worlds only as a callable (``simulate(start, rows, action,
trajectory, start_time) -> {"states", "measurements", ...}``) and the symbolic match as
another (``symbolic(step, observed, predicted_states) -> log-likelihood per row``): it
imports neither the worlds nor the planner, and the session owns neither its arithmetic.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from .belief import Belief
from .particle_budget import next_count
from .rejuvenation import rpf_bandwidth
from .resample_move import MOVE_WINDOW, KernelDensity, RealStep, mh_move, resample_move
from .reweighting import Reweighting

__all__ = ["FilterUpdate", "ParticleFilter", "Simulate", "Symbolic"]

Simulate = Callable[..., dict]
Symbolic = Callable[[RealStep, frozenset, list], np.ndarray]


@dataclass(frozen=True)
class FilterUpdate:
    """What one real step did to the belief (the session's step report reads it)."""

    ess: float                 # effective sample size after the update
    resampled: bool
    particles: int             # rows that weighed this step
    information: float         # nats the step moved the belief (``Reweighting.weigh``)
    explained: bool            # some row predicted the step (the monitor's input)
    injected: int              # rows moved (resample-move) or redrawn (recovery="prior")
    next_particles: int | None   # the KLD count for the next action (None: fixed budget)
    informative: bool          # the step carried information (the episode's counter)
    simulated: int             # particle-actions the move spent re-simulating its window

    def report(self) -> dict:
        out = {"ess": self.ess, "resampled": self.resampled, "particles": self.particles,
               "information": self.information, "explained": self.explained, "injected": self.injected}
        if self.next_particles is not None:
            out["next_particles"] = self.next_particles
        return out


class ParticleFilter:
    """The belief over L, its reweighting state and the move window (one per session)."""

    def __init__(self, belief: Belief | None, reweighting: Reweighting, config) -> None:
        self.belief = belief
        self.reweighting = reweighting
        self.config = config
        # The episode's latest real steps (the move's window); not checkpointed: emptied at
        # each episode's start, so a resumed run matches an uninterrupted one.
        self.recent: list[RealStep] = []
        # Real steps the belief absorbed before the window's first: 0 while the window
        # reaches back to the prior, where the move's target is the exact posterior.
        self.before_window = 0
        # The belief (rows, log weights) before each step of the window: the first is what
        # the move's target carries of the evidence older than the window.
        self.beliefs_before: list[tuple[np.ndarray, np.ndarray]] = []

    def start_episode(self) -> None:
        self.before_window += len(self.recent)
        self.recent, self.beliefs_before = [], []
        self.reweighting.start_episode()

    def remember(self, step: RealStep, belief_before: tuple[np.ndarray, np.ndarray] | None = None) -> None:
        """Add `step` to the move's window (the episode's last ``MOVE_WINDOW``), with the
        belief before it, counting the steps that leave it."""
        self.recent.append(step)
        self.beliefs_before.append(belief_before)
        self.before_window += max(len(self.recent) - MOVE_WINDOW, 0)
        del self.recent[:-MOVE_WINDOW]
        del self.beliefs_before[:-MOVE_WINDOW]

    @property
    def window_from_prior(self) -> bool:
        """The move's window holds every real step since the prior (the run's first
        ``MOVE_WINDOW``): uniform prior times its likelihood is then the exact posterior."""
        return self.before_window == 0

    @property
    def frozen(self) -> bool:
        """A point belief at the truth (``known_properties``): never redrawn nor resized."""
        return bool(self.config.known_properties)

    def update(self, step: RealStep, symbolic_ll: np.ndarray, simulated_measurements: np.ndarray,
               rng: np.random.Generator, simulate: Simulate, symbolic: Symbolic,
               nodes: Sequence[tuple[float, np.ndarray, np.ndarray]] | None = None) -> FilterUpdate:
        """One real step's whole update of the belief (steps 1-5 of the module's docstring).

        `symbolic_ll`: each row's log-likelihood of the observed symbolic outcome;
        `simulated_measurements`: each row's simulated measurement channels (N, C), against
        `step.measurements`. `simulate` and `symbolic` re-simulate and re-score the window
        if a move is due; `rng` is the session's seeded generator (every draw here).
        `nodes`: the worlds at each perception quadrature node, (log weight, symbolic
        log-likelihood, measurements) each (``Reweighting.weigh``); `simulate`'s result
        carries them as ``"perception"`` (log weight, result) for a move's window."""
        b, rw = self.belief, self.reweighting
        n = b.n
        before = self._density_before(step.action)
        # (kept only where the move's target reads it: a copy of the rows per step otherwise)
        prior = (b.particles.copy(), b.log_weights.copy()) if self.config.move_target == "belief" else None
        weighed = rw.weigh(b, step.action, symbolic_ll, step.measurements, simulated_measurements, nodes)
        self.remember(step, prior)
        resampled, injected = rw.resample(b, rng, step.action, rejuvenate=not self.frozen)
        moved, spent = self._move(rng, simulate, symbolic)
        if before is not None and not spent and (resampled or not weighed.explained):
            moved, spent = self._resample_move(before, step, rng, simulate, symbolic)
        next_n = None
        if self.config.particle_budget == "kld" and not self.frozen:
            next_n = self.kld_count()
            if next_n != b.n:
                rw.resample_to(b, next_n, rng)
                resampled = True
        return FilterUpdate(float(b.ess()), bool(resampled), n, weighed.information, weighed.explained,
                            injected + moved, next_n, weighed.informative, spent)

    def _density_before(self, action: str) -> tuple[np.ndarray, KernelDensity] | None:
        """The columns an action's update concerns and the belief over them before the
        update, as the kernel density resampling draws from (None: no move after
        resampling in this run)."""
        if not self.config.move_after_resample or self.frozen or self.belief.n < 2:
            return None
        b = self.belief
        log_w, dims = self.reweighting.action_view(b, action)
        floor = max(self.config.jitter_floor, 1e-6) * (b.high - b.low)[dims]
        return dims, KernelDensity.of(b.particles[:, dims], log_w, rpf_bandwidth(b.n, dims.size), floor)

    def _step_loglik(self, symbolic: Symbolic) -> Callable[[RealStep, dict], np.ndarray]:
        """A re-simulated step's log-likelihood per row, as the update weighed it."""
        def step_loglik(real: RealStep, res: dict) -> np.ndarray:
            if res.get("perception"):
                return self.reweighting.node_log_likelihood(
                    [(lw, symbolic(real, real.observed, r["states"]), r["measurements"]) for lw, r in res["perception"]],
                    real.measurements)
            sym = symbolic(real, real.observed, res["states"])
            return self.reweighting.log_likelihood(sym, real.measurements, res["measurements"])[0]
        return step_loglik

    @staticmethod
    def _counted(simulate: Simulate) -> tuple[Simulate, list[int]]:
        """`simulate`, counting the particle-actions it spends (in the list's one entry)."""
        spent = [0]

        def counted(start, rows, *args, **kwargs) -> dict:
            out = simulate(start, rows, *args, **kwargs)
            spent[0] += int(out.get("particle_actions", len(rows)))
            return out
        return counted, spent

    def _move(self, rng: np.random.Generator, simulate: Simulate, symbolic: Symbolic) -> tuple[int, int]:
        """The pending Metropolis-Hastings move, if any: (rows moved, particle-actions spent)."""
        dims = self.reweighting.pending_move
        if dims is None:
            return 0, 0
        self.reweighting.pending_move = None
        b = self.belief
        width = b.high - b.low
        scale = np.maximum(rpf_bandwidth(b.n, dims.size) * b.std()[dims],
                           max(self.config.jitter_floor, 1e-6) * width[dims])
        counted, spent = self._counted(simulate)
        # Where the target is the exact posterior the chain runs first_window_sweeps sweeps
        # (towards it: rows stranded by a run of failures reach the region the failures
        # leave); past the run's first window older evidence lives only in where the rows
        # are, so one.
        sweeps = self.config.first_window_sweeps if self.window_from_prior else 1
        rows, moved = mh_move(b.particles, dims, b.low, b.high, scale, self.recent, counted,
                              self._step_loglik(symbolic), rng, sweeps=sweeps,
                              before=self._window_prior(dims),
                              step_bound=lambda real: self.reweighting.log_likelihood_bound(real.measurements))
        b.particles = rows
        return moved, spent[0]

    def _window_prior(self, dims: np.ndarray) -> KernelDensity | None:
        """What the move's target takes for the evidence before its window: None (the
        uniform prior) while the window reaches back to it, or under ``move_target``
        "prior"; else the belief before the window's first step as a kernel density
        (docs/LOOP.md, "The move's target past the first window")."""
        if self.window_from_prior or self.config.move_target == "prior" or not self.beliefs_before \
                or self.beliefs_before[0] is None:
            return None
        rows, log_w = self.beliefs_before[0]
        floor = max(self.config.jitter_floor, 1e-6) * (self.belief.high - self.belief.low)[dims]
        return KernelDensity.of(rows[:, dims], log_w, rpf_bandwidth(len(rows), dims.size), floor)

    def _resample_move(self, before: tuple[np.ndarray, KernelDensity], step: RealStep,
                       rng: np.random.Generator, simulate: Simulate, symbolic: Symbolic) -> tuple[int, int]:
        """The move after a resample (module docstring, step 4): (rows moved, particle-actions)."""
        dims, density = before
        b = self.belief
        counted, spent = self._counted(simulate)
        rw = self.reweighting
        weighed = self.config.use_measurements and rw.channels.size > 0
        rows, accepted, _ = resample_move(b.particles, dims, b.low, b.high, density, step, counted,
                                          self._step_loglik(symbolic), rng,
                                          channels=rw.channels if weighed else None,
                                          sigma=rw.sigma() if weighed else None)
        b.particles = rows
        return accepted, spent[0]

    def kld_count(self) -> int:
        """The next action's particle count (KLD-sampling over the current posterior)."""
        c, b = self.config, self.belief
        return next_count(b.particles, b.weights, b.low, b.high, n_min=c.min_particles, n_max=c.particles,
                          bin_fraction=c.kld_bin, epsilon=c.kld_epsilon, quantile=c.kld_quantile)
