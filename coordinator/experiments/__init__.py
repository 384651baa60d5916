"""The paper's simulation experiments as one command each (`tmoc experiment NAME`).

An experiment is a list of *settings* (an agent, a particle count, a variation) times
``runs`` independent, seeded runs of ``coordinator.loop.runner.run``; the runs go out over the
Ray cluster, each finished run is written to ``DIR/runs/<setting>/<r>.json`` as it
finishes, and from the run files come ``DIR/NAME.csv``, ``DIR/NAME.json``, ``DIR/NAME.md``
and ``DIR/NAME.png``.

One module per concept:

- ``catalogue``: the experiments (``REGISTRY`` of ``ExperimentSpec``), scales, seeds,
  every run's ``RunConfig`` and cost;
- ``true_T``: T*, the true transition model estimated from probes and cached, and the
  ``Optimality`` judge of a plan's load split;
- ``runfiles``: run files, checkpoints and ``--resume``;
- ``execute``: the runs on Ray, with progress and checkpoints;
- ``analysis``: rows, convergence, the summary and its tables;
- ``tails``: a run's tails (failure loops, regret, |z|, sharpness) and their distributions;
- ``spec``: ``Setting`` and ``Spec``, what every other module passes around;
- ``reference``: the exact posterior of a recorded run, the judge;
- ``report``: the CSV, JSON, markdown and PNG files;
- ``sweep``: the learning-quality sweep's truths across the prior, judged per truth
  against its own T* (its own files: DIR/sweep.*).

Every public name is re-exported here: ``from coordinator import experiments as ex`` and
``ex.NAME`` keep working.
"""
from __future__ import annotations

from .analysis import (CONVERGENCE_BAND, convergence_episode, milestone_table, posterior_error,
                       robot_table, summarize, table_rows)
from .catalogue import (AGENTS, DEFAULT_PROBE_TRIALS, DEFAULT_SCALE, EXPERIMENT_TRUE_SIZE, EXPERIMENTS,
                        PAPER_SCALE, PARTICLE_FRACTIONS, REGISTRY, ROBOT_EPISODES, WEIGHTS_DOMAIN,
                        WEIGHTS_SIGMAS, WEIGHTS_TRUE_DENSITY, WEIGHTS_TRUE_SIZE, ExperimentSpec, Setting,
                        Spec, default_milestones, particle_counts, prior_truths, run_config, run_cost,
                        run_seed, settings_for)
from .execute import execute
from .report import CSV_COLUMNS, SYMLOG_ABOVE, SYMLOG_LINEAR, plot, summary_table, write_csv, write_outputs
from .sweep import judge_run, prior_sizes, summarize_sweep, sweep_settings, sweep_table, write_sweep
from .runfiles import (ResumeError, existing_runs, read_run, run_path, store_checkpoint, store_run,
                       write_atomic)
from .true_T import (Optimality, cached_true_T, probe_jobs, submit_probes, t_star_files,
                     t_star_params, true_transition, write_true_T)

__all__ = [
    "AGENTS", "CONVERGENCE_BAND", "CSV_COLUMNS", "DEFAULT_PROBE_TRIALS", "DEFAULT_SCALE",
    "EXPERIMENTS", "EXPERIMENT_TRUE_SIZE", "ExperimentSpec", "Optimality", "PAPER_SCALE",
    "PARTICLE_FRACTIONS", "REGISTRY", "ROBOT_EPISODES", "ResumeError", "SYMLOG_ABOVE", "SYMLOG_LINEAR",
    "Setting", "Spec", "WEIGHTS_DOMAIN", "WEIGHTS_SIGMAS", "WEIGHTS_TRUE_DENSITY", "WEIGHTS_TRUE_SIZE",
    "cached_true_T", "convergence_episode", "default_milestones", "execute", "existing_runs",
    "milestone_table", "particle_counts", "plot", "posterior_error", "probe_jobs",
    "read_run", "robot_table", "run_config", "run_cost", "run_path", "run_seed", "settings_for",
    "store_checkpoint", "store_run", "submit_probes", "summarize", "summary_table", "t_star_params",
    "table_rows", "true_transition", "write_atomic", "write_csv", "write_outputs",
    "write_true_T", "judge_run", "prior_sizes", "summarize_sweep", "sweep_settings", "sweep_table",
    "write_sweep", "t_star_files", "prior_truths",
]
