"""Executing an experiment on the Ray cluster: one Ray task per run, progress and
checkpoints through a small actor, run files written as runs finish.

How runs share the cluster's CPUs. Every run is one Ray task that reserves one CPU and
simulates its particles in-process (``ShardPool(n_shards=0)``), so as many runs go at once
as the cluster has CPUs, and no run pays Ray's fan-out round trips. Results do not depend
on where or with how many shards particles run (docs/LOOP.md, Determinism), so a run gives the
same episodes here as under ``tmoc run``. Runs are submitted most expensive first
(episodes x particles), which packs them well onto few CPUs. The cost of this choice: one
run never uses more than one CPU, so a cluster with more CPUs than ``settings x runs``
leaves some idle, and a run's wall time is its whole serial cost.

A long run also sends its checkpoint to the driver every ``checkpoint_s`` seconds, kept as
``<r>.partial.json``; ``--resume`` continues it from there with the same episodes as an
uninterrupted run.

The sweep's runs also keep their step records (``coordinator.loop.step_record``, as ``tmoc run``
writes them to steps.jsonl: ``tails.run_tails`` counts failure loops from them, an
offline judge can re-filter them) as ``<r>.steps.jsonl`` beside the run file; a checkpoint
carries those of the episodes so far.
"""
from __future__ import annotations

import json
import time
from pathlib import Path

from ..run_config import RunConfig
from .catalogue import Spec, run_config, run_cost
from .analysis import steps_path
from .report import write_outputs
from .runfiles import read_run, run_path, store_checkpoint, store_run, write_atomic
from .true_T import cached_true_T, submit_probes, t_star_files, true_transition


def _run_remote():
    import ray

    @ray.remote(num_cpus=1, max_retries=2)
    def run_task(config: dict, key: str, resume: dict | None, progress, checkpoint_s: float | None,
                 log_to: tuple[str, str] | None = None, keep_steps: bool = False):
        from ..agents import agent_spec
        from ..loop.observer import StepLog
        from ..loop.runner import run
        from ..distributed.shard_pools import ShardPools

        cfg = RunConfig(**config)
        last = [time.monotonic()]
        # The run's step records (a StepLog observer); None where a resumed checkpoint has
        # none (made before they were kept): never a partial list.
        steps = None
        if keep_steps and (resume is None or "steps" in resume):
            steps = StepLog(records=resume["steps"] if resume is not None else None)
        tracker = None
        if log_to is not None:              # (value, run name): one event folder per run
            from ..integrations.tracker import open_tracker

            tracker = open_tracker(*log_to)

        def on_episode(record, session, checkpoint):
            if steps is not None:
                checkpoint["steps"] = steps.records
            send = (checkpoint_s is not None and record["episode"] + 1 < cfg.episodes
                    and time.monotonic() - last[0] >= checkpoint_s)
            if send:
                last[0] = time.monotonic()
            if progress is not None:
                progress.episode.remote(key, checkpoint if send else None)

        # The run's particles stay in this task's process (n_shards=0): the experiment
        # spreads runs, not particles, over the cluster. Ray is already up in a task.
        try:
            with ShardPools(n_shards=0, max_pools=1, own_ray_thread=False) as shard_pools:
                pool = (shard_pools.acquire(cfg.scene)
                        if agent_spec(cfg.agent).learn_belief else None)
                watching = [o for o in (steps, tracker) if o is not None]
                result = run(cfg, pool=pool, on_episode=on_episode, resume=resume, observers=watching)
                if steps is not None:
                    result["steps"] = steps.records
                return result
        finally:
            if tracker is not None:
                tracker.close()

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


def _missing_runs(spec: Spec, out: Path, configs: dict, resume: bool) -> tuple[list, dict, int]:
    """(runs to compute, their checkpoints to resume from, finished runs reused): with
    `resume` a run file of the same config is reused and a checkpoint continued."""
    todo, partials, reused = [], {}, 0
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
    return todo, partials, reused


def execute(spec: Spec, out: Path, *, resume: bool = False, progress: bool = True,
            checkpoint_s: float | None = 60.0, log_to: str | None = None) -> dict:
    """Run every missing run of `spec` on the Ray cluster (already initialised), write run
    files as runs finish, then the CSV, JSON and PNG. Returns what was done. `log_to`
    ("tensorboard:DIR"): each run also logs its episodes to DIR/<setting>/run<r>."""
    import ray
    from tqdm import tqdm

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    configs = {(k, r): run_config(spec, k, r)
               for k in range(len(spec.settings)) for r in range(spec.runs)}
    todo, partials, reused = _missing_runs(spec, out, configs, resume)
    resumed = 0
    done_eps = {kr: partials[kr]["session"]["episode"] if kr in partials else 0 for kr in todo}
    # Most expensive remaining work first: packs the runs well onto few CPUs.
    todo.sort(key=lambda kr: -run_cost(configs[kr]) * (1 - done_eps[kr] / spec.episodes))

    # T*'s probes go out now, beside the runs, to share the cluster's CPUs with them (one
    # T* for most experiments; one per truth for the sweep).
    targets = dict(t_star_files(spec).values())
    probe_refs = {name: None if cached_true_T(out, params, name) is not None else submit_probes(params)
                  for name, params in targets.items()}

    prog = _progress_actor() if todo else None
    task = _run_remote()
    refs = {}
    for k, r in todo:
        cfg = configs[(k, r)]
        resumed += (k, r) in partials
        log = None if log_to is None else (log_to, f"{spec.settings[k].key}/run{r}")
        ref = task.remote(cfg.model_dump(), f"{k}/{r}", partials.get((k, r)), prog, checkpoint_s, log,
                          spec.name == "sweep")
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
                steps = result.pop("steps", None)
                path = steps_path(out, spec.settings[k], r)
                if steps is not None:           # before the run file: a finished run has both
                    write_atomic(path, "".join(json.dumps(s, separators=(",", ":")) + "\n" for s in steps))
                elif path.exists():             # (a stale one of an earlier run)
                    path.unlink()
                store_run(out, spec, k, r, configs[(k, r)], result)
                run_bar.update(1)
            if prog is not None:
                n_eps, checkpoints = ray.get(prog.drain.remote())
                for key, ckpt in checkpoints.items():
                    k, r = (int(v) for v in key.split("/"))
                    store_checkpoint(out, spec.settings[k], r, configs[(k, r)], ckpt)
                ep_bar.update(max(0, min(n_eps, ep_total) - ep_bar.n))
        ep_bar.update(ep_total - ep_bar.n)
        t_stars, cached = {}, True
        for name, params in targets.items():
            refs_of = probe_refs[name]
            t_stars[name], was_cached = true_transition(
                out, params, name=name,
                executor=lambda p, r=refs_of: ray.get(r if r is not None else submit_probes(p)))
            cached = cached and was_cached
    finally:
        run_bar.close()
        ep_bar.close()
        for ref in pending:
            ray.cancel(ref, force=True)
        if prog is not None:
            ray.kill(prog)
    files = write_outputs(spec, out, t_stars)
    return {"computed": len(todo), "resumed_from_checkpoint": resumed, "reused": reused,
            "true_T": "cached" if cached else "estimated",
            "wall_s": time.perf_counter() - t0, **files}

