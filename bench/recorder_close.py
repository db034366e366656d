"""Benchmark: how long closing a recording takes on a busy machine (the writer process's close).

    .venv-kilted/bin/python bench/recorder_close.py --load 4 --rounds 6
    .venv-kilted/bin/python bench/recorder_close.py --load 4 --rounds 6 --before /path/to/a/worktree

A node's close (SIGINT) finalises its bag: the writer process writes the ring's backlog and the
MCAP footer, its main thread first taking the lock of its background thread (SCHED_IDLE). Each
measurement is one fresh process: an emulator `DeviceRecorder` with `writer="process"`, 2 s of
1 kHz output samples fed in 0.1 s bursts, then `close()` timed, beside `--load` CPU burners (the
benchmark's own, for the whole run). With `--before TREE` (a git worktree of another commit) the
rounds alternate between that tree's package and this one's, so other load falls on both alike.
Per tree: the close times (median, max), and how many bags were not finished (`failed`: the
writer killed after STALL_TIMEOUT without progress).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import statistics
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent

ONE = """if True:
    import json, sys, tempfile, time
    sys.path.insert(0, sys.argv[1] + '/test')
    from conftest import make_emulator_recorder
    from pcv_sim.io.recorder import WriterSettings

    T0, DT = 1_700_000_000_000_000_000, 100_000

    def signals(k):
        return {'duty_command': .5, 'duty': .5, 'load_flow': 0.0, 'supply_pressure': 200e5, 'pressure': 1e5 + k,
                'current': 1e-3 * k, 'spool_position': 1e-9 * k}

    with tempfile.TemporaryDirectory() as d:
        rec = make_emulator_recorder(d, name='b', every=10, writing=WriterSettings(writer='process'))
        rec.start(T0, signals(0))
        for k in range(1, 20001):
            rec(T0 + k * DT, signals(k))
            if k % 1000 == 0:
                time.sleep(0.05)
        time.sleep(0.3)
        t = time.monotonic()
        st = rec.close()
        print(json.dumps({'close_s': time.monotonic() - t, 'state': st.state, 'messages': st.messages}))
"""


def measure(tree: Path) -> dict[str, float | str]:
    env = {k: v for k, v in os.environ.items() if k != "_ROS_WHEELS_BOOTSTRAP_COMPLETE"}
    env["PYTHONPATH"] = str(tree)
    out = subprocess.run([sys.executable, "-c", ONE, str(tree)], capture_output=True, text=True, env=env, cwd=tree,
                         timeout=300, check=True)
    result: dict[str, float | str] = json.loads(out.stdout.strip().splitlines()[-1])
    return result


def _options() -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--load", type=int, default=4, help="CPU burners beside (default 4)")
    ap.add_argument("--rounds", type=int, default=6, help="measurements per tree (default 6)")
    ap.add_argument("--before", type=Path, help="a worktree of another commit, alternated with this one")
    return ap.parse_args()


def main() -> None:
    a = _options()
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(1))     # the burners go with an interrupted run too
    trees = {"before": a.before.resolve(), "this": REPO} if a.before else {"this": REPO}
    print(f"load at start {os.getloadavg()[0]:.2f}; {a.load} burners, {a.rounds} rounds", flush=True)
    results: dict[str, list[dict[str, float | str]]] = {name: [] for name in trees}
    burners = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(a.load)]
    try:
        for r in range(a.rounds):
            for name, tree in trees.items():
                res = measure(tree)
                results[name].append(res)
                print(f"round {r}: {name}: close {float(res['close_s']):.2f} s, {res['state']}, "
                      f"{res['messages']} messages", flush=True)
    finally:
        for b in burners:
            b.kill()
        for b in burners:
            b.wait()
    print(f"load at end {os.getloadavg()[0]:.2f}")
    print("| tree | closes | median, s | max, s | not finished |")
    print("|---|---|---|---|---|")
    for name, rs in results.items():
        times = [float(x["close_s"]) for x in rs]
        failed = sum(x["state"] != "closed" for x in rs)
        print(f"| {name} | {len(rs)} | {statistics.median(times):.2f} | {max(times):.2f} | {failed} |")


if __name__ == "__main__":
    main()
