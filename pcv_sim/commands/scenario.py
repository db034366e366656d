"""Run scenarios on the rig in lockstep: `pcv-sim scenario run FILE.yaml | DIR/`.

A scenario (`pcv_sim.rig.scenario`) names a rig, a timeline of setpoints, duties, external force
and faults, a controller (`module:callable`) and assertions. The run is deterministic and as fast
as the machine allows. Exit status: 0 every assertion held, 1 one failed (or the model ran away),
2 a bad file (the message names the key). A directory runs each *.yaml in it in parallel
processes and prints one summary; --bag and --report then name directories (one entry per scenario).
"""

from __future__ import annotations

import argparse
import os
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

from pcv_sim.commands.common import emit_json
from pcv_sim.errors import UsageError

NAME = "scenario"
HELP = "run rig scenarios (valves + steering cylinder + controller) and check their assertions"


def add_arguments(p: argparse.ArgumentParser) -> None:
    run = p
    run.add_argument("action", choices=("run",), help="run: a scenario file, or every *.yaml in a directory")
    run.add_argument("path", type=Path, metavar="FILE.yaml|DIR")
    run.add_argument("--json", action="store_true", help="print every assertion's outcome and the real-time factor as JSON")
    run.add_argument("--report", type=Path, metavar="OUT.html", help="write an HTML report with plots (a directory for DIR)")
    run.add_argument("--bag", type=Path, metavar="BAG_DIR", help="write the run as a rosbag2/MCAP bag (a directory for DIR)")
    run.add_argument("--jobs", type=int, default=0, metavar="N",
                     help="parallel processes for a directory (default: the number of CPUs)")


def _one(path: Path, bag: Path | None, report: Path | None) -> dict[str, Any]:
    """Load, run, record one scenario; a dict (picklable) with `status` 0/1/2."""
    from pcv_sim.errors import PcvSimError  # noqa: PLC0415
    from pcv_sim.rig.record import render_html, write_bag  # noqa: PLC0415
    from pcv_sim.rig.scenario import load_scenario, run_scenario  # noqa: PLC0415

    try:
        scenario = load_scenario(path)
        result = run_scenario(scenario)
    except PcvSimError as err:
        return {"name": path.stem, "path": str(path), "status": 2, "error": str(err)}
    out = result.to_dict()
    out["status"] = 0 if result.passed else 1
    if result.run is not None and bag is not None:
        chambers = {v.name: v.chamber for v in scenario.rig.valves}
        write_bag(result.run, bag, chambers=chambers)
        out["bag"] = str(bag)
    if report is not None:
        report.parent.mkdir(parents=True, exist_ok=True)
        report.write_text(render_html(result), encoding="utf-8")
        out["report"] = str(report)
    return out


def _text(r: dict[str, Any]) -> str:
    if r["status"] == 2:
        return f"{r['name']}: BAD FILE: {r['error']}"
    lines = [f"{r['name']}: {'passed' if r['status'] == 0 else 'FAILED'} "
             f"(real-time factor {r['real_time_factor']:.1f}x)"]
    if r.get("error"):
        lines.append(f"  {r['error']}")
    for a in r["assertions"]:
        lines.append(f"  {'ok  ' if a['passed'] else 'FAIL'} {a['name']}: {a['detail']}")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    if getattr(args, "config", None) is not None:
        raise UsageError("--config: a scenario takes each valve's YAML from its rig file (valves.<name>.config); "
                         "accepted is no --config")
    path: Path = args.path
    if path.is_dir():
        files = sorted(path.glob("*.yaml"))
        if not files:
            raise UsageError(f"{path}: no *.yaml scenario in the directory")
        if args.bag is not None and args.bag.exists():
            raise UsageError(f"--bag {args.bag}: exists; accepted is a new directory (one bag per scenario inside)")
        jobs = args.jobs or os.cpu_count() or 1
        if jobs < 1:
            raise UsageError(f"--jobs {args.jobs}: accepted is a number >= 1")
        bags = [args.bag / f.stem if args.bag else None for f in files]
        reports = [args.report / f"{f.stem}.html" if args.report else None for f in files]
        if args.bag:
            args.bag.mkdir(parents=True)
        with ProcessPoolExecutor(max_workers=min(jobs, len(files))) as pool:
            results = list(pool.map(_one, files, bags, reports))
        status = max(r["status"] for r in results)
        if args.json:
            emit_json({"passed": status == 0, "scenarios": results})
        else:
            for r in results:
                print(_text(r))
            failed = sum(r["status"] == 1 for r in results)
            bad = sum(r["status"] == 2 for r in results)
            print(f"{len(results)} scenarios: {len(results) - failed - bad} passed, {failed} failed, {bad} bad files")
        return status
    if not path.is_file():
        raise UsageError(f"{path}: no such scenario file or directory")
    if args.bag is not None and args.bag.exists():
        raise UsageError(f"--bag {args.bag}: exists; accepted is a path that does not exist yet")
    r = _one(path, args.bag, args.report)
    if args.json:
        emit_json(r)
    else:
        print(_text(r), file=sys.stdout if r["status"] != 2 else sys.stderr)
    return int(r["status"])
