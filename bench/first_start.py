"""Benchmark: a process's first start into an empty kernel cache, for one or more source trees.

    .venv-kilted/bin/python bench/first_start.py [--tree LABEL=PATH ...] [--rounds 2] [--model simplified]
        [--options]

Each round starts, per tree, a fresh Python process with an empty `PCV_SIM_CACHE` that imports
pcv_sim from that tree, builds the emulator's device (its warm-up compiles every kernel it steps
with) and runs 10 steps; the wall time from the import to the last step is the figure
(compiling dominates it). Trees alternate within a round, so a before/after comparison (e.g. a
`git worktree` of the main branch against this checkout) sees the same machine load. `--options`
switches the valve's three options beyond the paper's bench on (docs/model.md R33-R35).
Prints a Markdown table (median and each round) and the load average before and after.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

CODE = """
import sys, time
sys.path.insert(0, {tree!r})
t0 = time.perf_counter()
from pcv_sim.params import load_params, replace_param
from pcv_sim.device.valve import ValveDevice
p = replace_param(load_params(), "simulation.model", {model!r})
if {options!r}:
    for key, value in (("solenoid.coil_temperature", "lumped"), ("fluid.temperature", "input"),
                       ("spool.core", "separate")):
        p = replace_param(p, key, value)
dev = ValveDevice(p, safe_duty=0.5)      # loads (or compiles) every kernel the stepping uses
dev.run(10)
import pcv_sim
assert pcv_sim.__file__.startswith({tree!r}), pcv_sim.__file__
print(time.perf_counter() - t0)
"""


def first_start(tree: Path, model: str, options: bool) -> float:
    """Seconds from import to the 10th step in a fresh process with an empty kernel cache."""
    with tempfile.TemporaryDirectory() as cache:
        env = {**os.environ, "PCV_SIM_CACHE": cache}
        env.pop("NUMBA_CACHE_DIR", None)
        code = CODE.format(tree=str(tree.resolve()), model=model, options=options)
        proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, cwd=cache, check=False)
        if proc.returncode != 0:
            raise SystemExit(f"first start of {tree} failed:\n{proc.stderr}")
        return float(proc.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tree", action="append", default=[], metavar="LABEL=PATH",
                    help="a source tree to measure (default: this checkout)")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--model", choices=("simplified", "full"), default="simplified")
    ap.add_argument("--options", action="store_true", help="the valve with its three options on")
    args = ap.parse_args()
    trees = [(label, Path(path)) for label, _, path in (t.partition("=") for t in args.tree)] or [("this", REPO)]
    print(f"load before: {os.getloadavg()[0]:.2f}", file=sys.stderr)
    times: dict[str, list[float]] = {label: [] for label, _ in trees}
    for _ in range(args.rounds):
        for label, path in trees:
            times[label].append(first_start(path, args.model, args.options))
    print(f"load after: {os.getloadavg()[0]:.2f}", file=sys.stderr)
    what = f"{args.model}{', options on' if args.options else ''}"
    print(f"| tree | first start, {what}: median s | rounds, s |")
    print("|---|---|---|")
    for label, values in times.items():
        print(f"| {label} | {statistics.median(values):.1f} | {' / '.join(f'{v:.1f}' for v in values)} |")


if __name__ == "__main__":
    main()
