"""Benchmark: the simulation core's cost per 0.1 ms step, compiled (numba) and as plain Python.

    .venv-kilted/bin/python bench/model_speed.py [--repeats 5] [--steps 20000] [--json]
    .venv-kilted/bin/python bench/model_speed.py --first-start [--repeats 3] [--json]

Times are CPU time of the measuring process (`time.process_time`: on a shared machine the wall
clock also counts waiting for a core). Every figure is measured twice in the same run: in this process
(compiled, if numba is there)
and in a child process with PCV_SIM_JIT=0 (the same source as plain Python, fewer steps).
Prints the Markdown table for BENCHMARKS.md, or with --json every figure as JSON.

- simplified valve, Heun (rk2): through a 0.5 -> 0.9 -> 0.4 -> 0.7 duty sequence
- full valve (with the damping chamber), exponential Heun (erk2), same sequence; and its largest
  pressure error on the reference bags' duty steps against the Radau-made bags
- two simplified valves + the mass-spring piston composed (rk2)
- replay of bags/pcv_step_levels with the emulator's integrator (model run + comparison; the
  bag is read once outside the timing), simplified and full: real-time factor
- first start: the emulator's device (`ValveDevice`, which loads every compiled call it steps with)
  to its first steps, compiling the kernels into an empty cache, and loading them from the cache;
  alone with `--first-start` (median of `--repeats` fresh processes each)
- `--options`: the valve with its three options beyond the paper's bench on (coil heating, oil
  at 41 degC, core-spool separation; docs/model.md R33-R35) against the paper's, per step, both
  models, alternating in one run; the ratio is the figure (goal: <= 1.5). Also coil heating with
  oil at -20 degC and the core attached (the spool's pole integrated exactly by erk2)
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
#: CPU seconds of this process (single-threaded work): on a machine shared with other jobs the
#: wall clock counts the time the process waited for a core; the CPU time is what a step costs.
CLOCK = time.process_time
BAGS = REPO / "bags"


def _with_options(kind: str, variant: str = "all") -> object:
    """The shipped valve with coil heating, the oil temperature (at 41 degC: off the reference, so
    Walther's relation runs every evaluation) and core separation on (`all`); or (`cold`) coil
    heating and oil at -20 degC with the core attached (the spool's pole taken exactly, erk2)."""
    from pcv_sim.params import load_params, replace_param

    p = load_params()
    changes = ((("solenoid.coil_temperature", "lumped"), ("fluid.temperature", "input"),
                ("fluid.oil_temperature_c", 41.0), ("spool.core", "separate")) if variant == "all" else
               (("solenoid.coil_temperature", "lumped"), ("fluid.temperature", "input"),
                ("fluid.oil_temperature_c", -20.0)))
    for key, value in changes:
        p = replace_param(p, key, value)
    return p


def _valve(kind: str, steps: int, options: bool | str = False) -> float:
    """The core's cost per step of one valve (its `Simulator`: what every device steps), in us."""
    from pcv_sim.params import load_params
    from pcv_sim.simulation.rest import rest_state
    from pcv_sim.simulation.simulator import Simulator
    from pcv_sim.simulation.valve import valve_inputs, valve_integrator, valve_system

    params = _with_options(kind, "all" if options is True else str(options)) if options else load_params()
    sim = Simulator(valve_system(params, kind), params.simulation.time_step, valve_integrator(params, kind))
    rest = rest_state(params, kind, 0.5, integrator=sim.integrator)
    sim.x[:], sim.W[0] = rest.state, rest.current
    sim.u[:] = valve_inputs(params, 0.5, 0.0, params.circuit.supply_pressure)
    duty = sim.plant.index("input", "valve.duty_cycle")
    sim.advance(10)                                          # compiled or loaded before timing
    chunk = max(1, steps // 4)
    t0 = CLOCK()
    for d in (0.9, 0.4, 0.7, 0.5):
        sim.u[duty] = d
        sim.advance(chunk)
    return (CLOCK() - t0) / (4 * chunk) * 1e6


def _composite(steps: int) -> float:
    from pcv_sim.params import load_params
    from pcv_sim.plant.mass_spring import mass_spring
    from pcv_sim.simulation.rest import rest_state
    from pcv_sim.simulation.simulator import Simulator
    from pcv_sim.simulation.system import compose
    from pcv_sim.simulation.valve import valve_system

    params = load_params()
    plant = compose([valve_system(params, "simplified", "left"), valve_system(params, "simplified", "right"),
                     mass_spring("piston", area=1e-4, mass=1.0, stiffness=2e5, damping=2000.0)],
                    [("left.pressure", "piston.pressure_a"), ("right.pressure", "piston.pressure_b"),
                     ("piston.flow_a", "left.load_flow"), ("piston.flow_b", "right.load_flow")])
    rest = rest_state(params, "simplified", 0.5)
    sim = Simulator(plant, 1e-4, "rk2")
    sim.x[:] = np.concatenate([rest.state, rest.state, [0.0, 0.0]])
    sim.W[:] = (rest.current, rest.current, 0.0)
    sim.u[:] = (0.5, 200e5, params.circuit.load_volume, 0.5, 200e5, params.circuit.load_volume)
    sim.advance(10)
    chunk = max(1, steps // 4)
    t0 = CLOCK()
    for left, right in ((0.9, 0.4), (0.4, 0.9), (0.7, 0.5), (0.5, 0.5)):
        sim.u[0], sim.u[3] = left, right
        sim.advance(chunk)
    return (CLOCK() - t0) / (4 * chunk) * 1e6


def _replay(kind: str) -> tuple[float, float]:
    """(real-time factor, largest pressure error in bar) of the levels bag on the emulator's engine."""
    from pcv_sim.params import load_params
    from pcv_sim.replay import load_recording, replay

    rec = load_recording(BAGS / "pcv_step_levels")
    params = load_params()
    replay(rec, params, model=kind)                          # warm (compile/load) outside the timing
    t0 = CLOCK()
    r = replay(rec, params, model=kind)
    wall = CLOCK() - t0
    return r.duration_s / wall, r.scalar_metrics()["pressure_max_error_bar"]


def measure(repeats: int, steps: int, *, replays: bool) -> dict[str, float]:
    out: dict[str, float] = {}
    out["simplified_rk2_us_per_step"] = statistics.median(_valve("simplified", steps) for _ in range(repeats))
    out["full_erk2_us_per_step"] = statistics.median(_valve("full", steps) for _ in range(repeats))
    out["two_valves_piston_rk2_us_per_step"] = statistics.median(_composite(steps) for _ in range(repeats))
    if replays:
        for kind in ("simplified", "full"):
            runs = [_replay(kind) for _ in range(max(1, repeats // 2))]
            out[f"replay_levels_{kind}_real_time_factor"] = statistics.median(r[0] for r in runs)
            out[f"replay_levels_{kind}_pressure_max_error_bar"] = runs[0][1]
    return out


def _child(args: list[str], env: dict[str, str]) -> dict[str, float]:
    proc = subprocess.run([sys.executable, __file__, *args], env=env, capture_output=True, text=True, check=True)
    return json.loads(proc.stdout)


def _first_start(repeats: int = 1) -> dict[str, float]:
    """Seconds to the first steps of the emulator's device in a fresh process (from before its
    imports): into an empty cache (compiles), and again from the filled cache (loads); the median
    of `repeats` processes each (each empty-cache run in a cache of its own). Wall clock, and the
    child's CPU time beside it (on a shared machine the wall clock also counts waiting for a core)."""
    code = ("import time; t0, c0 = time.perf_counter(), time.process_time(); from pcv_sim.params import load_params; "
            "from pcv_sim.device.valve import ValveDevice; "
            "d = ValveDevice(load_params(), safe_duty=0.5); d.advance_to(10); "
            "print(time.perf_counter() - t0, time.process_time() - c0)")
    runs: dict[str, list[tuple[float, float]]] = {"first_start_empty_cache": [], "first_start_cached": []}
    for _ in range(repeats):
        with tempfile.TemporaryDirectory() as cache:
            env = {**os.environ, "PCV_SIM_CACHE": cache}
            env.pop("NUMBA_CACHE_DIR", None)
            for values in runs.values():   # empty cache first, then the cache it filled
                proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                                      check=True)
                wall, cpu = (float(v) for v in proc.stdout.split())
                values.append((wall, cpu))
    out = {}
    for label, values in runs.items():
        out[f"{label}_s"] = statistics.median(w for w, _ in values)
        out[f"{label}_cpu_s"] = statistics.median(c for _, c in values)
    return out


def _options(repeats: int, steps: int, as_json: bool) -> None:
    """Per-step cost with the three options on against the paper's valve, alternating in one run."""
    out: dict[str, float] = {}
    for kind in ("simplified", "full"):
        _valve(kind, 100), _valve(kind, 100, True), _valve(kind, 100, "cold")   # compiled or loaded before timing
        base, opt, cold = [], [], []
        for _ in range(repeats):
            base.append(_valve(kind, steps))
            opt.append(_valve(kind, steps, True))
            cold.append(_valve(kind, steps, "cold"))
        out[f"{kind}_us_per_step"] = statistics.median(base)
        out[f"{kind}_options_us_per_step"] = statistics.median(opt)
        out[f"{kind}_ratio"] = out[f"{kind}_options_us_per_step"] / out[f"{kind}_us_per_step"]
        out[f"{kind}_cold_us_per_step"] = statistics.median(cold)
        out[f"{kind}_cold_ratio"] = out[f"{kind}_cold_us_per_step"] / out[f"{kind}_us_per_step"]
    if as_json:
        print(json.dumps(out, indent=2))
        return
    print("| model | paper's valve, µs per step | coil heating + oil temperature + core separation | ratio | goal "
          "| coil heating + oil at -20 degC, core attached (erk2) | ratio |")
    print("|---|---|---|---|---|---|---|")
    for kind in ("simplified", "full"):
        print(f"| {kind} | {out[f'{kind}_us_per_step']:.2f} | {out[f'{kind}_options_us_per_step']:.2f} | "
              f"{out[f'{kind}_ratio']:.2f} | <= 1.5 | {out[f'{kind}_cold_us_per_step']:.2f} | "
              f"{out[f'{kind}_cold_ratio']:.2f} |")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--steps", type=int, default=20000)
    ap.add_argument("--json", action="store_true", help="print every figure as JSON")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--options", action="store_true", help="only: the options on vs the paper's valve")
    ap.add_argument("--first-start", action="store_true",
                    help="only: the first start (median of --repeats processes each, empty cache and cached)")
    args = ap.parse_args()
    if args.first_start:
        start = _first_start(args.repeats)
        print(json.dumps(start, indent=2) if args.json else _first_start_line(start))
        return
    if args.options:
        _options(args.repeats, args.steps, args.json)
        return
    if args.child:
        print(json.dumps(measure(args.repeats, args.steps, replays=False)))
        return
    from pcv_sim.jit import backend

    compiled = measure(args.repeats, args.steps, replays=True)
    env = {**os.environ, "PCV_SIM_JIT": "0"}
    python = _child(["--child", "--repeats", "3", "--steps", str(max(400, args.steps // 50))], env)
    start = _first_start()
    result = {"machine": platform.processor() or platform.machine(), "python": platform.python_version(),
              "backend": backend(), "compiled": compiled, "python_path": python, **start}
    if args.json:
        print(json.dumps(result, indent=2))
        return
    dt_us = 100.0
    print(f"machine: {result['machine']}, Python {result['python']}, {result['backend']}")
    print("| figure | compiled | plain Python (PCV_SIM_JIT=0) | ratio | target |")
    print("|---|---|---|---|---|")
    rows = (("simplified valve, Heun, µs per 0.1 ms step", "simplified_rk2_us_per_step", "<= 1"),
            ("full valve, exponential Heun, µs per step", "full_erk2_us_per_step", "<= 10"),
            ("two valves + piston composed, µs per step", "two_valves_piston_rk2_us_per_step", "<= 3"))
    for label, key, target in rows:
        c, p = compiled[key], python[key]
        print(f"| {label} | {c:.2f} ({dt_us / c:.0f}x real time) | {p:.1f} | {p / c:.0f}x | {target} |")
    for kind, target in (("simplified", ">= 200x"), ("full", ">= 50x")):
        print(f"| replay pcv_step_levels, {kind}: real-time factor (max pressure error) | "
              f"{compiled[f'replay_levels_{kind}_real_time_factor']:.0f}x "
              f"({compiled[f'replay_levels_{kind}_pressure_max_error_bar']:.4f} bar) | - | - | {target} |")
    print(f"\n{_first_start_line(start)}")


def _first_start_line(start: dict[str, float]) -> str:
    return (f"first start (fresh process to the emulator's device's first steps): "
            f"{start['first_start_empty_cache_s']:.1f} s compiling into an empty cache "
            f"(CPU {start['first_start_empty_cache_cpu_s']:.1f} s), {start['first_start_cached_s']:.2f} s from "
            f"the cache (CPU {start['first_start_cached_cpu_s']:.2f} s)")


if __name__ == "__main__":
    main()
