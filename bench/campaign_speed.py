"""Benchmark: campaigns, per variant and in all, against the scenario's own in-process run.

    .venv-kilted/bin/python bench/campaign_speed.py [--k 20] [--scaling 100] [--big 1000] [--no-dask] [--json]

The scenario: examples/step.yaml (the example controller, a 20 mm step) lengthened to 2 s.
1. Overhead per variant, one worker, this process: K runs of the scenario's own in-process run
   (`run_scenario` on a kept rig, as pcv_sim.testing does; and load + new rig + run, as
   `pcv-sim scenario run` does) against a K-variant campaign (`run_campaign`, workers=1, no
   report): a sweep of a scenario value (the rig is reset between variants) and a Monte Carlo of
   valve tolerances (each variant a new rig: its own valve parameters and rest states). Each
   measured twice, interleaved; the better of the two.
2. Where a variant's time goes: the campaign's own timings (set-up: values into the files,
   validation, controller, rig; run: the lockstep run and its assertions).
3. Scaling: a Monte Carlo of `--scaling` variants on 1 and on 2 local workers (variants/s).
4. Dask against local: the same campaign on a localhost Dask cluster (a `dask scheduler` and two
   `dask worker --nworkers 1 --nthreads 1`, started here, stopped after; the cluster's start-up
   not counted) against 2 local workers.
5. `--big` variants of a Monte Carlo on every core: the wall time.
The machine's load average is printed with the figures: on a shared machine it changes them.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import shutil
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[1]


def _scenario(tmp: Path) -> Path:
    data = yaml.safe_load((REPO / "examples" / "step.yaml").read_text())
    data.update(duration=2.0, rig=str(REPO / "config" / "rig.yaml"),
                controller="pcv_sim.control.steering:PositionController")
    data["timeline"] = [{"t": 1.0, "force": 0.0}]
    (tmp / "step2.yaml").write_text(yaml.safe_dump(data, sort_keys=False))
    return tmp / "step2.yaml"


def _campaign(tmp: Path, name: str, body: dict) -> Path:
    p = tmp / f"{name}.yaml"
    p.write_text(yaml.safe_dump({"name": name, "scenario": "step2.yaml", "worst": 0, **body}, sort_keys=False))
    return p


def _mc(samples: int, seed: int = 1) -> dict:
    return {"monte_carlo": {"samples": samples, "seed": seed, "parameters": {
        "valves.spool.spring_preload": {"distribution": "normal", "sd": "2.5%", "truncate": "5%"},
        "valves.solenoid.coil_resistance": {"distribution": "uniform", "tolerance": "3%"},
        "valves.fluid.bulk_modulus": {"distribution": "uniform", "tolerance": "10%", "tied": True}}}}


def _timed_campaign(path: Path, out: Path, **kwargs) -> tuple[float, list[dict]]:
    from pcv_sim.campaign.run import run_campaign

    shutil.rmtree(out, ignore_errors=True)
    t0 = time.perf_counter()
    run_campaign(path, out, report=False, **kwargs)
    wall = time.perf_counter() - t0
    with (out / "timings.csv").open() as f:
        return wall, list(csv.DictReader(f))


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _dask_cluster(tmp: Path) -> tuple[str, list[subprocess.Popen]]:
    from distributed import Client

    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    env = {k: v for k, v in os.environ.items() if k != "_ROS_WHEELS_BOOTSTRAP_COMPLETE"}
    procs = [subprocess.Popen([sys.executable, "-m", "dask", "scheduler", "--host", "127.0.0.1", "--port", str(port),
                               "--dashboard-address", ":0"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                              env=env, cwd=tmp)]
    for k in range(2):
        procs.append(subprocess.Popen([sys.executable, "-m", "dask", "worker", address, "--nworkers", "1",
                                       "--nthreads", "1", "--host", "127.0.0.1", "--dashboard-address", ":0",
                                       "--name", f"w{k}"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                      env=env, cwd=tmp))
    deadline = time.monotonic() + 180
    while True:
        try:
            with Client(address, timeout=10) as c:
                c.wait_for_workers(2, timeout=max(1.0, deadline - time.monotonic()))
            return address, procs
        except (OSError, TimeoutError):
            if time.monotonic() > deadline:
                raise
            time.sleep(1.0)


def _stop(procs: list[subprocess.Popen]) -> None:
    for p in reversed(procs):
        p.terminate()
    for p in procs:
        try:
            p.wait(timeout=20)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--k", type=int, default=20, help="variants for the overhead per variant")
    ap.add_argument("--scaling", type=int, default=100, help="variants for 1 vs 2 workers and Dask vs local")
    ap.add_argument("--big", type=int, default=1000, help="variants of the large Monte Carlo (0: skip)")
    ap.add_argument("--no-dask", action="store_true")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()

    from pcv_sim.rig.rig import Rig
    from pcv_sim.rig.scenario import load_scenario, run_scenario

    out: dict = {"load_before": os.getloadavg(), "cpus": os.cpu_count()}
    tmp = Path(tempfile.mkdtemp(prefix="campaign_speed_"))
    try:
        scen = _scenario(tmp)
        k = args.k
        sweep = _campaign(tmp, "sweep", {"sweep": {"parameters": {"scenario.timeline[0].force": {
            "from": -100.0, "to": 100.0, "steps": k}}}})
        mc = _campaign(tmp, "mc", _mc(k))
        sc = load_scenario(scen)
        rig = Rig(sc.rig, seed=sc.seed)
        run_scenario(sc, rig=rig)                 # kernels loaded, caches warm
        _timed_campaign(sweep, tmp / "warm", workers=1)
        own_kept, own_full, camp_sweep, camp_mc = [], [], [], []
        timings: list[dict] = []
        for _ in range(2):
            t0 = time.perf_counter()
            for _ in range(k):
                run_scenario(sc, rig=rig)
            own_kept.append((time.perf_counter() - t0) / k)
            t0 = time.perf_counter()
            for _ in range(k):
                s = load_scenario(scen)
                run_scenario(s)
            own_full.append((time.perf_counter() - t0) / k)
            wall, _ = _timed_campaign(sweep, tmp / "o_sweep", workers=1)
            camp_sweep.append(wall / k)
            wall, timings = _timed_campaign(mc, tmp / "o_mc", workers=1)
            camp_mc.append(wall / k)
        o = out["overhead"] = {
            "k": k, "scenario_s": 2.0, "own_kept_rig_s": min(own_kept), "own_load_and_new_rig_s": min(own_full),
            "campaign_sweep_s": min(camp_sweep), "campaign_monte_carlo_s": min(camp_mc)}
        o["sweep_vs_own_kept"] = o["campaign_sweep_s"] / o["own_kept_rig_s"]
        o["monte_carlo_vs_own_kept"] = o["campaign_monte_carlo_s"] / o["own_kept_rig_s"]
        o["monte_carlo_vs_own_load_and_new_rig"] = o["campaign_monte_carlo_s"] / o["own_load_and_new_rig_s"]
        setup = [float(t["setup_s"]) for t in timings]
        run = [float(t["run_s"]) for t in timings]
        out["where"] = {"monte_carlo_setup_median_s": statistics.median(setup),
                        "monte_carlo_run_median_s": statistics.median(run),
                        "setup_share": statistics.median(setup) / (statistics.median(setup) + statistics.median(run))}
        n = args.scaling
        scal = _campaign(tmp, "scaling", _mc(n, seed=2))
        w1, _ = _timed_campaign(scal, tmp / "o1", workers=1)
        w2, _ = _timed_campaign(scal, tmp / "o2", workers=2)
        same = (tmp / "o1" / "results.csv").read_bytes() == (tmp / "o2" / "results.csv").read_bytes()
        out["scaling"] = {"variants": n, "one_worker_per_s": n / w1, "two_workers_per_s": n / w2,
                          "speed_up": w1 / w2, "same_table": same}
        if not args.no_dask:
            address, procs = _dask_cluster(tmp)
            try:
                wd, _ = _timed_campaign(scal, tmp / "od", scheduler=address)
                wl, _ = _timed_campaign(scal, tmp / "o2b", workers=2)
            finally:
                _stop(procs)
            same = (tmp / "od" / "results.csv").read_bytes() == (tmp / "o1" / "results.csv").read_bytes()
            out["dask"] = {"variants": n, "dask_per_s": n / wd, "local_two_per_s": n / wl, "dask_vs_local": wl / wd,
                           "same_table": same}
        if args.big:
            big = _campaign(tmp, "big", _mc(args.big, seed=3))
            wb, _ = _timed_campaign(big, tmp / "ob", workers=0)
            out["big"] = {"variants": args.big, "scenario_s": 2.0, "workers": os.cpu_count(), "wall_s": wb}
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    out["load_after"] = os.getloadavg()
    if args.json:
        print(json.dumps(out, indent=1))
        return
    o = out["overhead"]
    print(f"load average before {out['load_before']}, after {out['load_after']}; {out['cpus']} CPUs")
    print(f"per variant of a 2 s scenario, one worker (K = {o['k']}): own run on a kept rig "
          f"{o['own_kept_rig_s'] * 1e3:.1f} ms, own load + new rig + run {o['own_load_and_new_rig_s'] * 1e3:.1f} ms; "
          f"campaign sweep {o['campaign_sweep_s'] * 1e3:.1f} ms ({o['sweep_vs_own_kept']:.3f}x the kept-rig run), "
          f"Monte Carlo {o['campaign_monte_carlo_s'] * 1e3:.1f} ms ({o['monte_carlo_vs_own_kept']:.3f}x the kept-rig "
          f"run, {o['monte_carlo_vs_own_load_and_new_rig']:.3f}x load + new rig + run)")
    w = out["where"]
    print(f"a Monte Carlo variant: set-up {w['monte_carlo_setup_median_s'] * 1e3:.1f} ms, run "
          f"{w['monte_carlo_run_median_s'] * 1e3:.1f} ms (set-up {w['setup_share']:.1%})")
    s = out["scaling"]
    print(f"{s['variants']} variants: 1 worker {s['one_worker_per_s']:.2f}/s, 2 workers {s['two_workers_per_s']:.2f}/s "
          f"({s['speed_up']:.2f}x); same table: {s['same_table']}")
    if "dask" in out:
        d = out["dask"]
        print(f"Dask (2 workers) {d['dask_per_s']:.2f}/s vs local 2 workers {d['local_two_per_s']:.2f}/s "
              f"({d['dask_vs_local']:.2f}x); same table as local: {d['same_table']}")
    if "big" in out:
        b = out["big"]
        print(f"{b['variants']}-variant Monte Carlo of a 2 s scenario on {b['workers']} workers: {b['wall_s']:.1f} s")


if __name__ == "__main__":
    main()
