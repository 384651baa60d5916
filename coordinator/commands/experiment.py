"""`tmoc experiment NAME`: one of the paper's simulation experiments, runs in parallel on Ray,
resumable, writing DIR/NAME.png, DIR/NAME.csv and DIR/NAME.json."""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from pydantic import ValidationError

from . import UsageError

_FLAGS = {"particles": "--particles", "episodes": "--episodes", "seed": "--seed",
          "max_steps": "--max-steps", "true_size": "--true-size", "robot": "--robot"}


def register(sub) -> None:
    from ..experiments import (DEFAULT_PROBE_TRIALS, DEFAULT_SCALE, EXPERIMENT_TRUE_SIZE, EXPERIMENTS,
                               PAPER_SCALE)

    defaults = "; ".join(f"{n}: {d['runs']} runs x {d['episodes']} episodes, N {d['particles']}"
                         for n, d in DEFAULT_SCALE.items())
    p = sub.add_parser(
        "experiment", help="reproduce a paper experiment: " + " | ".join(EXPERIMENTS),
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=("Runs every setting of the experiment `runs` times (seeded, independent, one "
                     "Ray task and one CPU per run), keeps finished runs in DIR/runs/ and writes "
                     "DIR/NAME.png, DIR/NAME.csv and DIR/NAME.json.\n\n"
                     f"Default scale (each < 30 min on 2 cores, but weights: 36 min measured): {defaults}.\n"
                     f"--scale paper: {PAPER_SCALE['runs']} runs x {PAPER_SCALE['episodes']} "
                     f"episodes, N {PAPER_SCALE['particles']}. Explicit flags win over either."))
    p.add_argument("name", metavar="NAME", help=" | ".join(EXPERIMENTS))
    p.add_argument("--domain", default=None,
                   help="a registered domain (see tmoc domains; default container, and "
                        "stack_and_push for `weights`)")
    p.add_argument("--runs", type=int, default=None, help="independent runs per setting")
    p.add_argument("--episodes", type=int, default=None, help="episodes per run")
    p.add_argument("--particles", type=int, default=None,
                   help="particles N (`particles`: the largest N; the settings are N/4, N/2, 3N/4, N)")
    p.add_argument("--seed", type=int, default=0, help="experiment seed S (run seeds derive from it)")
    p.add_argument("--particle-budget", default="fixed", choices=("fixed", "kld"),
                   help="fixed: N particles every action; kld: as many as the posterior's spread "
                        "needs, from --min-particles up to N")
    p.add_argument("--min-particles", type=int, default=8, help="the kld budget's floor")
    p.add_argument("--scale", default="default", help="default | paper")
    p.add_argument("--max-steps", type=int, default=60, help="action limit per episode")
    p.add_argument("--true-size", type=float, default=None,
                   help=f"hidden block size (m; default {EXPERIMENT_TRUE_SIZE}, off the prior mean "
                        "0.045 on purpose: see docs/RESULTS.md; `weights`: 0.045, so that only "
                        "the mass is off for TMP-RL; `compare`: one size per run, drawn across the "
                        "prior, each judged against its own T*, unless this fixes one)")
    p.add_argument("--milestones", default=None,
                   help="`milestones`: comma-separated episodes (default: 5 evenly spaced)")
    p.add_argument("--probe-trials", type=int, default=None,
                   help=f"seeded trials per probe when estimating the true T (cached in DIR/true_T.json; "
                        f"default {DEFAULT_PROBE_TRIALS}, `sweep`: 10 per truth, in DIR/true_T/)")
    p.add_argument("--probe-seed", type=int, default=0, help="seed of the T* probes")
    p.add_argument("--probe-perception", type=float, default=0.0, metavar="M",
                   help="T*'s probes plan each action from positions perceived with this std (m), "
                        "as the runs' robot does (e.g. 0.002, the simulated reality's camera; "
                        "default 0: the exact positions)")
    p.add_argument("--checkpoint-s", type=float, default=60.0,
                   help="seconds between a running run's checkpoints (kept for --resume)")
    p.add_argument("--engine", default=None, metavar="pybullet|mujoco",
                   help="the particle worlds' physics engine (default: pybullet where installed, else mujoco)")
    p.add_argument("--reality-engine", default=None, metavar="pybullet|mujoco",
                   help="the simulated reality's engine (and T*'s probes); another than --engine's is "
                        "a simulator that is not reality")
    p.add_argument("--robot", default=None, metavar="NAME",
                   help="the robot every run drives (gripper | ur5e | a plugin's; default gripper): an arm "
                        "plans joint trajectories, and the simulated reality is that arm (`tmoc robots`)")
    p.add_argument("--set", action="append", default=None, metavar="KEY=VALUE", dest="run_fields",
                   help="a RunConfig field for every run (repeatable), e.g. sensor_noise=2 or "
                        "recovery=prior (tmoc run --print-config lists them)")
    p.add_argument("--ray-address", default=None, help="join a running Ray cluster")
    p.add_argument("--out", default="runs/experiments", help="output directory DIR")
    p.add_argument("--resume", action="store_true", help="reuse the finished runs in DIR/runs")
    p.add_argument("--log-to", default=None, metavar="tensorboard:DIR",
                   help="also log every run's episodes to TensorBoard event files in DIR/<setting>/run<r> "
                        "(needs tmoc-service[tracker])")
    p.add_argument("--no-progress", action="store_true")
    p.set_defaults(func=main)


