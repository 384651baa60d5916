"""T*: the *true* transition model, for judging whether a plan is optimal.

It is estimated once from the true world with seeded ``sim_workers.probe`` trials
(believed size = true size) and cached in ``DIR/true_T.json``; see
the domain's ``t_star_from_probes``. ``Optimality`` then judges a plan's load split against the
planner's optimum under T*.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Callable, Sequence

from sim_workers.domains import DEFAULT_DOMAIN

from ..loop.arm_trials import is_arm, with_robot
from ..robots import options_for
from .spec import WEIGHTS_TRUE_DENSITY, Setting, Spec
from .runfiles import jsonable, write_atomic


def _physics(domain: str):
    from sim_workers.domains import load

    return load(domain)


def _physics_spec(domain: str):
    from sim_workers.domains import spec

    return spec(domain)


def probe_jobs(n_blocks: int, domain: str) -> list[tuple[str, int]]:
    """(action, load) of every probe T* needs: the domain's ``t_star_probe_jobs``."""
    return _physics(domain).t_star_probe_jobs(n_blocks)


def run_object_count(spec: Spec, setting: Setting | None = None) -> int:
    """The object count the experiment's runs have: ``--set n_objects=N`` (or n_blocks, or
    a setting's own), else the domain's default (issue 39: T* was probed for 8 objects
    whatever the runs had, and the optimum judged for 8)."""
    fields = {**spec.run_fields, **(setting.overrides if setting is not None else {})}
    given = fields.get("n_objects", fields.get("n_blocks"))
    return int(given) if given is not None else int(_physics(spec.domain).n_objects)


def t_star_params(spec: Spec, n_blocks: int | None = None, setting: Setting | None = None) -> dict:
    """The probe parameters of `spec`'s T* (also the key of its cache); a setting with its
    own truth (``Setting.t_star``: e.g. the sweep's true size and density) overrides them."""
    if n_blocks is None:
        n_blocks = run_object_count(spec, setting)
    params = {"true_size": spec.true_size, "n_blocks": n_blocks, "trials": spec.probe_trials,
              "seed": spec.probe_seed}
    if spec.domain != DEFAULT_DOMAIN:       # (caches from before domains stay valid)
        params["domain"] = spec.domain
    if spec.probe_perception > 0:           # (caches probed exactly stay valid)
        params["perception_sigma"] = float(spec.probe_perception)
    version = _physics_spec(spec.domain).version
    if version != 1:                        # a cache without one is version 1's
        params["domain_version"] = version
    if spec.name == "weights":              # T* of the heavy blocks, Y at the true mass
        params["options"] = {"density": WEIGHTS_TRUE_DENSITY, "force_from_mass": True}
    if setting is not None and setting.t_star:
        params.update(setting.t_star)
    if spec.reality_engine is not None:     # T* is reality's: probed in its engine
        params["options"] = {**params.get("options", {}), "engine": spec.reality_engine}
    robot = {**spec.run_fields, **(setting.overrides if setting is not None else {})}.get("robot")
    if _is_arm(robot):                      # T* is the runs' robot's (issue 41): its arm does the probes
        params["robot"] = str(robot)
    return params


def _is_arm(name) -> bool:
    return isinstance(name, str) and is_arm(name)


def t_star_files(spec: Spec) -> dict[tuple[str, int], tuple[str, dict]]:
    """(setting key, run) -> (cache file under DIR, T* parameters). One T* for the whole
    experiment is ``true_T.json`` (as every experiment kept it); truths of their own (the
    sweep's settings, or runs across the prior) get ``true_T/<key>[-run<r>].json`` each,
    shared where the parameters are equal."""
    params = {}
    for s in spec.settings:
        for r in range(spec.runs):
            p = t_star_params(spec, setting=s)
            if spec.truths:
                p["true_size"] = spec.truths[r]
            params[(s.key, r)] = p
    distinct = {json.dumps(jsonable(p), sort_keys=True) for p in params.values()}
    if len(distinct) <= 1:
        return {kr: ("true_T.json", p) for kr, p in params.items()}
    first: dict[str, str] = {}
    for (key, r), p in params.items():
        first.setdefault(json.dumps(jsonable(p), sort_keys=True), f"{key}-run{r}" if spec.truths else key)
    return {kr: (f"true_T/{first[json.dumps(jsonable(p), sort_keys=True)]}.json", p)
            for kr, p in params.items()}


