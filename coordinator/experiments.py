"""The paper's simulation experiments as one command each (`tmoc experiment NAME`).

An experiment is a list of *settings* (an agent, a particle count, a variation) times
``runs`` independent, seeded runs of ``coordinator.runner.run``; the runs go out over the
Ray cluster, each finished run is written to ``DIR/runs/<setting>/<r>.json`` as it
finishes, and from the run files come ``DIR/NAME.csv``, ``DIR/NAME.json`` and
``DIR/NAME.png``.

How runs share the cluster's CPUs. Every run is one Ray task that reserves one CPU and
simulates its particles in-process (``ShardPool(n_shards=0)``), so as many runs go at once
as the cluster has CPUs, and no run pays Ray's fan-out round trips. Results do not depend
on where or with how many shards particles run (README, Determinism), so a run gives the
same episodes here as under ``tmoc run``. Runs are submitted most expensive first
(episodes x particles), which packs them well onto few CPUs. The cost of this choice: one
run never uses more than one CPU, so a cluster with more CPUs than ``settings x runs``
leaves some idle, and a run's wall time is its whole serial cost.

Seeds. Run r of setting k of experiment x gets
``SeedSequence(S, spawn_key=(x, k, r)).generate_state(2)`` folded into 63 bits: fixed by
(S, x, k, r) alone, so independent of how many runs go in parallel, of their order, and of
``--resume``.

Resume. A run file holds the run's full config; with ``--resume`` a file whose config is
the one asked for is reused as is (nothing finished is recomputed), one whose config
differs is refused. A long run also sends its checkpoint to the driver every
``checkpoint_s`` seconds, kept as ``<r>.partial.json``; ``--resume`` continues it from
there with the same episodes as an uninterrupted run.

T*. The *true* transition model (for "optimal plan") is estimated once from the true
world with seeded ``sim_workers.probe`` trials (believed size = true size) and cached in
``DIR/true_T.json``; see ``true_T_from_probes``.
"""
from __future__ import annotations

import csv
import io
import json
import math
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from sim_workers.properties import SIZES_VARIATION_SCALE

from .agents import AGENTS as AGENT_SPECS
from .run_config import RunConfig

# Appended, never reordered: a run's seed derives from its experiment's index here.
EXPERIMENTS = ("compare", "particles", "milestones", "sizes", "likelihood", "robot", "weights")
ROBOT_EPISODES = tuple(range(0, 37, 4))            # Table II of the paper: episodes 0, 4, ..., 36
AGENTS = tuple(AGENT_SPECS)    # the agent registry's names, in its order
PARTICLE_FRACTIONS = (0.25, 0.5, 0.75, 1.0)      # paper: N = 50, 100, 150, 200

# Paper scale (a cluster): 15 runs of 5000 episodes, N = 200.
PAPER_SCALE = {"runs": 15, "episodes": 5000, "particles": 200}

# Default scale: each finishes in under 30 minutes on 2 cores. Measured (whole command,
# 2-core machine, truth 34 mm, docs/RESULTS.md): compare 19 min 6 s (T* estimate
# included), particles 17 min 26 s, milestones 14 min 28 s, sizes 15 min 17 s,
# likelihood 14 min 57 s; weights 36 min 30 s (with tests sharing the two cores; a heavy-
# block episode replays pickups that slip and towers that fall). A TMOC episode costs about 1.8 s + 0.45 s per particle on one
# core once learned; GP ~12 s at N = 16 (more trips), TMP-RL ~2 s, TOEP ~1 s.
DEFAULT_SCALE = {
    "compare": {"runs": 3, "episodes": 30, "particles": 16},
    "particles": {"runs": 3, "episodes": 20, "particles": 24},
    "milestones": {"runs": 4, "episodes": 50, "particles": 16},
    "sizes": {"runs": 3, "episodes": 30, "particles": 16},
    "likelihood": {"runs": 3, "episodes": 30, "particles": 16},
    "robot": {"runs": 3, "episodes": 37, "particles": 16},
    "weights": {"runs": 3, "episodes": 6, "particles": 32},
}
# `weights` (issue 14): heavy blocks whose size is the prior mean, so that what TMP-RL
# gets wrong is the mass alone (its grip is 69 % of what the blocks need; `tmoc probe
# --believed-density`), on the one domain with density in L.
WEIGHTS_DOMAIN = "stack_and_push"
WEIGHTS_TRUE_SIZE = 0.045
WEIGHTS_TRUE_DENSITY = 2400.0
WEIGHTS_SIGMAS = (0.1, 3.5)       # N: an external wrist F/T sensor, a UR5e's built-in one
DEFAULT_PROBE_TRIALS = 20
# The experiments' hidden block size. Not the prior mean (45 mm, `tmoc run`'s default):
# there a grasp computed from the prior mean already works (pickup tolerates about
# +-10 mm, `tmoc probe`), so TMP-RL's fixed grounding would be right by construction and
# the experiments would not test grounding at all. At 34 mm the prior-mean grasp fails
# every time (probe: 0/10; 36 mm: 10/10) while 34 mm stays inside the prior (30-60 mm).
EXPERIMENT_TRUE_SIZE = 0.034
SYMLOG_ABOVE, SYMLOG_LINEAR = 1000.0, 200.0        # utility plot: symlog when curves span > 1000
CONVERGENCE_BAND = 0.05                           # "within 5 % of the final level"

CSV_COLUMNS = ("setting", "run", "episode", "seed", "agent", "particles", "utility", "actions",
               "failures", "delivered", "size_mean", "size_std", "size_error", "loads", "plan_loads",
               "optimal_plan", "success_rate", "particle_actions")


# --------------------------------------------------------------------------- settings

@dataclass(frozen=True)
class Setting:
    key: str                  # unique over experiments: the run directory DIR/runs/<key>
    label: str                # legend and CSV "setting"
    overrides: dict           # RunConfig fields


