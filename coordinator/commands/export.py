"""`tmoc export`: a finished run directory, or a task or robot session of a running service,
as MCAP (coordinator/export.py: per step the action, the commanded trajectory, the
observed configurations before and after, the measurements, the outcome and the belief).

    tmoc export runs/latest -o run.mcap
    tmoc export --server http://127.0.0.1:8000 --session SESSION_ID -o robot.mcap

The token for a server comes from --token or TMOC_API_TOKEN.
"""
from __future__ import annotations

import argparse
import json
import os
import time
import urllib.error
import urllib.request
from pathlib import Path

from . import UsageError

TIMEOUT_S = 300.0
BUSY_RETRIES = 12          # 429 (the server's export builds are busy): wait Retry-After, retry


def register(sub) -> None:
    p = sub.add_parser("export", help="a run, task or robot session as MCAP",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("run_dir", nargs="?", help="a `tmoc run --out` directory")
    p.add_argument("-o", "--out", required=True, help="the MCAP file to write")
    p.add_argument("--server", help="a running `tmoc serve` (its base URL)")
    which = p.add_mutually_exclusive_group()
    which.add_argument("--task", help="a task of --server")
    which.add_argument("--session", help="a robot session of --server")
    p.add_argument("--token", default=None, help="the server's API token (default: $TMOC_API_TOKEN)")
    p.set_defaults(func=main)


def _download(server: str, kind: str, ident: str, token: str | None, out: Path) -> None:
    url = f"{server.rstrip('/')}/v1/{kind}s/{urllib.request.quote(ident, safe='')}/export"
    req = urllib.request.Request(url, headers={"Authorization": f"Bearer {token}"} if token else {})
    try:
        for attempt in range(BUSY_RETRIES + 1):
            try:
                # The server streams the MCAP as it writes it; the timeout is per read.
                with urllib.request.urlopen(req, timeout=TIMEOUT_S) as resp, open(out, "wb") as f:
                    while block := resp.read(1 << 16):
                        f.write(block)
                return
            except urllib.error.HTTPError as exc:
                if exc.code != 429 or attempt == BUSY_RETRIES:
                    raise
                time.sleep(min(float(exc.headers.get("Retry-After") or 5), 30.0))   # builds are busy
    except urllib.error.HTTPError as exc:
        detail = exc.read().decode("utf-8", "replace")[:300]
        raise UsageError(f"--{kind}: {url} answered {exc.code}: {detail}") from None
    except (urllib.error.URLError, OSError) as exc:
        raise UsageError(f"--server: cannot fetch {url}: {getattr(exc, 'reason', exc)}") from None


def _counts(path: Path) -> dict:
    """Messages per topic, read back from the file's own summary."""
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    if summary is None or summary.statistics is None:
        return {}
    topics = {cid: ch.topic for cid, ch in summary.channels.items()}
    return {topics[c]: n for c, n in summary.statistics.channel_message_counts.items()}


def main(args) -> int:
    from ..integrations.export import ExportError, export_run

    out = Path(args.out)
    remote = args.task or args.session
    if args.server and not remote:
        raise UsageError("--server: name a --task or a --session to export")
    if remote and not args.server:
        raise UsageError(f"--{'task' if args.task else 'session'}: needs --server (the service holding it)")
    if remote and args.run_dir:
        raise UsageError("run_dir: give a run directory or --server with --task/--session, not both")
    if not remote and not args.run_dir:
        raise UsageError("run_dir: give a `tmoc run --out` directory (or --server with --task/--session)")
    if not out.parent.exists():
        raise UsageError(f"--out: {out.parent} does not exist")
    if remote:
        kind = "task" if args.task else "session"
        _download(args.server, kind, remote, args.token or os.environ.get("TMOC_API_TOKEN"), out)
    else:
        try:
            export_run(args.run_dir, out)
        except ExportError as exc:
            raise UsageError(f"run_dir: {exc}") from None
    print(json.dumps({"out": str(out), "messages": _counts(out)}, indent=2))
    return 0
