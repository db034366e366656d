"""The ROS domains the scenario runner starts controllers in are reserved on the machine: two
runners at once (other users', CI jobs', test runs') never share one, whatever they prefer. Two
rigs in one domain see each other's /clock (the second rig node refuses to start) and
controllers: that is how a directory run failed while another run was under way beside it."""
from __future__ import annotations

import subprocess
import sys

from pcv_sim.commands.scenario import DOMAINS

# Reserves a domain (preferring argv[1]), prints it, forks a child that reserves one too and
# prints it, and both hold them until stdin closes.
HOLDER = """
import multiprocessing, sys
from pcv_sim.commands.scenario import reserve_domain

def child(q, done):
    q.put(reserve_domain(int(sys.argv[1])))
    done.wait(60)

mine = reserve_domain(int(sys.argv[1]))
assert reserve_domain(int(sys.argv[1]) + 5) == mine        # one per process, kept
ctx = multiprocessing.get_context("fork")
q, done = ctx.Queue(), ctx.Event()
p = ctx.Process(target=child, args=(q, done))
p.start()
print(mine, q.get(timeout=60), flush=True)
sys.stdin.read()
done.set()
p.join()
"""


def hold(preferred: int) -> tuple[subprocess.Popen[str], list[int]]:
    proc = subprocess.Popen([sys.executable, "-c", HOLDER, str(preferred)], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    return proc, [int(x) for x in proc.stdout.readline().split()]


def test_runners_at_once_never_share_a_domain_whatever_they_prefer() -> None:
    procs = []
    try:
        seen: list[int] = []
        for _ in range(3):                    # all prefer the same one
            proc, domains = hold(3)
            procs.append(proc)
            assert len(domains) == 2, domains
            seen += domains
        assert len(set(seen)) == len(seen), seen          # the forked children's too
        assert all(d in DOMAINS for d in seen)
    finally:
        for p in procs:
            p.communicate("", timeout=60)
    assert all(p.returncode == 0 for p in procs)
