"""Run scenarios on the rig in lockstep: `pcv-sim scenario run FILE.yaml | DIR/`.

A scenario (`pcv_sim.rig.scenario`) names a rig, a timeline of setpoints, duties, external force
and faults, a controller (`module:callable`) and assertions. The run is deterministic and as fast
as the machine allows. Exit status: 0 every assertion held, 1 one failed (or the model ran away,
or a ROS controller did not answer within its `wait`, or its command exited), 2 a bad file (the
message names the key). A directory runs each *.yaml in it in parallel processes and prints one
summary; --bag and --report then name directories (one entry per scenario; the reports get an
index.html). --junit FILE writes JUnit XML (one test case per scenario) for CI; --csv DIR every
signal of each run as DIR/<scenario>.csv.

A ROS controller (`controller: {ros: ...}` in the file, or `--ros NAMESPACE` for any scenario):
the rig node runs here, over DDS. A controller the scenario starts (`command`) runs in a ROS
domain of the runner's own (one per parallel worker: 215 .. 232, localhost only, each reserved on
the machine while its process lives), so parallel scenarios, also other runs' on the machine,
never see each other; a node the user started is reached in $ROS_DOMAIN_ID, and the
scenarios of a directory that use such nodes run one after the other (one rig, one /clock, in
that domain at a time); the example node starts afresh when the next one's time starts at 0.
"""

from __future__ import annotations

import argparse
import contextlib
import fcntl
import multiprocessing
import os
import sys
import tempfile
import time
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
    run.add_argument("--junit", type=Path, metavar="FILE.xml",
                     help="write JUnit XML: one test case per scenario, its assertions as properties (for CI)")
    run.add_argument("--csv", type=Path, metavar="DIR",
                     help="write every signal of each run as DIR/<scenario>.csv (time + columns, units in the header)")
    run.add_argument("--jobs", type=int, default=0, metavar="N",
                     help="parallel processes for a directory (default: the number of CPUs)")
    run.add_argument("--ros", metavar="NAMESPACE", default=None,
                     help="run with the ROS 2 controller node you started in NAMESPACE ('/' for the root; "
                          "$ROS_DOMAIN_ID) instead of the file's controller")
    run.add_argument("--wait", type=float, default=30.0, metavar="S",
                     help="with --ros: s to wait for the node to answer (default 30)")


DOMAINS = range(215, 233)   # ROS domains for controllers the runner starts: above the ephemeral ports' range
_DOMAIN_LOCKS = Path(tempfile.gettempdir()) / "pcv_sim-ros-domains"
_reserved: tuple[int, int, int] | None = None     # (pid, domain, the locked file's descriptor)


def reserve_domain(preferred: int = 0) -> int:
    """This process's ROS domain (of DOMAINS) for the controllers it starts, reserved on the
    whole machine: an exclusive lock on one file per domain, held until the process ends
    (flock: released however it ends, and not shared with a forked child, which reserves its
    own). Two rigs in one domain see each other's /clock and controllers, and discovery is
    localhost-wide: runners of other users, CI jobs or test runs on the machine must not pick the
    same one. Tried from DOMAINS[preferred % len] on; with every one taken, waits for that one."""
    global _reserved
    if _reserved is not None and _reserved[0] == os.getpid():
        return _reserved[1]
    if not _DOMAIN_LOCKS.is_dir():
        _DOMAIN_LOCKS.mkdir(parents=True, exist_ok=True)
        with contextlib.suppress(OSError):           # every user's runners lock files in it
            os.chmod(_DOMAIN_LOCKS, 0o1777)
    order = [DOMAINS[(preferred + i) % len(DOMAINS)] for i in range(len(DOMAINS))]
    for i, domain in enumerate([*order, order[0]]):
        fd = os.open(_DOMAIN_LOCKS / f"{domain}.lock", os.O_RDONLY | os.O_CREAT, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | (fcntl.LOCK_NB if i < len(order) else 0))
        except BlockingIOError:
            os.close(fd)
            continue
        _reserved = (os.getpid(), domain, fd)
        return domain
    raise AssertionError("unreachable: the last attempt blocks until it holds the lock")


def _init_worker(counter: Any, base: int) -> None:
    """Each worker process of a directory run reserves a ROS domain of its own (tried from one
    per worker on, so that the workers of one run rarely try the same one first)."""
    with counter.get_lock():
        slot = counter.value
        counter.value += 1
    reserve_domain(base + slot)


def _load(path: Path, ros: str | None, wait: float) -> Any:
    """The scenario, its controller replaced by the ROS node in `ros` when given."""
    import dataclasses

    from pcv_sim.rig.scenario import RosController, ScenarioError, load_scenario, ros_controller

    scenario = load_scenario(path)
    if ros is not None:
        if scenario.valve_changes:
            raise ScenarioError(f"{path}: valves: with --ros the rig node loads the rig YAML itself (its rig_config); "
                                "accepted is a rig whose valve YAMLs hold these keys, named by `rig`")
        spec: RosController = ros_controller({"ros": {"namespace": ros, "wait": wait}})
        scenario = dataclasses.replace(scenario, controller=None, controller_params=None, ros=spec)
    return scenario