@dataclass
class Spec:
    """One experiment call, every scale field resolved."""

    name: str
    runs: int
    episodes: int
    particles: int
    seed: int = 0
    max_steps: int = 60
    true_size: float = EXPERIMENT_TRUE_SIZE
    milestones: tuple[int, ...] = ()
    probe_trials: int = DEFAULT_PROBE_TRIALS
    probe_seed: int = 0
    scale: str = "default"
    settings: list[Setting] = field(default_factory=list)
    domain: str = "container"
    particle_budget: str = "fixed"
    min_particles: int = 8

    def to_dict(self) -> dict:
        out = {"name": self.name, "runs": self.runs, "episodes": self.episodes,
               "particles": self.particles, "seed": self.seed, "max_steps": self.max_steps,
               "true_size": self.true_size, "milestones": list(self.milestones),
               "probe_trials": self.probe_trials, "probe_seed": self.probe_seed,
               "scale": self.scale}
        if self.domain != "container":     # the committed container summaries stay valid
            out["domain"] = self.domain
        if self.particle_budget != "fixed":
            out["particle_budget"], out["min_particles"] = self.particle_budget, self.min_particles
        return out


def particle_counts(n_max: int) -> list[int]:
    """The `particles` experiment's N: n_max x (1/4, 1/2, 3/4, 1), rounded, at least 1,
    duplicates dropped (200 -> 50, 100, 150, 200; 16 -> 4, 8, 12, 16; 2 -> 1, 2)."""
    return sorted({max(1, int(round(n_max * q))) for q in PARTICLE_FRACTIONS})


def settings_for(name: str, particles: int) -> list[Setting]:
    if name == "compare":
        return [Setting(f"compare-{a}", a, {"agent": a}) for a in AGENTS]
    if name == "particles":
        return [Setting(f"particles-N{n}", f"N={n}", {"agent": "tmoc", "particles": n})
                for n in particle_counts(particles)]
    if name == "milestones":
        return [Setting("milestones-tmoc", "tmoc", {"agent": "tmoc"})]
    if name == "sizes":
        return [Setting("sizes-equal", "equal", {"agent": "tmoc", "sizes_variation": False}),
                Setting("sizes-varied", "one 20% larger", {"agent": "tmoc", "sizes_variation": True})]
    if name == "likelihood":
        return [Setting(f"likelihood-{m}", m, {"agent": "tmoc", "likelihood": m})
                for m in ("replay", "paper")]
    if name == "robot":     # Table II: the real-robot run with the sizes given, and learned
        return [Setting("robot-given", "sizes given", {"agent": "tmoc", "known_properties": True}),
                Setting("robot-learned", "sizes learned", {"agent": "tmoc"})]
    if name == "weights":   # density learned with a fine and a coarse wrist sensor, or known
        truth = {"density": WEIGHTS_TRUE_DENSITY}
        learned = [Setting(f"weights-sigma{sg:g}", f"density learned, {sg:g} N",
                           {"agent": "tmoc", "truth": truth,
                            "options": {"unknown_density": True, "force_sigma": sg}})
                   for sg in WEIGHTS_SIGMAS]
        known = Setting("weights-known", "density known",
                        {"agent": "tmoc", "options": {"density": WEIGHTS_TRUE_DENSITY, "force_from_mass": True}})
        rl = Setting("weights-tmp_rl", "TMP-RL (prior-mean mass)",
                     {"agent": "tmp_rl", "truth": truth,
                      "options": {"unknown_density": True, "force_sigma": WEIGHTS_SIGMAS[0]}})
        return [*learned, known, rl]
    raise ValueError(f"unknown experiment {name!r} (known: {', '.join(EXPERIMENTS)})")


def default_milestones(episodes: int, count: int = 5) -> tuple[int, ...]:
    """`count` evenly spaced episodes (1-based), the last one being `episodes`."""
    return tuple(sorted({max(1, int(round(episodes * i / count))) for i in range(1, count + 1)}))


def run_seed(seed: int, experiment: int, setting: int, run: int) -> int:
    """The seed of run `run` of setting `setting` (SeedSequence; see the module doc)."""
    words = np.random.SeedSequence(seed, spawn_key=(experiment, setting, run)).generate_state(2)
    return int(((int(words[0]) << 32) | int(words[1])) & (2**63 - 1))


def run_config(spec: Spec, k: int, r: int) -> RunConfig:
    """RunConfig of run r of setting k (pydantic ValidationError on bad values)."""
    s = spec.settings[k]
    fields = {"domain": spec.domain, "particles": spec.particles, "episodes": spec.episodes,
              "max_steps": spec.max_steps, "true_size": spec.true_size,
              "seed": run_seed(spec.seed, EXPERIMENTS.index(spec.name), k, r),
              "particle_budget": spec.particle_budget, "min_particles": spec.min_particles}
    fields.update(s.overrides)
    if not AGENT_SPECS[fields["agent"]].learn_belief:     # tmp_rl, toep
        fields["particles"] = 1          # they keep no particles; 1 keeps the config honest
    return RunConfig(**fields)


def _jsonable(obj):
    return json.loads(json.dumps(obj))


def run_cost(config: RunConfig) -> float:
    """Relative cost, for submitting the most expensive runs first."""
    from .agents import agent

    per_episode = 0.5 + (0.62 * config.particles if agent(config.agent).learn_belief else 1.5)
    return config.episodes * per_episode


# --------------------------------------------------------------------------- T*

def probe_jobs(n_blocks: int, domain: str = "container") -> list[tuple[str, int]]:
    """(action, load) of every probe T* needs: pickup; stack of the first k blocks, k =
    1..n; push with k blocks loaded, k = 1..n. A domain with other probe semantics says
    so in its physics half (`t_star_probe_jobs`)."""
    custom = _t_star_hooks(domain)[0]
    if custom is not None:
        return custom(n_blocks)
    return ([("pickup", 1)] + [("stack", k) for k in range(1, n_blocks + 1)]
            + [("push", k) for k in range(1, n_blocks + 1)])