def _int_at_least(value, flag: str, low: int, high: int | None = None) -> int:
    if value < low or (high is not None and value > high):
        rng = f">= {low}" if high is None else f"in [{low}, {high}]"
        raise UsageError(f"{flag}: must be {rng} (got {value})")
    return value


def _engine(value: str | None, flag: str) -> str | None:
    """A known, installed engine, or None (the default); UsageError naming `flag`."""
    if value is None:
        return None
    from sim_workers.engines import EngineError, check_engine

    try:
        return check_engine(value, flag)
    except EngineError as exc:
        raise UsageError(str(exc)) from None


def _with_robot(fields: dict, name: str | None) -> dict:
    """`fields` with ``--robot``'s robot (also spelt ``--set robot=NAME``; both: one name)."""
    if name is None:
        return fields
    if fields.get("robot", name) != name:
        raise UsageError(f"--robot: {name!r} and --set robot={fields['robot']!r} disagree")
    return {**fields, "robot": name}


def _run_fields(items: list[str] | None) -> dict:
    """``--set KEY=VALUE`` items as RunConfig fields (values read as JSON, else text);
    ``--set options.KEY=VALUE`` sets one domain option (as `tmoc run --option KEY=VALUE`)."""
    from ..run_config import RunConfig
    from .run import parse_options

    try:
        fields = parse_options(items)
    except UsageError as exc:
        raise UsageError(str(exc).replace("--option", "--set", 1)) from None
    options = {k.removeprefix("options."): fields.pop(k) for k in [k for k in fields if k.startswith("options.")]}
    if options:
        if not isinstance(fields.get("options", {}), dict):
            raise UsageError("--set options: expected options.KEY=VALUE")
        fields["options"] = {**fields.get("options", {}), **options}
    unknown = sorted(set(fields) - set(RunConfig.model_fields))
    if unknown:
        raise UsageError(f"--set: {unknown[0]} is not a RunConfig field (tmoc run --print-config lists them)")
    return fields


