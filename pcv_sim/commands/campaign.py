"""Run a campaign: one scenario over many variants of its valves, plant, inputs and faults.

    pcv-sim campaign run FILE.yaml [--workers N] [--batch B] [--scheduler tcp://HOST:PORT] [--out DIR] [--json]
                                   [--resume]
    pcv-sim campaign run FILE.yaml --variant K [--report r.html] [--bag b]

The campaign file (`pcv_sim.campaign.spec`) names a scenario and what varies: a sweep, a Monte
Carlo of tolerances, a fault matrix. Every variant runs in lockstep like `pcv-sim scenario run`
of the scenario with its values written into the files. By default on every core of this
machine (worker processes that load the compiled kernels once); with --scheduler on a Dask
cluster. --batch B steps B variants in one compiled call per control period (the same results;
the first use of a batch of this rig compiles for minutes); by default two where that is compiled
already, else each alone. Out: DIR/results.csv (a row per variant), DIR/report.html, the summary on stdout.
Ctrl-C (SIGINT) or SIGTERM keeps every finished variant; --resume runs only the missing ones. --variant K re-runs
variant K alone (its report and bag), with the same assertion values as in the campaign.
Exit status: 0 the campaign's gate holds, 1 it does not, 2 a bad file or options, 130 interrupted.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import signal
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from pcv_sim.commands.common import emit_json
from pcv_sim.errors import UsageError

NAME = "campaign"
HELP = "run a scenario over many valve variants, tolerances and faults (locally or on a Dask cluster)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("action", choices=("run",), help="run: every variant of the campaign file (or one: --variant)")
    p.add_argument("path", type=Path, metavar="FILE.yaml")
    p.add_argument("--workers", type=int, default=0, metavar="N",
                   help="local worker processes (default: every core; 1 runs in this process)")
    p.add_argument("--batch", type=int, default=0, metavar="B",
                   help="variants stepped together in one compiled call (1: each alone; 0: two where that "
                        "batch's compiled code is in the kernel cache, default; the same results)")
    p.add_argument("--scheduler", metavar="ADDRESS", default=None,
                   help="run on the Dask cluster whose scheduler is at ADDRESS (tcp://HOST:PORT)")
    p.add_argument("--out", type=Path, default=None, metavar="DIR",
                   help="results directory (default: <campaign name>_campaign)")
    p.add_argument("--json", action="store_true", help="print the summary as JSON (no progress)")
    p.add_argument("--resume", action="store_true", help="run only the variants missing from DIR")
    p.add_argument("--variant", type=int, default=None, metavar="K", help="re-run variant K alone")
    p.add_argument("--report", type=Path, default=None, metavar="OUT.html", help="with --variant: its scenario report")
    p.add_argument("--bag", type=Path, default=None, metavar="BAG_DIR", help="with --variant: its run as a bag")


class Progress:
    """Variants done, failed, rate and ETA on one line of a terminal; silent elsewhere."""

    def __init__(self, total: int, enabled: bool) -> None:
        self.total, self.enabled = total, enabled
        self.done = self.failed = 0
        self.t0 = time.perf_counter()
        self._last = 0.0

    def start(self, total: int) -> None:
        """`total` variants to run (with --resume, the missing ones)."""
        self.total = total
        self.done = self.failed = 0
        self.t0 = time.perf_counter()
        self._last = 0.0

    def update(self, row: dict[str, Any]) -> None:
        self.done += 1
        self.failed += row["status"] != "passed"
        now = time.perf_counter()
        if not self.enabled or (now - self._last < 0.2 and self.done < self.total):
            return
        self._last = now
        rate = self.done / max(now - self.t0, 1e-9)
        eta = (self.total - self.done) / rate if rate > 0 else math.inf
        width = 30
        bar = "#" * round(width * self.done / max(self.total, 1))
        sys.stderr.write(f"\r[{bar:<{width}}] {self.done}/{self.total} done, {self.failed} failed, "
                         f"{rate:.1f}/s, ETA {eta:.0f} s ")
        sys.stderr.flush()

    def close(self) -> None:
        if self.enabled:
            sys.stderr.write("\n")


def _interactive(args: argparse.Namespace) -> bool:
    return not args.json and sys.stderr.isatty() and not os.environ.get("CI")


def _one(args: argparse.Namespace, campaign: Any) -> int:
    """--variant K: that variant alone, fresh, with its report and bag."""
    from pcv_sim.campaign.runner import Worker
    from pcv_sim.rig.record import write_bag
    from pcv_sim.rig.report import render_html

    if args.bag is not None and args.bag.exists():
        raise UsageError(f"--bag {args.bag}: exists; accepted is a path that does not exist yet")
    w = Worker(campaign)
    row, result, scenario = w.run_recorded(args.variant)
    if result is not None and result.run is not None and scenario is not None and args.bag is not None:
        write_bag(result.run, args.bag, chambers={v.name: v.chamber for v in scenario.rig.valves})
    if result is not None and args.report is not None:
        args.report.parent.mkdir(parents=True, exist_ok=True)
        args.report.write_text(render_html(result), encoding="utf-8")
    row.pop("_timing", None)
    row.pop("_kinds", None)
    if args.json:
        emit_json(row)
    else:
        print(f"variant {args.variant}: {row['status']}" + (f": {row['error']}" if row.get("error") else ""))
        for k, v in row.items():
            if k not in ("index", "status", "error"):
                print(f"  {k}: {v}")
    return 0 if row["status"] == "passed" else 1


def run(args: argparse.Namespace) -> int:
    from pcv_sim.campaign.results import summary_text
    from pcv_sim.campaign.run import run_campaign
    from pcv_sim.campaign.spec import load_campaign
    from pcv_sim.campaign.variants import Variants

    if getattr(args, "config", None) is not None:
        raise UsageError("--config: a campaign takes each valve's YAML from its scenario's rig file; accepted is "
                         "no --config")
    if args.workers < 0:
        raise UsageError(f"--workers {args.workers}: accepted is a number >= 1 (0: every core)")
    if args.batch < 0:
        raise UsageError(f"--batch {args.batch}: accepted is a number >= 1 (0: auto)")
    if args.variant is None and (args.report is not None or args.bag is not None):
        raise UsageError("--report/--bag: with --variant K (the campaign's own report is DIR/report.html)")
    campaign = load_campaign(args.path)
    if args.variant is not None:
        n = len(Variants(campaign, validate=True))
        if not 0 <= args.variant < n:
            raise UsageError(f"--variant {args.variant}: accepted is 0 .. {n - 1}")
        return _one(args, campaign)
    out = args.out if args.out is not None else Path(f"{campaign.name}_campaign")
    progress = Progress(campaign.size, _interactive(args))
    try:
        with _interrupt_on_signals():
            result = run_campaign(campaign, out, workers=args.workers, scheduler=args.scheduler,
                                  resume=args.resume, on_row=progress.update, on_start=progress.start,
                                  batch=args.batch)
    finally:
        progress.close()
    s = result.summary
    if args.json:
        emit_json(s)
    else:
        print(summary_text(s))
        print(f"{s['ran']} variants in {s['wall_time_s']:.1f} s; results: {s['results']}"
              + (f"; report: {s['report']}" if "report" in s else ""))
    if result.interrupted:
        print(f"pcv-sim campaign: interrupted; {s['done']} of {s['variants']} variants kept in {out} (--resume runs "
              "the rest)", file=sys.stderr)
        return 130
    return 0 if result.passed else 1


@contextlib.contextmanager
def _interrupt_on_signals() -> Iterator[None]:
    """SIGINT and SIGTERM stop the campaign as Ctrl-C does (finished variants kept, exit 130),
    whatever the process inherited: a job started in the background by a non-interactive shell
    (a CI script's `&`, nohup) inherits SIGINT ignored, and Python then installs no
    KeyboardInterrupt for it; SIGTERM is what CI runners and `timeout` send."""
    def interrupt(_signum: int, _frame: Any) -> None:
        raise KeyboardInterrupt

    previous = {sig: signal.signal(sig, interrupt) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)