def _t_star_hooks(domain: str):
    """(probe_jobs, from_probes) of a domain's physics half, or (None, None): the container's."""
    if domain == "container":
        return None, None
    from sim_workers.domains import load

    phys = load(domain)
    return getattr(phys, "t_star_probe_jobs", None), getattr(phys, "t_star_from_probes", None)


def true_T_from_probes(successes: dict[tuple[str, int], int], trials: int, n_blocks: int) -> dict:
    """T* in the planner's form from probe success counts.

    pickup: its success rate. push[k-1]: the rate of a push with k blocks loaded.
    stack[h] (h blocks already in the container): a stack probe of k blocks succeeds when
    all k pickups and stacks do, and trial t of every k replays the same seeded world, so
    S(h+1) / S(h) (S(0) = trials) is the rate of "pick up, then stack on h"; dividing by
    the pickup rate leaves the stack's (clipped to [0, 1]). A height no trial reached
    (S(h) = 0) gets 0: never seen to succeed.
    """
    p_pickup = successes[("pickup", 1)] / trials
    S = [trials] + [successes[("stack", k)] for k in range(1, n_blocks + 1)]
    stack = []
    for h in range(n_blocks):
        if S[h] == 0 or p_pickup == 0:
            stack.append(0.0)
        else:
            stack.append(float(min(1.0, S[h + 1] / S[h] / p_pickup)))
    push = [successes[("push", k)] / trials for k in range(1, n_blocks + 1)]
    return {"pickup": float(p_pickup), "stack": stack, "push": [float(p) for p in push]}


def _t_star_params(spec: Spec, n_blocks: int = 8) -> dict:
    params = {"true_size": spec.true_size, "n_blocks": n_blocks, "trials": spec.probe_trials,
              "seed": spec.probe_seed}
    if spec.domain != "container":          # (cached container estimates stay valid)
        params["domain"] = spec.domain
    if spec.name == "weights":              # T* of the heavy blocks, Y at the true mass
        params["options"] = {"density": WEIGHTS_TRUE_DENSITY, "force_from_mass": True}
    return params


def cached_true_T(out: Path, params: dict) -> dict | None:
    """The cached T* in out/true_T.json if it was made with these parameters."""
    path = Path(out) / "true_T.json"
    if not path.exists():
        return None
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return data if data.get("params") == _jsonable(params) else None


def _probe_remote():
    import ray
    from sim_workers.probe import probe

    @ray.remote(num_cpus=1)
    def probe_task(action: str, true_size: float, load_k: int, trials: int, seed: int,
                   n_blocks: int, domain: str = "container", options: dict | None = None) -> int:
        return probe(action, true_size, true_size, load_k, trials, seed, n_blocks,
                     domain=domain, options=options).successes

    return probe_task


def submit_probes(params: dict) -> list:
    """Submit every probe of T* as a Ray task (one CPU each); refs in probe_jobs order."""
    task = _probe_remote()
    domain = params.get("domain", "container")
    return [task.remote(a, params["true_size"], k, params["trials"], params["seed"], params["n_blocks"],
                        domain, params.get("options"))
            for a, k in probe_jobs(params["n_blocks"], domain)]


def write_true_T(out: Path, params: dict, counts: Sequence[int]) -> dict:
    domain = params.get("domain", "container")
    jobs = probe_jobs(params["n_blocks"], domain)
    successes = dict(zip(jobs, (int(c) for c in counts)))
    from_probes = _t_star_hooks(domain)[1] or true_T_from_probes
    data = {"params": _jsonable(params),
            "transition": from_probes(successes, params["trials"], params["n_blocks"]),
            "successes": {f"{a}:{k}": successes[(a, k)] for a, k in jobs},
            "method": " ".join((from_probes.__doc__ or "").split())}
    _write_atomic(Path(out) / "true_T.json", json.dumps(data, indent=2))
    return data


def true_transition(out: Path, params: dict,
                    executor: Callable[[dict], Sequence[int]] | None = None) -> tuple[dict, bool]:
    """(T* record, was_cached): the cached out/true_T.json, or estimated by `executor`
    (default: the probes as Ray tasks) and cached."""
    cached = cached_true_T(out, params)
    if cached is not None:
        return cached, True
    if executor is None:
        import ray

        executor = lambda p: ray.get(submit_probes(p))
    return write_true_T(out, params, executor(params)), False


def load_actions(loads: Sequence[int]) -> list[str]:
    """The container plan that carries `loads` blocks per trip (blocks in order)."""
    actions, b = [], 1
    for i, k in enumerate(loads):
        for _ in range(k):
            actions += [f"pickup(r,b{b},init)", f"stack(r,b{b},c)"]
            b += 1
        actions.append("push(r,c,init,goal)")
        if i < len(loads) - 1:
            actions.append("push(r,c,goal,init)")
    return actions


class Optimality:
    """Is a plan's load split an expected-utility optimum under T*? A split is optimal when
    its expected utility equals the planner's optimum (ties count: 5+3 and 3+5 are worth
    the same, and so may other splits be)."""

    def __init__(self, transition: dict, costs: dict, n_blocks: int, domain: str = "container") -> None:
        from .domains import task_half

        self.task = task_half(domain)
        self.T, self.costs, self.n_blocks = transition, costs, n_blocks
        self.state = self.task.initial_state(n_blocks)
        best = self.task.plan(self.state, transition, costs)
        self.best_loads = list(best.loads)
        self.best_value = float(best.expected_utility)
        self._actions_for = getattr(self.task, "actions_for_loads", None) \
            or (lambda n, loads: load_actions(loads))
        self._cache: dict[tuple[int, ...], bool] = {}

    def value(self, loads: Sequence[int]) -> float:
        return self.task.expected_utility(self.state, self._actions_for(self.n_blocks, loads),
                                          self.T, self.costs)

    def __call__(self, loads: Sequence[int]) -> bool | None:
        key = tuple(int(k) for k in loads)
        if sum(key) != self.n_blocks or any(k < 1 for k in key):
            return None if not key else False
        if key not in self._cache:
            tol = 1e-6 * max(1.0, abs(self.best_value))
            self._cache[key] = abs(self.value(key) - self.best_value) <= tol
        return self._cache[key]