def spec_from_args(args):
    from .. import experiments as ex

    if args.name not in ex.EXPERIMENTS:
        raise UsageError(f"NAME: unknown experiment {args.name!r} (known: {', '.join(ex.EXPERIMENTS)})")
    from ..domains import names as domain_names

    entry = ex.REGISTRY[args.name]
    if args.domain is None:
        args.domain = entry.domain
    across = entry.truths_across_prior and args.true_size is None
    if args.true_size is None:
        args.true_size = entry.true_size
    if args.domain not in domain_names():
        raise UsageError(f"--domain: unknown domain {args.domain!r} (known: {', '.join(domain_names())})")
    if args.scale not in ("default", "paper"):
        raise UsageError(f"--scale: must be default or paper (got {args.scale!r})")
    base = (entry.paper_scale or ex.PAPER_SCALE) if args.scale == "paper" else ex.DEFAULT_SCALE[args.name]
    runs = _int_at_least(args.runs if args.runs is not None else base["runs"], "--runs", 1, 10000)
    episodes = args.episodes if args.episodes is not None else base["episodes"]
    particles = args.particles if args.particles is not None else base["particles"]
    _int_at_least(episodes, "--episodes", 1)
    _int_at_least(particles, "--particles", 1)
    _int_at_least(args.seed, "--seed", 0)
    if args.probe_trials is None:
        from ..experiments.sweep import SWEEP_PROBE_TRIALS

        args.probe_trials = SWEEP_PROBE_TRIALS if args.name == "sweep" else ex.DEFAULT_PROBE_TRIALS
    _int_at_least(args.probe_trials, "--probe-trials", 1, 100000)
    _int_at_least(args.probe_seed, "--probe-seed", 0)
    perception = getattr(args, "probe_perception", 0.0)
    if not 0.0 <= perception <= 0.05:
        raise UsageError(f"--probe-perception: must be in [0, 0.05] m (got {perception})")
    if not args.checkpoint_s > 0:
        raise UsageError(f"--checkpoint-s: must be > 0 (got {args.checkpoint_s})")
    if args.milestones is None:
        milestones = ex.default_milestones(episodes)
    else:
        try:
            milestones = tuple(sorted({int(v) for v in args.milestones.split(",") if v.strip()}))
        except ValueError:
            raise UsageError(f"--milestones: expected comma-separated episodes "
                             f"(got {args.milestones!r})") from None
        if not milestones or milestones[0] < 1 or milestones[-1] > episodes:
            raise UsageError(f"--milestones: episodes must lie in [1, --episodes={episodes}] "
                             f"(got {args.milestones!r})")
    spec = ex.Spec(name=args.name, runs=runs, episodes=episodes, particles=particles, seed=args.seed,
                   max_steps=args.max_steps, true_size=args.true_size, milestones=milestones,
                   probe_trials=args.probe_trials, probe_seed=args.probe_seed, probe_perception=perception,
                   scale=args.scale,
                   settings=ex.settings_for(args.name, particles, args.domain, args.scale), domain=args.domain,
                   particle_budget=args.particle_budget,
                   min_particles=_int_at_least(args.min_particles, "--min-particles", 1),
                   truths=(ex.prior_truths(args.domain, runs, args.seed, ex.EXPERIMENTS.index(args.name))
                           if across else ()),
                   engine=_engine(args.engine, "--engine"),
                   reality_engine=_engine(args.reality_engine, "--reality-engine"),
                   run_fields=_with_robot(_run_fields(getattr(args, "run_fields", None)),
                                          getattr(args, "robot", None)))
    try:       # every run's config must validate before anything starts
        for k in range(len(spec.settings)):
            ex.run_config(spec, k, 0)
    except ValidationError as exc:
        err = exc.errors()[0]
        field = str(err["loc"][0]) if err["loc"] else ""
        if args.name == "weights" and ("options." in err["msg"] or "truth." in err["msg"]):
            raise UsageError(f"--domain: the weights experiment needs density in L, which "
                             f"{args.domain!r} does not have ({err['msg'].removeprefix('Value error, ')})") from None
        msg = err["msg"].removeprefix("Value error, ")
        named, _, rest = msg.partition(": ")
        if not field and named in _FLAGS:          # a check across fields names its field first
            raise UsageError(f"{_FLAGS[named]}: {rest}") from None
        raise UsageError(f"{_FLAGS.get(field, '--' + field.replace('_', '-'))}: {err['msg']} "
                         f"(got {err.get('input')!r})") from None
    return spec


def main(args) -> int:
    from .. import experiments as ex

    spec = spec_from_args(args)
    out = Path(args.out)
    if not args.resume:
        found = ex.existing_runs(out, spec)
        if found:
            raise UsageError(f"--resume: {out} already holds {len(found)} run files of "
                             f"`{spec.name}` (e.g. {found[0]}); pass --resume to reuse them, "
                             "or choose another --out")
    from ..distributed.fanout import init_ray

    if args.log_to is not None:
        from ..integrations.tracker import TrackerError, parse_log_to

        try:
            parse_log_to(args.log_to)
            import tensorboard  # noqa: F401
        except TrackerError as exc:
            raise UsageError(f"--log-to: {exc}") from None
        except ImportError:
            raise UsageError("--log-to: tensorboard is not installed: pip install 'tmoc-service[tracker]'") from None
    init_ray(args.ray_address)
    try:
        done = ex.execute(spec, out, resume=args.resume, progress=not args.no_progress,
                          checkpoint_s=args.checkpoint_s, log_to=args.log_to)
    except ex.ResumeError as exc:
        raise UsageError(f"--resume: {exc}; choose another --out") from None
    except KeyboardInterrupt:
        print(f"tmoc experiment: interrupted; finished runs (and checkpoints of running ones) "
              f"are kept in {out / 'runs'}: continue with the same command plus --resume",
              file=sys.stderr)
        return 130
    summary = json.loads(Path(done["json"]).read_text())
    if spec.name == "sweep":
        print(json.dumps({**done, "summary": summary["summary"]}, indent=2))
        print(Path(done["md"]).read_text())
        return 0
    print(json.dumps({**done, "settings": {
        k: {key: v[key] for key in ("mean_utility_last_fifth", "episodes_to_converge",
                                    "final_posterior_error_mm", "optimal_plans_pct_last_fifth",
                                    "successful_actions_pct_last_fifth")}
        for k, v in summary["settings"].items()}}, indent=2))
    return 0
