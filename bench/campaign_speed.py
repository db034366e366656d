"""Benchmark: campaigns, per variant and in all, against the scenario's own in-process run.

    .venv-kilted/bin/python bench/campaign_speed.py [--k 20] [--scaling 100] [--big 1000] [--no-dask] [--batch B]
                                                    [--json]

The scenario: examples/step.yaml (the example controller, a 20 mm step) lengthened to 2 s.
1. Overhead per variant, one worker, this process: K runs of the scenario's own in-process run
   (`run_scenario` on a kept rig, as pcv_sim.testing does; and load + new rig + run, as
   `pcv-sim scenario run` does) against a K-variant campaign (`run_campaign`, workers=1, no
   report): a sweep of a scenario value (the rig is reset between variants) and a Monte Carlo of
   valve tolerances (each variant a new rig: its own valve parameters and rest states). Each
   measured twice, interleaved; the better of the two.
2. Where a Monte Carlo variant's time goes, part by part, timed around the calls the campaign's
   worker makes (median over K variants): the variant's scenario (its values into the YAML
   mappings and the loaders' validation), the controller (import and instance), the new rig
   (composing the plant, the compiled module looked up, of it the valves' rest states), the
   lockstep loop (of it the controller's calls, timed inside the loop, in the array form the
   lockstep calls when the controller has one: the timer's own cost, ~0.1 us a call, is in that
   figure) and the assertions with the row.
3. Scaling: a Monte Carlo of `--scaling` variants on 1 and on 2 local workers (variants/s of the
   run; the workers' set-up, one warm-up variant before the fork, counted apart).
4. Dask against local: the same campaign on a localhost Dask cluster (a `dask scheduler` and two
   `dask worker --nworkers 1 --nthreads 1`, started here, stopped after; the cluster's start-up
   not counted; the workers' warm-up, one pinned task each, counted apart) against 2 local
   workers, interleaved, twice each (the better of each).
5. `--big` variants of a Monte Carlo on every core: the wall time (set-up and run).
Every campaign of 1-5 runs its variants alone (`--batch 1`, the default here) or B at a time in one
batch (`--batch B`: `pcv_sim.rig.batch`; its compiled code is loaded, or compiled, before the first
figure); run it both ways, alternated, to see what the batch saves.
The machine's load average is printed with the figures: on a shared machine it changes them.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import shutil
import statistics
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


#: `--batch`: variants per batch in every campaign of the bench (1: each alone).
_BATCH = [1]


def _timed_campaign(path: Path, out: Path, **kwargs) -> tuple[float, list[dict], dict]:
    """Wall time, the per-variant timings and the summary (its setup_time_s and run_time_s)."""
    from pcv_sim.campaign.run import run_campaign

    shutil.rmtree(out, ignore_errors=True)
    t0 = time.perf_counter()
    result = run_campaign(path, out, report=False, batch=_BATCH[0], **kwargs)
    wall = time.perf_counter() - t0
    with (out / "timings.csv").open() as f:
        return wall, list(csv.DictReader(f)), result.summary


class _Timed:
    """A controller with each call of either of its forms (the dict form, the array form the
    lockstep calls when there is one) timed into `spent` (s)."""

    def __init__(self, inner):
        self.inner, self.spent = inner, 0.0

    def __call__(self, t, m):
        t0 = time.perf_counter()
        out = self.inner(t, m)
        self.spent += time.perf_counter() - t0
        return out

    def lockstep_arrays(self, signals, valves):
        bind = getattr(self.inner, "lockstep_arrays", None)
        form = bind(signals, valves) if bind is not None else None
        if form is None:
            return None
        step, commanded, flags = form

        def timed(t, y, out):
            t0 = time.perf_counter()
            step(t, y, out)
            self.spent += time.perf_counter() - t0

        return timed, commanded, flags


def _where(mc: Path, k: int) -> dict[str, float]:
    """Median seconds per part of a Monte Carlo variant (see the module docstring, 2)."""
    from pcv_sim.campaign.runner import Worker
    from pcv_sim.campaign.spec import load_campaign
    from pcv_sim.rig import rig as rig_module
    from pcv_sim.rig.lockstep import run_lockstep
    from pcv_sim.rig.rig import Rig
    from pcv_sim.rig.scenario import resolve_controller, scenario_result, schedule_timeline

    w = Worker(load_campaign(mc))
    w.run(0)
    parts: dict[str, list[float]] = {}
    rest_solve = rig_module.rest_state
    spent = [0.0]

    def timed_rest(*a, **kw):
        t0 = time.perf_counter()
        try:
            return rest_solve(*a, **kw)
        finally:
            spent[0] += time.perf_counter() - t0

    rig_module.rest_state = timed_rest                      # type: ignore[attr-defined]
    try:
        for j in range(1, k + 1):
            t = [time.perf_counter()]
            sc = w.scenario(w.variants[j])
            t.append(time.perf_counter())
            ctrl = resolve_controller(sc.controller, sc.controller_params, sc.path.parent if sc.path else None)
            t.append(time.perf_counter())
            spent[0] = 0.0
            rig = Rig(sc.rig, seed=sc.seed)
            rest = spent[0]
            t.append(time.perf_counter())
            schedule_timeline(rig, sc)
            counted = _Timed(ctrl)
            run = run_lockstep(rig, counted, sc.duration, setpoint=sc.setpoint_function())
            t.append(time.perf_counter())
            scenario_result(sc, run)
            t.append(time.perf_counter())
            for name, a, b in (("scenario_s", 0, 1), ("controller_import_s", 1, 2), ("new_rig_s", 2, 3),
                               ("lockstep_s", 3, 4), ("assertions_s", 4, 5)):
                parts.setdefault(name, []).append(t[b] - t[a])
            parts.setdefault("of_new_rig_rest_states_s", []).append(rest)
            parts.setdefault("of_lockstep_controller_calls_s", []).append(counted.spent)
            parts.setdefault("lockstep_real_time_factor", []).append(run.real_time_factor)
    finally:
        rig_module.rest_state = rest_solve                  # type: ignore[attr-defined]
    return {name: statistics.median(v) for name, v in parts.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--k", type=int, default=20, help="variants for the overhead per variant")
    ap.add_argument("--scaling", type=int, default=100, help="variants for 1 vs 2 workers and Dask vs local")
    ap.add_argument("--big", type=int, default=1000, help="variants of the large Monte Carlo (0: skip)")
    ap.add_argument("--no-dask", action="store_true")
    ap.add_argument("--batch", type=int, default=1, metavar="B", help="variants per batch in every campaign (1: alone)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    _BATCH[0] = args.batch

    from pcv_sim.rig.rig import Rig
    from pcv_sim.rig.scenario import load_scenario, run_scenario

    out: dict = {"load_before": os.getloadavg(), "cpus": os.cpu_count(), "batch": args.batch}
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
        _timed_campaign(mc, tmp / "warm", workers=1)          # a batch's kernel loaded (or compiled) too
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
            wall, _, _ = _timed_campaign(sweep, tmp / "o_sweep", workers=1)
            camp_sweep.append(wall / k)
            wall, timings, _ = _timed_campaign(mc, tmp / "o_mc", workers=1)
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
                        "setup_share": statistics.median(setup) / (statistics.median(setup) + statistics.median(run)),
                        "parts": _where(mc, k - 1)}
        n = args.scaling
        scal = _campaign(tmp, "scaling", _mc(n, seed=2))
        w1, _, s1 = _timed_campaign(scal, tmp / "o1", workers=1)
        w2, _, s2 = _timed_campaign(scal, tmp / "o2", workers=2)
        same = (tmp / "o1" / "results.csv").read_bytes() == (tmp / "o2" / "results.csv").read_bytes()
        out["scaling"] = {"variants": n, "one_worker_per_s": n / s1["run_time_s"],
                          "two_workers_per_s": n / s2["run_time_s"], "speed_up": s1["run_time_s"] / s2["run_time_s"],
                          "two_workers_setup_s": s2["setup_time_s"], "wall_one_s": w1, "wall_two_s": w2,
                          "same_table": same}
        if not args.no_dask:
            from pcv_sim.testing import dask_cluster

            (tmp / "dask").mkdir()
            runs: dict[str, list[dict]] = {"dask": [], "local": []}
            with dask_cluster(tmp / "dask", 2) as address:
                for r in range(2):
                    _, _, sd = _timed_campaign(scal, tmp / f"od{r}", scheduler=address)
                    _, _, sl = _timed_campaign(scal, tmp / f"ol{r}", workers=2)
                    runs["dask"].append(sd)
                    runs["local"].append(sl)
            same = all((tmp / f"od{r}" / "results.csv").read_bytes() == (tmp / "o1" / "results.csv").read_bytes()
                       for r in range(2))
            best = {key: min(v, key=lambda x: x["run_time_s"]) for key, v in runs.items()}
            out["dask"] = {"variants": n, "dask_per_s": n / best["dask"]["run_time_s"],
                           "local_two_per_s": n / best["local"]["run_time_s"],
                           "dask_vs_local": best["local"]["run_time_s"] / best["dask"]["run_time_s"],
                           "dask_setup_s": [x["setup_time_s"] for x in runs["dask"]],
                           "local_setup_s": [x["setup_time_s"] for x in runs["local"]],
                           "dask_run_s": [x["run_time_s"] for x in runs["dask"]],
                           "local_run_s": [x["run_time_s"] for x in runs["local"]], "same_table": same}
        if args.big:
            big = _campaign(tmp, "big", _mc(args.big, seed=3))
            wb, _, sb = _timed_campaign(big, tmp / "ob", workers=0)
            out["big"] = {"variants": args.big, "scenario_s": 2.0, "workers": os.cpu_count(), "wall_s": wb,
                          "setup_s": sb["setup_time_s"], "run_s": sb["run_time_s"]}
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    out["load_after"] = os.getloadavg()
    if args.json:
        print(json.dumps(out, indent=1))
        return
    o = out["overhead"]
    print(f"load average before {out['load_before']}, after {out['load_after']}; {out['cpus']} CPUs; "
          f"batch {out['batch']}")
    print(f"per variant of a 2 s scenario, one worker (K = {o['k']}): own run on a kept rig "
          f"{o['own_kept_rig_s'] * 1e3:.1f} ms, own load + new rig + run {o['own_load_and_new_rig_s'] * 1e3:.1f} ms; "
          f"campaign sweep {o['campaign_sweep_s'] * 1e3:.1f} ms ({o['sweep_vs_own_kept']:.3f}x the kept-rig run), "
          f"Monte Carlo {o['campaign_monte_carlo_s'] * 1e3:.1f} ms ({o['monte_carlo_vs_own_kept']:.3f}x the kept-rig "
          f"run, {o['monte_carlo_vs_own_load_and_new_rig']:.3f}x load + new rig + run)")
    w = out["where"]
    print(f"a Monte Carlo variant: set-up {w['monte_carlo_setup_median_s'] * 1e3:.1f} ms, run "
          f"{w['monte_carlo_run_median_s'] * 1e3:.1f} ms (set-up {w['setup_share']:.1%})")
    print("  parts (median): " + ", ".join(f"{name} {v * 1e3:.2f} ms" if name.endswith("_s") else f"{name} {v:.1f}"
                                           for name, v in w["parts"].items()))
    s = out["scaling"]
    print(f"{s['variants']} variants: 1 worker {s['one_worker_per_s']:.2f}/s, 2 workers {s['two_workers_per_s']:.2f}/s "
          f"({s['speed_up']:.2f}x; set-up of the 2 workers {s['two_workers_setup_s']:.2f} s apart); "
          f"same table: {s['same_table']}")
    if "dask" in out:
        d = out["dask"]
        print(f"Dask (2 workers) {d['dask_per_s']:.2f}/s vs local 2 workers {d['local_two_per_s']:.2f}/s "
              f"({d['dask_vs_local']:.2f}x; set-up apart: Dask {d['dask_setup_s']}, local {d['local_setup_s']} s); "
              f"same table as local: {d['same_table']}")
    if "big" in out:
        b = out["big"]
        print(f"{b['variants']}-variant Monte Carlo of a 2 s scenario on {b['workers']} workers: {b['wall_s']:.1f} s "
              f"(set-up {b['setup_s']:.1f} s, run {b['run_s']:.1f} s)")


if __name__ == "__main__":
    main()