# --------------------------------------------------------------------------- run files

def run_path(out: Path, setting: Setting, r: int, partial: bool = False) -> Path:
    return Path(out) / "runs" / setting.key / (f"{r}.partial.json" if partial else f"{r}.json")


def _write_atomic(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + f".tmp{os.getpid()}")
    tmp.write_text(text)
    os.replace(tmp, path)


class ResumeError(ValueError):
    """An existing run file cannot be used for this call (the message says why)."""


def _config_diff(stored: dict, wanted: dict) -> str:
    keys = sorted(k for k in set(stored) | set(wanted) if stored.get(k) != wanted.get(k))
    return ", ".join(f"{k}={stored.get(k)!r} (asked {wanted.get(k)!r})" for k in keys)


def read_run(path: Path, config: RunConfig) -> dict | None:
    """A finished or partial run file if its config is `config`; ResumeError if it was made
    with another config; None if unreadable (a torn write: recomputed)."""
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    wanted = _jsonable(config.model_dump())
    if data.get("config") != wanted:
        raise ResumeError(f"{path} was made with other settings: "
                          f"{_config_diff(data.get('config') or {}, wanted)}")
    return data


# --------------------------------------------------------------------------- running

def _run_remote():
    import ray

    @ray.remote(num_cpus=1, max_retries=2)
    def run_task(config: dict, key: str, resume: dict | None, progress, checkpoint_s: float | None):
        from .agents import agent
        from .fanout import ShardPool
        from .runner import run

        cfg = RunConfig(**config)
        pool = (ShardPool(cfg.domain, {"n_blocks": cfg.n_blocks, **cfg.options}, n_shards=0)
                if agent(cfg.agent).learn_belief else None)
        last = [time.monotonic()]

        def on_episode(record, session, checkpoint):
            send = (checkpoint_s is not None and record["episode"] + 1 < cfg.episodes
                    and time.monotonic() - last[0] >= checkpoint_s)
            if send:
                last[0] = time.monotonic()
            if progress is not None:
                progress.episode.remote(key, checkpoint if send else None)

        try:
            return run(cfg, pool=pool, on_episode=on_episode, resume=resume)
        finally:
            if pool is not None:
                pool.close()

    return run_task


def _progress_actor():
    import ray

    @ray.remote(num_cpus=0)
    class Progress:
        """Episodes done, and the latest checkpoint of each run, for the driver to collect."""

        def __init__(self) -> None:
            self.episodes = 0
            self.checkpoints: dict = {}

        def episode(self, key: str, checkpoint: dict | None) -> None:
            self.episodes += 1
            if checkpoint is not None:
                self.checkpoints[key] = checkpoint

        def drain(self) -> tuple[int, dict]:
            out, self.checkpoints = self.checkpoints, {}
            return self.episodes, out

    return Progress.remote()


def existing_runs(out: Path, spec: Spec) -> list[Path]:
    return [p for s in spec.settings for p in sorted((Path(out) / "runs" / s.key).glob("*.json"))]


def execute(spec: Spec, out: Path, *, resume: bool = False, progress: bool = True,
            checkpoint_s: float | None = 60.0) -> dict:
    """Run every missing run of `spec` on the Ray cluster (already initialised), write run
    files as runs finish, then the CSV, JSON and PNG. Returns what was done."""
    import ray
    from tqdm import tqdm

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    configs = {(k, r): run_config(spec, k, r)
               for k in range(len(spec.settings)) for r in range(spec.runs)}
    todo, reused, resumed = [], 0, 0
    partials: dict[tuple[int, int], dict] = {}
    for (k, r), cfg in configs.items():
        setting = spec.settings[k]
        if resume:
            done = run_path(out, setting, r)
            if done.exists() and read_run(done, cfg) is not None:
                reused += 1
                continue
            part = run_path(out, setting, r, partial=True)
            if part.exists():
                data = read_run(part, cfg)
                if data is not None:
                    partials[(k, r)] = data["checkpoint"]
        todo.append((k, r))
    done_eps = {kr: partials[kr]["session"]["episode"] if kr in partials else 0 for kr in todo}
    # Most expensive remaining work first: packs the runs well onto few CPUs.
    todo.sort(key=lambda kr: -run_cost(configs[kr]) * (1 - done_eps[kr] / spec.episodes))

    params = _t_star_params(spec)
    t_star = cached_true_T(out, params)
    probe_refs = submit_probes(params) if t_star is None else None

    prog = _progress_actor() if todo else None
    task = _run_remote()
    refs = {}
    for k, r in todo:
        cfg = configs[(k, r)]
        resumed += (k, r) in partials
        ref = task.remote(cfg.model_dump(), f"{k}/{r}", partials.get((k, r)), prog, checkpoint_s)
        refs[ref] = (k, r)
    ep_total = sum(spec.episodes - done_eps[kr] for kr in todo)
    run_bar = tqdm(total=len(todo), desc=f"{spec.name}: runs", unit="run", disable=not progress,
                   position=0)
    ep_bar = tqdm(total=ep_total, desc=f"{spec.name}: episodes", unit="ep", disable=not progress,
                  position=1)
    t0 = time.perf_counter()
    pending = list(refs)
    try:
        while pending:
            ready, pending = ray.wait(pending, num_returns=len(pending), timeout=0.5)
            for ref in ready:
                k, r = refs[ref]
                result = ray.get(ref)
                _store_run(out, spec, k, r, configs[(k, r)], result)
                run_bar.update(1)
            if prog is not None:
                n_eps, checkpoints = ray.get(prog.drain.remote())
                for key, ckpt in checkpoints.items():
                    k, r = (int(v) for v in key.split("/"))
                    if not run_path(out, spec.settings[k], r).exists():
                        _write_atomic(run_path(out, spec.settings[k], r, partial=True),
                                      json.dumps({"config": _jsonable(configs[(k, r)].model_dump()),
                                                  "checkpoint": ckpt}))
                ep_bar.update(max(0, min(n_eps, ep_total) - ep_bar.n))
        ep_bar.update(ep_total - ep_bar.n)
        if probe_refs is not None:
            t_star = write_true_T(out, params, ray.get(probe_refs))
    finally:
        run_bar.close()
        ep_bar.close()
        for ref in pending:
            ray.cancel(ref, force=True)
        if prog is not None:
            ray.kill(prog)
    files = write_outputs(spec, out, t_star)
    return {"computed": len(todo), "resumed_from_checkpoint": resumed, "reused": reused,
            "true_T": "cached" if probe_refs is None else "estimated",
            "wall_s": time.perf_counter() - t0, **files}


