"""`tmoc run`: one task on local Ray (or a cluster), a progress bar, result.json and curve.png."""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from pydantic import ValidationError

from ..cli import UsageError
from ..run_config import RunConfig


def register(sub) -> None:
    p = sub.add_parser("run", help="run one task (TMOC or a baseline) and write result.json + curve.png",
                       formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    d = RunConfig()
    p.add_argument("--domain", default=d.domain)
    p.add_argument("--agent", default=d.agent, help="tmoc | tmp_rl | gp | toep")
    p.add_argument("--particles", type=int, default=d.particles)
    p.add_argument("--episodes", type=int, default=d.episodes)
    p.add_argument("--seed", type=int, default=d.seed)
    p.add_argument("--true-size", type=float, default=d.true_size, help="hidden block size (m)")
    p.add_argument("--sizes-variation", action="store_true", help="one block 20%% larger")
    p.add_argument("--likelihood", default=d.likelihood, help="replay | paper")
    p.add_argument("--max-steps", type=int, default=d.max_steps)
    p.add_argument("--shards", type=int, default=None, help="shard actors (default: one per CPU)")
    p.add_argument("--ray-address", default=None, help="join a running Ray cluster")
    p.add_argument("--out", default="runs/latest", help="output directory")
    p.add_argument("--no-progress", action="store_true")
    p.set_defaults(func=main)


def _config(args) -> RunConfig:
    try:
        return RunConfig(domain=args.domain, agent=args.agent, particles=args.particles,
                         episodes=args.episodes, seed=args.seed, true_size=args.true_size,
                         sizes_variation=args.sizes_variation, likelihood=args.likelihood,
                         max_steps=args.max_steps, shards=args.shards)
    except ValidationError as exc:
        err = exc.errors()[0]
        field = "--" + str(err["loc"][0]).replace("_", "-")
        raise UsageError(f"{field}: {err['msg']} (got {err.get('input')!r})") from None


def main(args) -> int:
    config = _config(args)
    from ..runner import run, write_result
    from tqdm import tqdm

    bar = tqdm(total=config.episodes, desc=f"{config.agent}", unit="ep", disable=args.no_progress)

    def on_episode(record, session, checkpoint):
        post = record["posterior"]
        bar.set_postfix(utility=f"{record['utility']:.0f}", size=f"{post['size_mean'] * 1000:.1f}mm",
                        spread=f"{post['size_std'] * 1000:.1f}mm", loads=record["loads"])
        bar.update(1)

    result = run(config, ray_address=args.ray_address, on_episode=on_episode)
    bar.close()
    path, png = write_result(result, Path(args.out))
    print(json.dumps({"summary": result["summary"], "runtime": result["runtime"],
                      "result": str(path), "plot": str(png)}, indent=2))
    return 0
