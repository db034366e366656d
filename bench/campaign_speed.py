"""Benchmark: campaigns, per variant and in all, against the scenario's own in-process run.

    .venv-kilted/bin/python bench/campaign_speed.py [--k 20] [--scaling 100] [--big 1000] [--repeats 5] [--no-dask]
                                                    [--batch B] [--json]

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
3. Scaling: a Monte Carlo of `--scaling` variants on 1 and on 2 local workers, `--repeats`
   alternated pairs (the order turned each pair): the ratio of each pair's run times, its median
   and range, each side's rate (variants/s; median, range) and CPU time per variant (this process
   and its workers, set-up included; at the same CPU per variant no variant got costlier, and what is missing from
   2x is time the workers did not run: idle, or taken by other processes). The workers' set-up
   (one warm-up variant before the fork) is counted apart.
4. Dask against local: the same campaign on a localhost Dask cluster (a `dask scheduler` and two
   `dask worker --nworkers 1 --nthreads 1`, started here, stopped after; the cluster's start-up
   not counted). Its first campaign on the fresh workers (their imports and kernels: the set-up;
   its run) is reported apart; then `--repeats` alternated pairs of Dask and 2 local workers,
   summarised as in 3 (the CPU of the cluster's processes and this one).
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


def _measured_campaign(path: Path, out: Path, *, processes: list | None = None, **kwargs) -> dict:
    """A campaign's run and set-up time (s, from its summary) and the CPU time (s) it took in
    all: this process, its finished children (a local pool's workers, reaped by the end) and
    `processes` (psutil: a Dask cluster's scheduler, nannies and workers)."""

    def cpu() -> float:
        t = os.times()
        return t.user + t.system + t.children_user + t.children_system + \
            sum(sum(p.cpu_times()[:2]) for p in processes or ())

    c0 = cpu()
    _, _, s = _timed_campaign(path, out, **kwargs)
    return {"run_s": s["run_time_s"], "setup_s": s["setup_time_s"], "cpu_s": cpu() - c0}


def _paired(pairs: list[dict[str, dict]], base: str, other: str, n: int, name: str) -> dict:
    """Per pair the ratio of `base`'s run time to `other`'s (> 1: `other` ran faster); the
    median and the range of the ratios and of each side's rate (variants/s); each side's CPU
    time per variant (all the campaign's processes, set-up included, over the variants it ran)."""
    ratios = [p[base]["run_s"] / p[other]["run_s"] for p in pairs]
    out: dict = {name: statistics.median(ratios), f"{name}_range": (min(ratios), max(ratios)), f"{name}_all": ratios}
    for side in (base, other):
        rates = [n / p[side]["run_s"] for p in pairs]
        out[f"{side}_per_s"] = statistics.median(rates)
        out[f"{side}_per_s_range"] = (min(rates), max(rates))
        out[f"{side}_setup_s"] = statistics.median(p[side]["setup_s"] for p in pairs)
        out[f"{side}_cpu_per_variant_s"] = statistics.median(p[side]["cpu_s"] for p in pairs) / n
    return out


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
    from pcv_sim.device import restarts as rig_module  # where the rig solves its valves' rest states
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
    ap.add_argument("--scaling", type=int, default=100, help="variants for 1 vs 2 workers and Dask vs local (0: skip both)")
    ap.add_argument("--big", type=int, default=1000, help="variants of the large Monte Carlo (0: skip)")
    ap.add_argument("--repeats", type=int, default=5,
                    help="alternated pairs for 1 vs 2 workers and for Dask vs local (medians and ranges)")
    ap.add_argument("--no-dask", action="store_true")
    ap.add_argument("--batch", type=int, default=1, metavar="B", help="variants per batch in every campaign (1: alone)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    _BATCH[0] = args.batch

    import pcv_sim
    from pcv_sim.rig.rig import Rig
    from pcv_sim.rig.scenario import load_scenario, run_scenario

    # which build ran: a worktree on PYTHONPATH for a before/after pair
    out: dict = {"load_before": os.getloadavg(), "cpus": os.cpu_count(), "package": str(Path(pcv_sim.__file__).parent),
                 "batch": args.batch}
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
        if args.scaling:
            n, reps = args.scaling, args.repeats
            scal = _campaign(tmp, "scaling", _mc(n, seed=2))
            # Alternated pairs, the order turned each time (1-2, 2-1, ...): a change of the machine's
            # load in one pair's seconds hits both sides about equally; the ratio is taken per pair.
            pairs: list[dict[str, dict]] = []
            for r in range(reps):
                pair = {}
                for w in ((1, 2) if r % 2 == 0 else (2, 1)):
                    pair[str(w)] = _measured_campaign(scal, tmp / f"o{w}", workers=w)
                pairs.append(pair)
            same = (tmp / "o1" / "results.csv").read_bytes() == (tmp / "o2" / "results.csv").read_bytes()
            out["scaling"] = {"variants": n, "repeats": reps, "same_table": same,
                              **_paired(pairs, "1", "2", n, "speed_up")}
            if not args.no_dask:
                import psutil

                from pcv_sim.testing import dask_cluster

                (tmp / "dask").mkdir()
                dpairs: list[dict[str, dict]] = []
                with dask_cluster(tmp / "dask", 2) as address:
                    cluster = psutil.Process().children(recursive=True)
                    # The first campaign on fresh workers: their imports and kernels are its set-up,
                    # and its run is reported apart (a new process's first variants).
                    first = _measured_campaign(scal, tmp / "od_first", scheduler=address, processes=cluster)
                    for r in range(reps):
                        pair = {}
                        for kind in (("dask", "local") if r % 2 == 0 else ("local", "dask")):
                            if kind == "dask":
                                pair[kind] = _measured_campaign(scal, tmp / "od", scheduler=address, processes=cluster)
                            else:
                                pair[kind] = _measured_campaign(scal, tmp / "ol", workers=2)
                        dpairs.append(pair)
                same = all((tmp / d / "results.csv").read_bytes() == (tmp / "o1" / "results.csv").read_bytes()
                           for d in ("od", "od_first"))
                out["dask"] = {"variants": n, "repeats": reps, "same_table": same,
                               "first_setup_s": first["setup_s"], "first_per_s": n / first["run_s"],
                               **_paired(dpairs, "local", "dask", n, "dask_vs_local")}
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
          f"package {out['package']}, batch {out['batch']}")
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
    s = out.get("scaling")
    if s:
        print(f"{s['variants']} variants, {s['repeats']} alternated pairs: 2 workers against 1 {s['speed_up']:.2f}x "
              f"(median; range {s['speed_up_range'][0]:.2f}-{s['speed_up_range'][1]:.2f}x); 1 worker "
              f"{s['1_per_s']:.1f}/s ({s['1_per_s_range'][0]:.1f}-{s['1_per_s_range'][1]:.1f}), 2 workers "
              f"{s['2_per_s']:.1f}/s ({s['2_per_s_range'][0]:.1f}-{s['2_per_s_range'][1]:.1f}); CPU per variant "
              f"{s['1_cpu_per_variant_s'] * 1e3:.1f} / {s['2_cpu_per_variant_s'] * 1e3:.1f} ms; set-up of the 2 workers "
              f"{s['2_setup_s']:.2f} s apart; same table: {s['same_table']}")
    if "dask" in out:
        d = out["dask"]
        print(f"Dask (2 workers) against 2 local workers, {d['repeats']} alternated pairs: {d['dask_vs_local']:.2f}x "
              f"(median; range {d['dask_vs_local_range'][0]:.2f}-{d['dask_vs_local_range'][1]:.2f}x); Dask "
              f"{d['dask_per_s']:.1f}/s ({d['dask_per_s_range'][0]:.1f}-{d['dask_per_s_range'][1]:.1f}), local "
              f"{d['local_per_s']:.1f}/s ({d['local_per_s_range'][0]:.1f}-{d['local_per_s_range'][1]:.1f}); CPU per "
              f"variant Dask {d['dask_cpu_per_variant_s'] * 1e3:.1f} ms, local "
              f"{d['local_cpu_per_variant_s'] * 1e3:.1f} ms; set-up apart: Dask {d['dask_setup_s']:.2f} s, local "
              f"{d['local_setup_s']:.2f} s; the first campaign on fresh workers: set-up {d['first_setup_s']:.2f} s, "
              f"{d['first_per_s']:.1f}/s; same table as local: {d['same_table']}")
    if "big" in out:
        b = out["big"]
        print(f"{b['variants']}-variant Monte Carlo of a 2 s scenario on {b['workers']} workers: {b['wall_s']:.1f} s "
              f"(set-up {b['setup_s']:.1f} s, run {b['run_s']:.1f} s)")


if __name__ == "__main__":
    main()
