"""The server's reaper (issue 25): what a killed server started goes with it; a clean exit
leaves everything to the server's own shutdown."""
from __future__ import annotations

import signal
import subprocess
import sys
import time

import pytest

from coordinator.distributed.reaper import CLEAN, alive, descendants, sweep

pytestmark = [pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc"),
              pytest.mark.slow]          # process trees of their own

# A stand-in server: starts a grandchild that would outlive it, then waits.
SERVER = ("import subprocess, sys, time; subprocess.Popen([sys.executable, '-c', "
          "'import time; time.sleep(120)']); time.sleep(120)")


def _server_and_reaper():
    server = subprocess.Popen([sys.executable, "-c", SERVER])
    reaper = subprocess.Popen([sys.executable, "-m", "coordinator.distributed.reaper", str(server.pid)],
                              stdin=subprocess.PIPE)
    t0 = time.monotonic()
    while not descendants(server.pid) and time.monotonic() - t0 < 10:
        time.sleep(0.05)
    kids = descendants(server.pid)
    assert len(kids) == 1, kids
    time.sleep(1.5)                                        # the reaper has noted it
    return server, reaper, kids


def _gone_within(kids: dict[int, int], seconds: float) -> bool:
    t0 = time.monotonic()
    while time.monotonic() - t0 < seconds:
        if not any(alive(p, s) for p, s in kids.items()):
            return True
        time.sleep(0.05)
    return False


def test_a_killed_server_takes_its_descendants_along():
    server, reaper, kids = _server_and_reaper()
    try:
        server.send_signal(signal.SIGKILL)
        server.wait(10)
        reaper.stdin.close()          # the pipe closes as the server's end does at its death
        assert _gone_within(kids, 3.0)
        assert reaper.wait(5) == 0
    finally:
        for pid in kids:
            subprocess.run(["kill", "-9", str(pid)], capture_output=True)


def test_a_clean_exit_leaves_them_to_the_server():
    server, reaper, kids = _server_and_reaper()
    try:
        reaper.stdin.write(CLEAN)
        reaper.stdin.close()
        assert reaper.wait(5) == 0
        server.send_signal(signal.SIGKILL)
        server.wait(10)
        assert not _gone_within(kids, 1.5)              # untouched: not the reaper's to kill
    finally:
        for pid in kids:
            subprocess.run(["kill", "-9", str(pid)], capture_output=True)


# A stand-in for a server whose Ray was still starting: a child that has a child of its
# own, and a second child to spare (the reaper, in `tmoc serve`).
TREE = ("import subprocess, sys, time; c = [sys.executable, '-c', 'import time; time.sleep(120)']; "
        "subprocess.Popen([sys.executable, '-c', 'import subprocess, sys, time; "
        "subprocess.Popen(' + repr(c) + '); time.sleep(120)']); subprocess.Popen(c); time.sleep(120)")


def test_sweep_kills_the_whole_tree_but_what_it_is_told_to_spare():
    server = subprocess.Popen([sys.executable, "-c", TREE])
    try:
        t0 = time.monotonic()
        while len(descendants(server.pid)) < 3 and time.monotonic() - t0 < 10:
            time.sleep(0.05)
        kids = descendants(server.pid)
        assert len(kids) == 3, kids
        children = [p for p in kids if open(f"/proc/{p}/stat").read().split(") ")[1].split()[1]
                    == str(server.pid)]
        spared = max(children, key=lambda p: (len(descendants(p)) == 0, p))   # the childless one
        assert len(descendants(spared)) == 0
        assert sweep(server.pid, exclude={spared}) == 2                       # a child and its child
        assert set(descendants(server.pid)) == {spared}
        assert alive(spared, kids[spared])
        assert sweep(server.pid, exclude={spared}) == 0
    finally:
        for pid in descendants(server.pid):
            subprocess.run(["kill", "-9", str(pid)], capture_output=True)
        server.kill()
        server.wait(10)