def _store_run(out: Path, spec: Spec, k: int, r: int, config: RunConfig, result: dict) -> None:
    setting = spec.settings[k]
    record = {"experiment": spec.name, "setting": setting.key, "label": setting.label, "run": r,
              "seed": config.seed, "config": _jsonable(config.model_dump()),
              "episodes": result["episodes"], "summary": result["summary"],
              "runtime": result["runtime"]}
    _write_atomic(run_path(out, setting, r), json.dumps(record))
    part = run_path(out, setting, r, partial=True)
    if part.exists():
        part.unlink()


# --------------------------------------------------------------------------- outputs

def posterior_error(posterior: dict, config: dict) -> float:
    """|posterior size mean - true size| (metres); with sizes_variation (block 1 is 20 %
    larger, sim_workers.container) the mean over blocks of |block mean - block truth|."""
    if config["sizes_variation"] and len(posterior.get("mean") or []) == config["n_blocks"]:
        truth = np.full(config["n_blocks"], config["true_size"])
        truth[0] *= SIZES_VARIATION_SCALE
        return float(np.mean(np.abs(np.array(posterior["mean"]) - truth)))
    return abs(posterior["size_mean"] - config["true_size"])


def _rows(spec: Spec, out: Path, optimal: Optimality) -> tuple[list[dict], dict]:
    """CSV rows (setting order, run, episode) and the per-setting arrays for the summary."""
    rows, arrays = [], {}
    for k, s in enumerate(spec.settings):
        per = {"utility": [], "size_err": [], "optimal": [], "successes": [], "actions": [],
               "wall_s": [], "density_err": [], "density_std": [], "particle_actions": []}
        for r in range(spec.runs):
            data = json.loads(run_path(out, s, r).read_text())
            cfg = data["config"]
            eps = data["episodes"]
            judge = not cfg["sizes_variation"]       # T* is probed with equal blocks
            u, err, opt, succ, acts, d_err, d_std, pa = [], [], [], [], [], [], [], []
            true_density = _true_density(cfg)
            for e in eps:
                n_fail = int(sum(e["failures"].values()))
                plan_loads = list(e["plans"][0]) if e.get("plans") else []
                is_opt = optimal(plan_loads) if judge else None
                rate = (e["actions"] - n_fail) / e["actions"] if e["actions"] else None
                rows.append({
                    "setting": s.label, "run": r, "episode": e["episode"] + 1, "seed": data["seed"],
                    "agent": cfg["agent"], "particles": cfg["particles"],
                    "utility": e["utility"], "actions": e["actions"], "failures": n_fail,
                    "delivered": e["delivered"], "size_mean": e["posterior"]["size_mean"],
                    "size_std": e["posterior"]["size_std"],
                    "size_error": posterior_error(e["posterior"], cfg),
                    "loads": "+".join(str(x) for x in e["loads"]),
                    "plan_loads": "+".join(str(x) for x in plan_loads),
                    "optimal_plan": "" if is_opt is None else int(is_opt),
                    "success_rate": "" if rate is None else rate,
                    "particle_actions": e.get("particle_actions", ""),
                })
                dens = (e["posterior"].get("properties") or {}).get("density")
                if spec.name == "weights":
                    rows[-1].update(_density_cells(dens, true_density))
                d_err.append(np.nan if dens is None or true_density is None
                             else abs(dens["mean"] - true_density))
                d_std.append(np.nan if dens is None else dens["std"])
                u.append(e["utility"])
                err.append(rows[-1]["size_error"])
                opt.append(np.nan if is_opt is None else float(is_opt))
                succ.append(e["actions"] - n_fail)
                acts.append(e["actions"])
                pa.append(e.get("particle_actions", np.nan))     # runs from before the budget: unknown
            for key, v in (("utility", u), ("size_err", err), ("optimal", opt),
                           ("successes", succ), ("actions", acts), ("density_err", d_err),
                           ("density_std", d_std), ("particle_actions", pa)):
                per[key].append(v)
            per["wall_s"].append(data["runtime"]["wall_s"])
        arrays[s.label] = {key: (np.array(v, dtype=float) if key != "wall_s" else v)
                           for key, v in per.items()}
    return rows, arrays


def _true_density(cfg: dict) -> float | None:
    """The run's true block density: the hidden truth's, or the known one it was set to."""
    value = (cfg.get("truth") or {}).get("density", (cfg.get("options") or {}).get("density"))
    return None if value is None else float(value)