def _one(path: Path, bag: Path | None, report: Path | None, ros: str | None = None, wait: float = 30.0,
         domain: int | None = None, csv: Path | None = None) -> dict[str, Any]:
    """Load, run, record one scenario; a dict (picklable) with `status` 0/1/2. A controller the
    scenario starts runs in ROS domain `domain` (None: the one this process reserved)."""
    from pcv_sim.errors import PcvSimError
    from pcv_sim.rig.record import write_bag, write_csv
    from pcv_sim.rig.report import render_html
    from pcv_sim.rig.scenario import run_scenario

    started = time.perf_counter()
    try:
        scenario = _load(path, ros, wait)
        if scenario.ros is not None and scenario.ros.command:
            if domain is None:
                domain = reserve_domain(os.getpid())
        else:
            domain = None                  # a node the user started: in $ROS_DOMAIN_ID
        if scenario.ros is not None:
            from pcv_sim.node.scenario_host import run_ros_scenario

            result = run_ros_scenario(scenario, domain=domain)
        else:
            result = run_scenario(scenario)
    except PcvSimError as err:
        return {"name": path.stem, "path": str(path), "status": 2, "error": str(err)}
    out = result.to_dict()
    # Reading the files, building the rig and compiling (or loading) its kernels: apart from the
    # run, whose real-time factor is the model's speed (a first run with an empty kernel cache
    # spends ~10-100 s here).
    out["setup_time_s"] = max(time.perf_counter() - started - result.wall_time, 0.0)
    out["status"] = 0 if result.passed else 1
    if result.run is not None and bag is not None:
        chambers = {v.name: v.chamber for v in scenario.rig.valves}
        write_bag(result.run, bag, chambers=chambers)
        out["bag"] = str(bag)
    if result.run is not None and csv is not None:
        out["csv"] = str(write_csv(result.run, csv / f"{path.stem}.csv"))
    if report is not None:
        report.parent.mkdir(parents=True, exist_ok=True)
        report.write_text(render_html(result), encoding="utf-8")
        out["report"] = str(report)
    return out


def _group(items: list[tuple[Path, Path | None, Path | None]], ros: str | None, wait: float,
           csv: Path | None = None) -> list[dict[str, Any]]:
    """Scenarios one after the other (they share a controller node the user started)."""
    return [_one(path, bag, report, ros, wait, csv=csv) for path, bag, report in items]


def _groups(files: list[Path], ros: str | None, wait: float) -> list[list[int]]:
    """Indices of `files` to run together, one after the other: those with a ROS controller the
    user started (they share $ROS_DOMAIN_ID, where one rig's /clock at a time is accepted, and a
    node serves one rig at a time); every other file alone."""
    from pcv_sim.errors import PcvSimError

    shared: list[int] = []
    alone: list[list[int]] = []
    for k, f in enumerate(files):
        try:
            sc = _load(f, ros, wait)
        except PcvSimError:
            sc = None                      # reported by its run
        if sc is not None and sc.ros is not None and not sc.ros.command:
            shared.append(k)
        else:
            alone.append([k])
    return sorted([shared, *alone] if shared else alone)


def _text(r: dict[str, Any]) -> str:
    if r["status"] == 2:
        return f"{r['name']}: BAD FILE: {r['error']}"
    lines = [f"{r['name']}: {'passed' if r['status'] == 0 else 'FAILED'} "
             f"(real-time factor {r['real_time_factor']:.1f}x: {r['wall_time_s']:.2f} s for the run; "
             f"{r['setup_time_s']:.2f} s before it to load the files and compile or load the model)"]
    if r.get("error"):
        lines.append(f"  {r['error']}")
    for a in r["assertions"]:
        lines.append(f"  {'ok  ' if a['passed'] else 'FAIL'} {a['name']}: {a['detail']}")
    return "\n".join(lines)


def _outputs(args: argparse.Namespace, results: list[dict[str, Any]], folder: Path | None) -> None:
    """The JUnit file, and a folder's report index."""
    if getattr(args, "junit", None) is not None:
        from pcv_sim.rig.junit import write_junit

        write_junit(results, args.junit)
    if folder is not None and args.report is not None:
        from pcv_sim.rig.report import render_index

        args.report.mkdir(parents=True, exist_ok=True)
        (args.report / "index.html").write_text(render_index(results, title=str(folder), base=args.report),
                                                encoding="utf-8")


def run(args: argparse.Namespace) -> int:
    if getattr(args, "config", None) is not None:
        raise UsageError("--config: a scenario takes each valve's YAML from its rig file (valves.<name>.config); "
                         "accepted is no --config")
    path: Path = args.path
    if args.ros is not None:
        from pcv_sim.rig.scenario import ScenarioError, ros_controller

        try:
            ros_controller({"ros": {"namespace": args.ros, "wait": args.wait}})
        except ScenarioError as err:
            raise UsageError(f"--ros/--wait: {err}") from None
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
        groups = _groups(files, args.ros, args.wait)
        counter = multiprocessing.Value("i", 0)
        results: list[dict[str, Any]] = [{} for _ in files]
        with ProcessPoolExecutor(max_workers=min(jobs, len(groups), len(DOMAINS)), initializer=_init_worker,
                                 initargs=(counter, os.getpid())) as pool:
            done = pool.map(_group, [[(files[k], bags[k], reports[k]) for k in g] for g in groups],
                            [args.ros] * len(groups), [args.wait] * len(groups), [args.csv] * len(groups))
            for g, rs in zip(groups, done):
                for k, r in zip(g, rs):
                    results[k] = r
        status = max(int(r["status"]) for r in results)
        _outputs(args, results, path)
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
    r = _one(path, args.bag, args.report, args.ros, args.wait, csv=args.csv)
    _outputs(args, [r], None)
    if args.json:
        emit_json(r)
    else:
        print(_text(r), file=sys.stdout if r["status"] != 2 else sys.stderr)
    return int(r["status"])
