"""Benchmark: the real-time stepper's cost per 0.1 ms step, and the static sweep.

    .venv-kilted/bin/python bench/model_speed.py [--repeats 7] [--steps 20000]

Prints a Markdown table for BENCHMARKS.md. Median over repeats; each repeat runs the stepper
at the 70 % rest point and through a 0.5 -> 0.9 -> 0.4 duty sequence (the realistic mix of
pump-side and tank-side openings).
"""

from __future__ import annotations

import argparse
import platform
import statistics
import time

from pcv_sim.analysis.static import pressure_flow_curve
from pcv_sim.model.valve import ValveModel
from pcv_sim.params import load_params
from pcv_sim.simulation.stepper import RealTimeStepper


def per_step_us(integrator: str, steps: int) -> float:
    params = load_params()
    st = RealTimeStepper(params, integrator=integrator, duty=0.5)
    chunk = steps // 3
    t0 = time.perf_counter()
    for duty in (0.9, 0.4, 0.7):
        st.set_duty(duty)
        st.advance(chunk)
    return (time.perf_counter() - t0) / (3 * chunk) * 1e6


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--steps", type=int, default=20000)
    args = ap.parse_args()
    dt = load_params().simulation.time_step
    print(f"machine: {platform.processor() or platform.machine()}, Python {platform.python_version()}")
    print("| integrator | µs per 0.1 ms step (median) | min | real-time factor (median) |")
    print("|---|---|---|---|")
    for integ in ("euler", "rk2", "rk4"):
        runs = [per_step_us(integ, args.steps) for _ in range(args.repeats)]
        med = statistics.median(runs)
        print(f"| {integ}{' (default)' if integ == 'rk2' else ''} | {med:.2f} | {min(runs):.2f} | {dt * 1e6 / med:.1f}x |")
    model = ValveModel(load_params())
    times = []
    for _ in range(3):
        t0 = time.perf_counter()
        for d in (0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0):
            pressure_flow_curve(model, d, 100)
        times.append(time.perf_counter() - t0)
    print(f"\nstatic sweep, 8 duties x 100 points: {statistics.median(times):.2f} s (median of 3)")


if __name__ == "__main__":
    main()
