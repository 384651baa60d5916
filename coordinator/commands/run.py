"""`tmoc run`: one task on local Ray (or a cluster), a progress bar, result.json and curve.png."""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from pydantic import ValidationError

from . import UsageError
from ..run_config import RunConfig
from ..loop.step_record import STEPS_FILE


# Flags and the RunConfig fields they set (the rest, e.g. pose_rule or error_rate, come from
# --config FILE).
_FLAG_FIELDS = {"domain": "--domain", "agent": "--agent", "particles": "--particles",
                "episodes": "--episodes", "seed": "--seed", "true_size": "--true-size",
                "sizes_variation": "--sizes-variation", "likelihood": "--likelihood",
                "max_steps": "--max-steps", "shards": "--shards", "truth": "--truth",
                "options": "--option", "particle_budget": "--particle-budget",
                "min_particles": "--min-particles", "reality_fail": "--reality-fail",
                "engine": "--engine", "reality_engine": "--reality-engine",
                "sensor_noise": "--sensor-noise", "sensor_bias": "--sensor-bias",
                "sensor_tails": "--sensor-tails", "perception_sigma": "--perception-sigma",
                "n_blocks": "--objects", "counterfactual_rows": "--counterfactual", "robot": "--robot"}


def register(sub) -> None:
    p = sub.add_parser("run", help="run one task (TMOC or a baseline) and write result.json + curve.png",
                       formatter_class=argparse.ArgumentDefaultsHelpFormatter,
                       description="Settings come from the defaults, then --config FILE, then the "
                                   "flags given (flags win). --print-config prints the result.")
    d = RunConfig()
    # Defaults are None here so that a flag given can be told from a flag left out (the
    # help shows RunConfig's default).
    p.add_argument("--config", default=None, metavar="FILE",
                   help="every RunConfig setting from a JSON or YAML file (flags override)")
    p.add_argument("--print-config", action="store_true",
                   help="print the resulting settings as JSON and exit (a --config FILE to start from)")
    p.add_argument("--domain", default=None, help=f"registered domain (default {d.domain})")
    p.add_argument("--agent", default=None, help=f"tmoc | tmp_rl | gp | toep (default {d.agent})")
    p.add_argument("--particles", type=int, default=None,
                   help=f"particles (with --particle-budget kld: the most) (default {d.particles})")
    p.add_argument("--particle-budget", default=None, metavar="fixed|kld",
                   help=f"fixed: --particles for every action; kld: as many as the posterior's "
                        f"spread needs (KLD-sampling), from --min-particles up (default {d.particle_budget})")
    p.add_argument("--min-particles", type=int, default=None,
                   help=f"the kld budget's floor (at most --particles) (default {d.min_particles})")
    p.add_argument("--episodes", type=int, default=None, help=f"(default {d.episodes})")
    p.add_argument("--seed", type=int, default=None, help=f"(default {d.seed})")
    p.add_argument("--objects", "--n-objects", "--blocks", type=int, default=None, dest="n_blocks",
                   metavar="N", help="objects in the scene (default: the domain's own count, "
                                     "tmoc domains; 8 for the built-in block worlds)")
    p.add_argument("--true-size", type=float, default=None, help=f"hidden block size, m (default {d.true_size})")
    p.add_argument("--truth", action="append", default=None, metavar="NAME=VALUE[,NAME=VALUE]",
                   help="the hidden truth by the names of L (tmoc domains), e.g. size=0.04,density=2400")
    p.add_argument("--option", action="append", default=None, metavar="KEY=VALUE", dest="options",
                   help="a domain option (repeatable), e.g. unknown_density=true or force_sigma=0.1")
    p.add_argument("--sizes-variation", action="store_true", default=None, help="one block 20%% larger")
    p.add_argument("--likelihood", default=None, help=f"replay | paper (default {d.likelihood})")
    p.add_argument("--max-steps", type=int, default=None, help=f"(default {d.max_steps})")
    p.add_argument("--reality-fail", default=None, metavar="ACTION:K",
                   help="a reality gap the particle worlds do not know: every ACTION in a T context "
                        ">= K fails in the simulated reality only, e.g. stack:3")
    p.add_argument("--engine", default=None, metavar="pybullet|mujoco|mujoco_warp",
                   help="the particle worlds' physics engine (default: pybullet where installed, else mujoco; "
                        "mujoco_warp: each shard's particles as one MuJoCo Warp batch, the [warp] extra)")
    p.add_argument("--reality-engine", default=None, metavar="pybullet|mujoco",
                   help="the simulated reality's physics engine (default: as --engine's default); "
                        "another engine than --engine's is a simulator that is not reality")
    p.add_argument("--sensor-noise", type=float, default=None, metavar="X",
                   help=f"the simulated reality's sensor noise: each weighed channel's std in multiples "
                        f"of its declared sigma; 0: exact readings (default {d.sensor_noise:g})")
    p.add_argument("--sensor-bias", type=float, default=None, metavar="X",
                   help=f"a constant offset of each weighed reading, in declared sigmas "
                        f"(default {d.sensor_bias:g})")
    p.add_argument("--sensor-tails", default=None, metavar="gaussian|student_t",
                   help=f"the sensor noise's shape; student_t: Student-t with 3 dof at the same std "
                        f"(default {d.sensor_tails})")
    p.add_argument("--perception-sigma", type=float, default=None, metavar="M",
                   help=f"std (m) of the simulated reality's perceived planar object positions; "
                        f"0: exact (default {d.perception_sigma:g})")
    p.add_argument("--counterfactual", type=int, default=None, metavar="M", dest="counterfactual_rows",
                   help=f"counterfactual experience: before each episode's first plan, M rows drawn from "
                        f"the belief each simulate every context the domain declares, and T learns from "
                        f"them (a power prior per action family); 0: off, the paper's loop "
                        f"(default {d.counterfactual_rows})")
    p.add_argument("--robot", default=None, metavar="NAME",
                   help=f"the robot that moves the tool (`tmoc robots`): gripper, the floating gripper, or an "
                        f"arm such as ur5e, which gets a joint trajectory per step (default {d.robot})")
    p.add_argument("--shards", type=int, default=None, help="shard actors (default: one per CPU)")
    p.add_argument("--ray-address", default=None, help="join a running Ray cluster")
    p.add_argument("--out", default="runs/latest", help="output directory")
    p.add_argument("--frames", action="store_true",
                   help="also write scene pictures (PNG) to OUT/frames/: the real world at the end of "
                        "every episode and every failed action beside what particles predicted")
    p.add_argument("--log-to", default=None, metavar="tensorboard:DIR",
                   help="also log every episode to an experiment tracker: TensorBoard event files in "
                        "DIR (utility, failures, particles, the posterior of L, T per context; needs "
                        "tmoc-service[tracker])")
    p.add_argument("--no-progress", action="store_true")
    p.set_defaults(func=main)