def cached_true_T(out: Path, params: dict, name: str = "true_T.json") -> dict | None:
    """The cached T* in out/`name` if it was made with these parameters."""
    path = Path(out) / name
    if not path.exists():
        return None
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    if data.get("params") != jsonable(params):
        return None
    # Probed some other way (e.g. stack-and-push before its towers were built by the
    # agent's actions): not this T*.
    jobs = {f"{a}:{k}" for a, k in probe_jobs(params["n_blocks"], params.get("domain", DEFAULT_DOMAIN))}
    return data if set(data.get("successes", {})) == jobs else None


def _probe_remote():
    import ray

    @ray.remote(num_cpus=1)
    def probe_task(action: str, true_size: float, load_k: int, trials: int, seed: int,
                   n_blocks: int, domain: str, options: dict | None = None, robot: str | None = None,
                   perception_m: float = 0.0) -> int:
        return probe_successes(action, true_size, load_k, trials, seed, n_blocks, domain, options, robot,
                               perception_m)

    return probe_task


def probe_successes(action: str, true_size: float, load_k: int, trials: int, seed: int, n_blocks: int,
                    domain: str, options: dict | None = None, robot: str | None = None,
                    perception_m: float = 0.0) -> int:
    """One of T*'s probes (Y at the truth): its successes in `trials`, done by `robot` (None:
    the floating gripper) with the domain's options as that robot runs it, each action
    planned from positions perceived with std `perception_m` (0: exactly)."""
    from sim_workers.probe import probe

    options = dict(options or {})
    if robot is not None:
        options = options_for(robot, _physics(domain), options)
    with with_robot(robot) as doing:
        successes = probe(action, true_size, true_size, load_k, trials, seed, n_blocks,
                          domain=domain, options=options, perception_m=perception_m).successes
    doing.check_used(domain)
    return successes


def submit_probes(params: dict) -> list:
    """Submit every probe of T* as a Ray task (one CPU each); refs in probe_jobs order."""
    task = _probe_remote()
    domain = params.get("domain", DEFAULT_DOMAIN)
    return [task.remote(a, params["true_size"], k, params["trials"], params["seed"], params["n_blocks"],
                        domain, params.get("options"), params.get("robot"), params.get("perception_sigma", 0.0))
            for a, k in probe_jobs(params["n_blocks"], domain)]


def write_true_T(out: Path, params: dict, counts: Sequence[int], name: str = "true_T.json") -> dict:
    """T* from the probes' success `counts` (probe_jobs order), cached in out/`name`."""
    domain = params.get("domain", DEFAULT_DOMAIN)
    jobs = probe_jobs(params["n_blocks"], domain)
    successes = dict(zip(jobs, (int(c) for c in counts)))
    from_probes = _physics(domain).t_star_from_probes
    data = {"params": jsonable(params),
            "transition": from_probes(successes, params["trials"], params["n_blocks"]),
            "successes": {f"{a}:{k}": successes[(a, k)] for a, k in jobs},
            "method": " ".join((from_probes.__doc__ or "").split())}
    write_atomic(Path(out) / name, json.dumps(data, indent=2))
    return data


def true_transition(out: Path, params: dict,
                    executor: Callable[[dict], Sequence[int]] | None = None,
                    name: str = "true_T.json") -> tuple[dict, bool]:
    """(T* record, was_cached): the cached out/`name`, or estimated by `executor`
    (default: the probes as Ray tasks) and cached."""
    cached = cached_true_T(out, params, name)
    if cached is not None:
        return cached, True
    if executor is None:
        import ray

        executor = lambda p: ray.get(submit_probes(p))
    return write_true_T(out, params, executor(params), name), False


class Optimality:
    """Is a plan's load split an expected-utility optimum under T*? A split is optimal when
    its expected utility equals the planner's optimum (ties count: 5+3 and 3+5 are worth
    the same, and so may other splits be)."""

    def __init__(self, transition: dict, costs: dict, n_blocks: int, domain: str) -> None:
        from ..domains import task_half

        self.task = task_half(domain)
        self.T, self.costs, self.n_blocks = transition, costs, n_blocks
        self.state = self.task.initial_state(n_blocks)
        best = self.task.plan(self.state, transition, costs)
        self.best_loads = list(best.loads)
        self.best_value = float(best.expected_utility)
        self._cache: dict[tuple[int, ...], bool] = {}

    def value(self, loads: Sequence[int]) -> float:
        return self.task.expected_utility(self.state, self.task.actions_for_loads(self.n_blocks, loads),
                                          self.T, self.costs)

    def __call__(self, loads: Sequence[int]) -> bool | None:
        key = tuple(int(k) for k in loads)
        if sum(key) != self.n_blocks or any(k < 1 for k in key):
            return None if not key else False
        if key not in self._cache:
            tol = 1e-6 * max(1.0, abs(self.best_value))
            self._cache[key] = abs(self.value(key) - self.best_value) <= tol
        return self._cache[key]

