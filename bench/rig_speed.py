"""Benchmark: the rig in lockstep with a Python controller, in one process.

    .venv-kilted/bin/python bench/rig_speed.py [--repeats 5] [--duration 2.0] [--json]

Two simplified valves + the steering cylinder (config/rig.yaml) at 0.1 ms, the example
PI position controller (examples/steering.py) called every control period on that period's
samples, a 20 mm setpoint step: the real-time factor (simulated s per wall s) at a 1 ms and a
10 ms control period, the median of the repeats. Also the parts of one 1 ms period: the 10
compiled steps alone (the floor: the rig with no controller), sampling the outputs, both in the
one compiled call (`Rig.advance_sample`; the lockstep's planned stretch, `Rig.planned_stretch`,
the same call without the method's checks), the controller call (its dict form, and the array
form the lockstep calls); the 1 kHz factor over the floor's. The machine's load average is printed
with the figures: on a shared machine it changes them.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "examples"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--duration", type=float, default=2.0, help="simulated s per run")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()

    from steering import PositionController

    from pcv_sim.jit import backend
    from pcv_sim.rig import Rig, load_rig, run_lockstep

    base = load_rig()
    out: dict[str, object] = {"backend": backend(), "python": platform.python_version(),
                              "cpus": os.cpu_count(), "load_before": os.getloadavg()[0]}
    for period in (1e-3, 1e-2):
        params = dataclasses.replace(base, timing=dataclasses.replace(base.timing, control_period=period))
        rig = Rig(params)
        rtf = []
        for _ in range(args.repeats):
            rig.reset()
            run = run_lockstep(rig, PositionController(period=period), args.duration,
                               setpoint=lambda t: 0.02 if t >= 0.1 else 0.0)
            rtf.append(run.real_time_factor)
        out[f"rtf_{period * 1e3:g}ms"] = {"median": statistics.median(rtf), "best": max(rtf)}
    # The parts of a 1 ms period.
    rig = Rig(base)
    n = int(args.duration / 1e-3)
    sim = rig.sim
    t0 = time.perf_counter()
    for _ in range(n):
        sim.advance(10)
    steps_us = (time.perf_counter() - t0) / n * 1e6
    t0 = time.perf_counter()
    for _ in range(n):
        rig.sample()
    sample_us = (time.perf_counter() - t0) / n * 1e6
    t0 = time.perf_counter()
    for _ in range(n):
        rig.advance_sample(sim.steps + 10)
    fused_us = (time.perf_counter() - t0) / n * 1e6
    stretch = rig.planned_stretch()
    rows = np.empty((n, len(rig.signals)))
    t0 = time.perf_counter()
    for k in range(n):
        stretch(sim.steps + 9, rows[k], 1)
    stretch_us = (time.perf_counter() - t0) / n * 1e6
    ctrl = PositionController()
    m = dict(zip(rig.signals, rig.sample().tolist()))
    m["setpoint"] = 0.01
    t0 = time.perf_counter()
    for k in range(n):
        ctrl(k * 1e-3, m)
    ctrl_us = (time.perf_counter() - t0) / n * 1e6
    ctrl = PositionController()
    step, commanded, flags = ctrl.lockstep_arrays((*rig.signals, "setpoint"), rig.valve_names)
    samples, answer = [*m.values()], [0.0] * (len(commanded) + len(flags))
    t0 = time.perf_counter()
    for k in range(n):
        step(k * 1e-3, samples, answer)
    array_us = (time.perf_counter() - t0) / n * 1e6
    out["per_1ms_period_us"] = {"10_steps": steps_us, "sample": sample_us, "10_steps_and_sample_in_one_call": fused_us,
                                "planned_stretch": stretch_us, "controller": ctrl_us, "controller_array_form": array_us}
    out["floor_rtf"] = 1e3 / steps_us
    out["rtf_1ms_of_floor"] = out["rtf_1ms"]["median"] / out["floor_rtf"]    # type: ignore[index]
    out["load_after"] = os.getloadavg()[0]
    if args.json:
        json.dump(out, sys.stdout, indent=2)
        print()
        return
    r1, r10 = out["rtf_1ms"], out["rtf_10ms"]
    print(f"backend {out['backend']}, Python {out['python']}, {out['cpus']} CPUs, load average "
          f"{out['load_before']:.1f} -> {out['load_after']:.1f}")
    print(f"| control period | real-time factor (median of {args.repeats}) | best |")
    print("|---|---|---|")
    print(f"| 1 ms (1 kHz) | {r1['median']:.1f}x | {r1['best']:.1f}x |")        # type: ignore[index]
    print(f"| 10 ms (100 Hz) | {r10['median']:.1f}x | {r10['best']:.1f}x |")    # type: ignore[index]
    print(f"1 kHz over the floor: {out['rtf_1ms_of_floor']:.3f}")
    print(f"one 1 ms period: 10 steps {steps_us:.1f} us (alone: {out['floor_rtf']:.1f}x real time), "
          f"sampling {sample_us:.1f} us, both in one call {fused_us:.1f} us (the lockstep's planned stretch "
          f"{stretch_us:.1f} us), "
          f"controller {ctrl_us:.1f} us (its array form, which the lockstep calls, {array_us:.1f} us)")


if __name__ == "__main__":
    main()