# A settings file is a few hundred bytes; anything near this is not one.
CONFIG_MAX_BYTES = 1 << 20


def _yaml_without_aliases(text: str):
    """YAML as safe_load reads it, but refusing aliases: a few hundred bytes of nested
    aliases expand to gigabytes (issue 25: 349 bytes, 11 s and 830 MB); settings need none."""
    import yaml

    class Loader(yaml.SafeLoader):
        def compose_node(self, parent, index):
            if self.check_event(yaml.AliasEvent):
                mark = self.peek_event().start_mark
                raise yaml.YAMLError(f"line {mark.line + 1}: aliases (*name) are not allowed in settings")
            return super().compose_node(parent, index)

    return yaml.load(text, Loader=Loader)  # noqa: S506 - a SafeLoader subclass


def _config_file(path: str) -> dict:
    """The settings in a JSON or YAML file (a mapping); UsageError naming the file otherwise."""
    try:
        with open(path, "rb") as f:
            raw = f.read(CONFIG_MAX_BYTES + 1)
    except OSError as exc:
        raise UsageError(f"--config {path}: cannot read it ({exc.strerror})") from None
    if len(raw) > CONFIG_MAX_BYTES:
        raise UsageError(f"--config {path}: over {CONFIG_MAX_BYTES} bytes; not a settings file")
    try:
        text = raw.decode("utf-8")
        if path.endswith((".yaml", ".yml")):
            data = _yaml_without_aliases(text)
        else:
            data = json.loads(text)
    except Exception as exc:  # noqa: BLE001 - any parse error is the user's file
        raise UsageError(f"--config {path}: not valid {'YAML' if path.endswith(('.yaml', '.yml')) else 'JSON'} "
                         f"({str(exc).splitlines()[0]})") from None
    if not isinstance(data, dict):
        raise UsageError(f"--config {path}: expected a mapping of settings, got {type(data).__name__}")
    return data


def parse_truth(items: list[str] | None) -> dict[str, float]:
    """``["size=0.04,density=2400", ...]`` -> {"size": 0.04, "density": 2400.0}."""
    out: dict[str, float] = {}
    for item in items or []:
        for pair in filter(None, item.split(",")):
            name, sep, value = pair.partition("=")
            if not sep or not name.strip():
                raise UsageError(f"--truth {pair}: expected NAME=VALUE")
            try:
                out[name.strip()] = float(value)
            except ValueError:
                raise UsageError(f"--truth {pair}: {value!r} is not a number") from None
    return out


def parse_options(items: list[str] | None) -> dict:
    """``["unknown_density=true", "force_sigma=0.1"]`` -> {"unknown_density": True,
    "force_sigma": 0.1}: a value is read as JSON (true, 3, 0.1, null), else kept as text."""
    out: dict = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise UsageError(f"--option {item}: expected KEY=VALUE")
        try:
            parsed = json.loads(value)
        except ValueError:
            parsed = value
        if isinstance(parsed, (list, dict)):
            raise UsageError(f"--option {item}: expected a single value")
        out[key.strip()] = parsed
    return out