def _density_cells(dens: dict | None, truth: float | None) -> dict:
    """CSV cells of the density posterior (empty where L has no density: it is known)."""
    if dens is None:
        return {"density_mean": "", "density_std": "", "density_error": ""}
    return {"density_mean": dens["mean"], "density_std": dens["std"],
            "density_error": "" if truth is None else abs(dens["mean"] - truth)}


def convergence_episode(curve: np.ndarray, band: float = CONVERGENCE_BAND) -> tuple[int | None, float, int]:
    """(episode, final level, smoothing window) for a mean curve.

    final level = mean of the curve over its last fifth (at least one episode). The curve
    is smoothed by a trailing moving average over w = max(1, E // 20) episodes (per-episode
    means over a few runs are too noisy to ever "stay" anywhere). The answer is the first
    episode (1-based) from which the smoothed curve stays within band x |final level| of
    the final level to the end; None if its last point is outside.
    """
    E = len(curve)
    tail = max(1, int(math.ceil(E / 5)))
    final = float(np.mean(curve[-tail:]))
    w = max(1, E // 20)
    c = np.cumsum(np.concatenate([[0.0], curve]))
    idx = np.arange(1, E + 1)
    smooth = (c[idx] - c[np.maximum(0, idx - w)]) / np.minimum(idx, w)
    inside = np.abs(smooth - final) <= band * abs(final) + 1e-12
    if not inside[-1]:
        return None, final, w
    outside = np.flatnonzero(~inside)
    return (int(outside[-1]) + 2 if len(outside) else 1), final, w


def _nan_mean(a) -> float | None:
    a = np.asarray(a, dtype=float)
    return None if a.size == 0 or np.all(np.isnan(a)) else float(np.nanmean(a))


def summarize(spec: Spec, arrays: dict, optimal: Optimality) -> dict:
    E = spec.episodes
    tail = max(1, int(math.ceil(E / 5)))
    settings = {}
    for k, s in enumerate(spec.settings):
        a = arrays[s.label]
        curve = a["utility"].mean(axis=0)
        conv, final, w = convergence_episode(curve)
        last = a["utility"][:, -tail:].mean(axis=1)
        cfg = run_config(spec, k, 0)
        opt_tail = a["optimal"][:, -tail:]
        settings[s.label] = {
            "key": s.key, "agent": cfg.agent, "particles": cfg.particles,
            "sizes_variation": cfg.sizes_variation, "likelihood": cfg.likelihood,
            "runs": spec.runs, "episodes": E,
            "mean_utility_last_fifth": float(final),
            "std_utility_last_fifth": float(np.std(last)),
            "episodes_to_converge": conv,
            "final_posterior_error": float(np.mean(a["size_err"][:, -1])),
            "final_posterior_error_mm": float(np.mean(a["size_err"][:, -1]) * 1000),
            "optimal_plans_pct_last_fifth": (None if np.all(np.isnan(opt_tail))
                                             else 100 * _nan_mean(opt_tail)),
            "successful_actions_pct_last_fifth": 100 * float(a["successes"][:, -tail:].sum()
                                                             / max(1.0, a["actions"][:, -tail:].sum())),
            "mean_wall_s_per_run": float(np.mean(a["wall_s"])),
            # the adaptive budget at work: particle worlds per episode, first and last
            "particle_actions_first_episode": _nan_mean(a["particle_actions"][:, 0]),
            "particle_actions_last_episode": _nan_mean(a["particle_actions"][:, -1]),
        }
        if spec.name == "weights":
            truth = _true_density(cfg.model_dump())
            d_err, d_std = a["density_err"][:, -1], a["density_std"][:, -1]
            learned = not np.all(np.isnan(d_err))
            settings[s.label].update({
                "true_density": truth,
                "density_in_L": bool(learned or not np.all(np.isnan(d_std))),
                "final_density_error": _nan_mean(d_err) if learned else None,
                "final_density_error_pct": (100 * _nan_mean(d_err) / truth) if learned and truth else None,
                "final_density_std": _nan_mean(d_std),
            })
    summary = {
        "experiment": spec.name, "spec": spec.to_dict(), "settings": settings,
        "optimum_under_true_T": {"loads": optimal.best_loads, "expected_utility": optimal.best_value},
        "definitions": {
            "episode": "1-based",
            "last_fifth": f"the last {tail} of {E} episodes (ceil(E / 5))",
            "mean_utility_last_fifth": "mean over runs of the utility over the last fifth "
                                       "(= the final level of the mean curve)",
            "episodes_to_converge": convergence_episode.__doc__.strip().split("\n\n")[1]
                                    .replace("\n", " ").replace("    ", ""),
            "final_posterior_error": "|posterior size mean - true size| after the last episode, "
                                     "metres, mean over runs (tmp_rl and toep: the prior mean); "
                                     "with sizes_variation the mean over blocks of |block mean - "
                                     "block truth|",
            "optimal_plan": "the episode's first plan (from the initial state) has a load split "
                            "whose expected utility under T* equals the optimum's; not judged "
                            "with sizes_variation (T* is probed with equal blocks)",
            "success_rate": "successful actions / actions in the episode",
            "particle_actions": "particle worlds simulated in the episode (actions x particles; "
                                "with --particle-budget kld the count falls as the belief converges)",
        },
    }
    if spec.name == "milestones":
        summary["milestones"] = milestone_table(spec, arrays)
    if spec.name == "robot":
        summary["table_ii"] = robot_table(spec, arrays)
    if spec.name == "weights":
        summary["definitions"]["final_density_error"] = (
            "|posterior density mean - true density| after the last episode, kg/m^3, mean over "
            "runs (TMP-RL: the prior mean's; none where the density is known, not in L)")
        summary["definitions"]["final_density_std"] = "the density posterior's std after the last episode, kg/m^3"
    return summary


def milestone_table(spec: Spec, arrays: dict) -> list[dict]:
    """Per setting and milestone m: % optimal plans and % successful actions over the
    episodes since the previous milestone (exclusive) up to m (inclusive), per run, then
    mean and std over runs."""
    out = []
    for label, a in arrays.items():
        lo = 0
        for m in spec.milestones:
            opt = a["optimal"][:, lo:m]
            succ = a["successes"][:, lo:m].sum(axis=1) / np.maximum(1, a["actions"][:, lo:m].sum(axis=1))
            per_run_opt = (np.array([np.nan if np.all(np.isnan(row)) else np.nanmean(row) for row in opt])
                           * 100)
            out.append({"setting": label, "episode": m, "from_episode": lo + 1,
                        "optimal_plans_pct": _nan_mean(per_run_opt),
                        "optimal_plans_pct_std": (None if np.all(np.isnan(per_run_opt))
                                                  else float(np.nanstd(per_run_opt))),
                        "successful_actions_pct": float(np.mean(succ) * 100),
                        "successful_actions_pct_std": float(np.std(succ) * 100)})
            lo = m
    return out


def write_csv(rows: list[dict], path: Path) -> None:
    buf = io.StringIO()
    extra = [k for k in ("density_mean", "density_std", "density_error") if rows and k in rows[0]]
    w = csv.DictWriter(buf, fieldnames=[*CSV_COLUMNS, *extra], lineterminator="\n")
    w.writeheader()
    for row in rows:
        w.writerow({k: (repr(v) if isinstance(v, float) else v) for k, v in row.items()})
    _write_atomic(path, buf.getvalue())


def plot(spec: Spec, arrays: dict, summary: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if spec.name == "milestones":
        table = summary["milestones"]
        fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
        for ax, key, title in ((axes[0], "optimal_plans_pct", "optimal plans"),
                               (axes[1], "successful_actions_pct", "successful actions")):
            rows = list(table)
            x = np.arange(len(rows))
            vals = [np.nan if t[key] is None else t[key] for t in rows]
            errs = [0.0 if t[key + "_std"] is None else t[key + "_std"] for t in rows]
            bars = ax.bar(x, vals, yerr=errs, capsize=3,
                          color="tab:blue" if "optimal" in key else "tab:green")
            ax.bar_label(bars, labels=["n/a" if np.isnan(v) else f"{v:.0f}" for v in vals],
                         padding=2, fontsize=8)
            ax.set_xticks(x, [str(t["episode"]) if t["from_episode"] == t["episode"]
                              else f"{t['from_episode']}-{t['episode']}" for t in rows])
            ax.set_ylim(0, 105)
            ax.set_xlabel("episodes"); ax.set_ylabel("%"); ax.set_title(f"{title} (mean ± std over runs)")
        fig.suptitle(f"milestones: TMOC, {spec.runs} runs, N = {spec.particles}, "
                     f"true size {spec.true_size * 1000:.0f} mm")
    else:
        weights = spec.name == "weights"
        fig, axes = plt.subplots(1, 3 if weights else 2, figsize=(16 if weights else 11, 3.8))
        ax1, ax2 = axes[0], axes[1]
        x = np.arange(1, spec.episodes + 1)
        for label, a in arrays.items():
            panels = [(ax1, a["utility"], 1.0), (ax2, a["size_err"], 1000.0)]
            if weights:
                panels.append((axes[2], a["density_err"], 1.0))
            for ax, v, scale in panels:
                if np.all(np.isnan(v)):        # the density known: nothing to plot
                    ax.plot([], [])
                    continue
                m, s = v.mean(axis=0) * scale, v.std(axis=0) * scale
                line, = ax.plot(x, m, label=label, marker="o" if len(x) < 30 else None, ms=3)
                ax.fill_between(x, m - s, m + s, alpha=0.2, color=line.get_color())
        if weights:
            axes[2].set_xlabel("episode"); axes[2].set_ylabel("|density mean - truth| (kg/m^3)")
            axes[2].set_title("posterior error of the density", fontsize=10)
        ax1.set_xlabel("episode"); ax1.set_ylabel("utility")
        ax1.set_title("utility (mean ± 1 std over runs)")
        means = np.concatenate([a["utility"].mean(axis=0) for a in arrays.values()])
        if np.ptp(means) > SYMLOG_ABOVE:
            # An agent that never grounds the blocks (TMP-RL off the prior mean) fails every
            # action of every episode, ~30x below the others: a linear axis flattens them.
            ax1.set_yscale("symlog", linthresh=SYMLOG_LINEAR)
            lo, hi = ax1.get_ylim()
            ticks = [t for t in (-1e5, -1e4, -1e3, -100, 0, 100, 1e3) if lo <= t <= hi]
            ax1.set_yticks(ticks, [f"{t:.0f}" for t in ticks])
            ax1.set_title(f"utility (mean ± 1 std; linear within ±{SYMLOG_LINEAR:.0f}, log beyond)",
                          fontsize=10)
        ax2.set_xlabel("episode"); ax2.set_ylabel("|size mean - truth| (mm)")
        ax2.set_title("posterior error of L (agents without a belief: the prior mean's)", fontsize=10)
        from matplotlib.ticker import MaxNLocator

        for ax in axes:
            ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax1.legend(fontsize=8)
        fig.suptitle(f"{spec.name}: {spec.runs} runs x {spec.episodes} episodes, "
                     f"true size {spec.true_size * 1000:.0f} mm"
                     + (f", density {WEIGHTS_TRUE_DENSITY:.0f} kg/m^3" if weights else ""))
    fig.tight_layout()
    tmp = path.with_name(path.name + f".tmp{os.getpid()}.png")
    fig.savefig(tmp, dpi=90)
    plt.close(fig)
    os.replace(tmp, path)


def _fmt(v, digits: int = 1, unit: str = "") -> str:
    return "n/a" if v is None else f"{v:.{digits}f}{unit}"


def robot_table(spec: Spec, arrays: dict) -> list[dict]:
    """Table II of the paper: utility mean and std over runs at episodes 0, 4, ..., 36
    (0-based, as the paper counts), per setting; episodes beyond the run are left out."""
    rows = []
    for s in spec.settings:
        u = arrays[s.label]["utility"]
        cells = {str(e): {"mean": float(np.mean(u[:, e])), "std": float(np.std(u[:, e]))}
                 for e in ROBOT_EPISODES if e < u.shape[1]}
        rows.append({"setting": s.label, "episodes": cells})
    return rows


def summary_table(summary: dict) -> str:
    """The summary as a markdown table (one row per setting; `milestones` adds its bars as a
    second table). DIR/NAME.md holds it, and docs/RESULTS.md embeds it verbatim."""
    from .agents import agent

    spec = summary["spec"]
    lines = [f"`{summary['experiment']}`: {spec['runs']} runs x {spec['episodes']} episodes, "
             f"true size {spec['true_size'] * 1000:.0f} mm, seed {spec['seed']}; optimum under T*: "
             f"{'+'.join(map(str, summary['optimum_under_true_T']['loads']))} "
             f"(expected utility {summary['optimum_under_true_T']['expected_utility']:.1f}, without "
             "the all-delivered bonus that every complete plan earns alike)",
             "",
             "| setting | N | utility, last fifth (mean ± std over runs) | episodes to converge "
             "| posterior error (mm) | optimal plans, last fifth | successful actions, last fifth "
             "| wall per run (s) |",
             "|---|---|---|---|---|---|---|---|"]
    for label, v in summary["settings"].items():
        lines.append(
            f"| {label} | {v['particles'] if agent(v['agent']).learn_belief else '-'} "
            f"| {v['mean_utility_last_fifth']:.1f} ± {v['std_utility_last_fifth']:.1f} "
            f"| {'not converged' if v['episodes_to_converge'] is None else v['episodes_to_converge']} "
            f"| {v['final_posterior_error_mm']:.1f} "
            f"| {_fmt(v['optimal_plans_pct_last_fifth'], 0, ' %')} "
            f"| {_fmt(v['successful_actions_pct_last_fifth'], 1, ' %')} "
            f"| {v['mean_wall_s_per_run']:.0f} |")
    if "table_ii" in summary:
        episodes = list(summary["table_ii"][0]["episodes"]) if summary["table_ii"] else []
        lines += ["", "| setting (utility, mean (std) over runs) | " + " | ".join(
                      f"ep {e}" for e in episodes) + " |",
                  "|---|" + "---|" * len(episodes)]
        for row in summary["table_ii"]:
            lines.append(f"| {row['setting']} | " + " | ".join(
                f"{c['mean']:.0f} ({c['std']:.0f})" for c in row["episodes"].values()) + " |")
    if spec.get("particle_budget", "fixed") != "fixed":
        lines += ["", f"Particle budget `{spec['particle_budget']}` (floor {spec.get('min_particles')}): "
                      "particle-actions per episode, mean over runs", "",
                  "| setting | episode 1 | last episode |", "|---|---|---|"]
        for label, v in summary["settings"].items():
            lines.append(f"| {label} | {_fmt(v['particle_actions_first_episode'], 0, '')} "
                         f"| {_fmt(v['particle_actions_last_episode'], 0, '')} |")
    if summary["experiment"] == "weights":
        lines += ["", "| setting | density | posterior error of the density, last episode "
                      "| density posterior std | posterior error of the size (mm) |",
                  "|---|---|---|---|---|"]
        for label, v in summary["settings"].items():
            err = ("-" if v["final_density_error"] is None
                   else f"{v['final_density_error']:.0f} kg/m^3 ({v['final_density_error_pct']:.1f} %)")
            std = "-" if v["final_density_std"] is None else f"{v['final_density_std']:.0f} kg/m^3"
            where = ("known" if not v["density_in_L"] else "prior mean" if not agent(v["agent"]).learn_belief
                     else "learned")
            lines.append(f"| {label} | {where} | {err} | {std} | {v['final_posterior_error_mm']:.1f} |")
    if "milestones" in summary:
        lines += ["", "| setting | episodes | optimal plans (mean ± std) | successful actions (mean ± std) |",
                  "|---|---|---|---|"]
        for m in summary["milestones"]:
            span = (str(m["episode"]) if m["from_episode"] == m["episode"]
                    else f"{m['from_episode']}-{m['episode']}")
            opt = ("n/a" if m["optimal_plans_pct"] is None
                   else f"{m['optimal_plans_pct']:.0f} ± {m['optimal_plans_pct_std']:.0f} %")
            lines.append(f"| {m['setting']} | {span} | {opt} "
                         f"| {m['successful_actions_pct']:.1f} ± {m['successful_actions_pct_std']:.1f} % |")
    return "\n".join(lines) + "\n"


def write_outputs(spec: Spec, out: Path, t_star: dict) -> dict:
    from .domains import task_half

    optimal = Optimality(t_star["transition"], dict(task_half(spec.domain).default_costs),
                         t_star["params"]["n_blocks"], spec.domain)
    rows, arrays = _rows(spec, out, optimal)
    summary = summarize(spec, arrays, optimal)
    summary["true_T"] = t_star["transition"]
    paths = {"csv": out / f"{spec.name}.csv", "json": out / f"{spec.name}.json",
             "png": out / f"{spec.name}.png", "md": out / f"{spec.name}.md"}
    write_csv(rows, paths["csv"])
    _write_atomic(paths["json"], json.dumps(summary, indent=2))
    _write_atomic(paths["md"], summary_table(summary))
    plot(spec, arrays, summary, paths["png"])
    return {k: str(v) for k, v in paths.items()}
