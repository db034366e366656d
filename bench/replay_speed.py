"""Benchmark: replay speed of the reference bags (bags/), per model and solver.

    .venv-kilted/bin/python bench/replay_speed.py [--repeats 5]

Times `pcv_sim.replay.replay` (model run + comparison; the bag is read once, outside the
timing) and reports the real-time factor = bag duration / wall time (best and median of the
repeats), with the pressure fit against the bag. Prints a Markdown table for BENCHMARKS.md.
"""

from __future__ import annotations

import argparse
import platform
import statistics
import time
from pathlib import Path

from pcv_sim.params import load_params
from pcv_sim.replay import load_recording, replay

BAGS = Path(__file__).resolve().parents[1] / "bags"
CASES = (("simplified", "stepper"), ("full", "stepper"), ("full", "radau"))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    params = load_params()
    print(f"machine: {platform.machine()}, Python {platform.python_version()}")
    print("| bag | model (solver) | duration [s] | wall [s] best / median | real-time factor best / median "
          "| pressure RMSE [bar] | max error [bar] | fit % |")
    print("|---|---|---|---|---|---|---|---|")
    for bag in ("pcv_step_levels", "pcv_step_amplitudes"):
        rec = load_recording(BAGS / bag)
        for model, solver in CASES:
            repeats = 1 if solver == "radau" else args.repeats
            replay(rec, params, model=model, solver=solver)  # type: ignore[arg-type]  # compile/load first
            walls, result = [], None
            for _ in range(repeats):
                t0 = time.perf_counter()
                result = replay(rec, params, model=model, solver=solver)  # type: ignore[arg-type]
                walls.append(time.perf_counter() - t0)
            assert result is not None
            m = result.scalar_metrics()
            best, med = min(walls), statistics.median(walls)
            print(f"| {bag} | {model} ({solver}) | {result.duration_s:.3f} | {best:.3f} / {med:.3f} | "
                  f"{result.duration_s / best:.1f}x / {result.duration_s / med:.1f}x | "
                  f"{m['pressure_rmse_bar']:.4f} | {m['pressure_max_error_bar']:.4f} | "
                  f"{m['pressure_fit_percent']:.4f} |")


if __name__ == "__main__":
    main()