def _config(args) -> RunConfig:
    from_file = _config_file(args.config) if args.config else {}
    from_flags = {f: getattr(args, f) for f in _FLAG_FIELDS if getattr(args, f, None) is not None}
    if "n_blocks" in from_flags:          # the flag wins over the file's count by either name
        from_file = {k: v for k, v in from_file.items() if k not in ("n_blocks", "n_objects")}
    if "truth" in from_flags:
        from_flags["truth"] = {**from_file.get("truth", {}), **parse_truth(from_flags["truth"])}
    if "options" in from_flags:
        from_flags["options"] = {**from_file.get("options", {}), **parse_options(from_flags["options"])}
    try:
        return RunConfig(**{**from_file, **from_flags})
    except ValidationError as exc:
        err = exc.errors()[0]
        loc = [str(x) for x in err["loc"]]
        msg = err["msg"].removeprefix("Value error, ")
        for field, flag in (("truth", "--truth"), ("options", "--option")):
            if not loc and msg.startswith(f"{field}.") and field in from_flags:
                raise UsageError(f"{flag}: {msg}") from None
        if not loc and msg.startswith("reality_fail: ") and "reality_fail" in from_flags:
            raise UsageError(f"--reality-fail: {msg.removeprefix('reality_fail: ')}") from None
        if not loc and msg.startswith(("truth", "options")):
            raise UsageError(f"{'--config ' + args.config + ': ' if args.config else ''}{msg}") from None
        if loc and loc[0] in from_flags:
            where = _FLAG_FIELDS[loc[0]]
        elif args.config:
            where = f"--config {args.config}: {'.'.join(loc) or 'settings'}"
        else:
            where = "--" + (loc[0] if loc else "settings").replace("_", "-")
        got = repr(err.get("input"))
        got = got if len(got) <= 80 else got[:77] + "..."       # never the whole input back
        raise UsageError(f"{where}: {err['msg']} (got {got})") from None


def main(args) -> int:
    config = _config(args)
    if args.frames:
        from sim_workers.engines import installed

        if not installed("pybullet"):
            raise UsageError("--frames: the pictures are drawn by pybullet's TinyRenderer, which is not "
                             "installed (pip install pybullet, where it builds), or leave --frames out")
    tracker = None
    if getattr(args, "log_to", None):
        from ..integrations.tracker import TrackerError, open_tracker

        try:
            tracker = open_tracker(args.log_to)
        except TrackerError as exc:
            raise UsageError(f"--log-to: {exc}") from None
    if args.print_config:
        print(json.dumps(config.model_dump(mode="json"), indent=2))
        return 0
    from ..loop.observer import StepLog
    from ..loop.runner import run, write_result
    from tqdm import tqdm

    bar = tqdm(total=config.episodes, desc=f"{config.agent}", unit="ep", disable=args.no_progress)
    # Every real step, as it happened (coordinator/step_record.py): `tmoc export` reads it.
    Path(args.out).mkdir(parents=True, exist_ok=True)
    steps_file = open(Path(args.out) / STEPS_FILE, "w", encoding="utf-8")

    def write_steps(records: list[dict]) -> None:
        for step in records:
            steps_file.write(json.dumps(step, separators=(",", ":")) + "\n")
        steps_file.flush()

    def on_episode(record, session, checkpoint):
        post = record["posterior"]
        counts = record.get("particles_per_action") or [0]
        if "size_mean" in post:
            shown = {"size": f"{post['size_mean'] * 1000:.1f}mm", "spread": f"{post['size_std'] * 1000:.1f}mm"}
        else:                       # a domain without a size: its first property of L
            name, p = next(iter(post["properties"].items()))
            shown = {name: f"{p['mean']:.3g}", "spread": f"{p['std']:.2g}"}
        bar.set_postfix(utility=f"{record['utility']:.0f}", **shown, loads=record["loads"],
                        particles=f"{min(counts)}-{max(counts)}" if min(counts) != max(counts) else counts[0])
        if record.get("transit_fallbacks"):       # an unchecked transit must not go unnoticed
            bar.write(f"episode {record['episode']}: {record['transit_fallbacks']} action(s) without a "
                      f"checked transit: {record['transit_fallback_notes'][0]}", file=sys.stderr)
        bar.update(1)

    sink = None
    if args.frames:
        from ..integrations.frames import DirectorySink

        sink = DirectorySink(Path(args.out) / "frames")
    try:
        # The steps file, TensorBoard and the progress bar all watch the run as its observers.
        observers = [StepLog(write_steps)] + ([tracker] if tracker is not None else [])
        result = run(config, ray_address=args.ray_address, on_episode=on_episode, frames=sink,
                     observers=observers)
    finally:
        steps_file.close()
        if tracker is not None:
            tracker.close()
    bar.close()
    path, png = write_result(result, Path(args.out))
    out = {"summary": result["summary"], "runtime": result["runtime"], "result": str(path), "plot": str(png),
           "steps": str(Path(args.out) / STEPS_FILE)}
    if sink is not None:
        out["frames"] = {"folder": str(sink.folder), "count": len(sink.index)}
    print(json.dumps(out, indent=2))
    return 0
