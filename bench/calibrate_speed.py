"""Calibration speed: a rig-style recording of 8 duty steps of 0.5 s (1 kHz, sensor lag, noise,
offset, DAQ units and broken rows through import-csv), made with the model and a perturbed
valve, calibrated with `pcv_sim.calibration.calibrate`. Prints the wall time, the model
evaluations and simulations, and what the fit recovered against the truth.

    .venv-kilted/bin/python bench/calibrate_speed.py [--solver stepper fast] [--model simplified]
"""

from __future__ import annotations

import argparse
import platform
import sys
import tempfile
import time
from pathlib import Path

from pcv_sim.calibration import calibrate, fit_parameter, write_rig_csv
from pcv_sim.io.csv_import import import_csv
from pcv_sim.params import default_params, replace_param
from pcv_sim.replay import load_recording

DUTIES = [0.3, 0.5, 0.7, 0.9, 0.5, 0.8, 0.4, 0.6]          # 8 steps of 0.5 s: 4 s at 1 kHz
TRUTH = {"spool.spring_preload": 2.6, "calibration.net_area": 2.95e-6}
LAG = {"pressure": 0.003, "current": 0.0005, "spool_position": 0.001}
NOISE = {"pressure": 0.3e5, "current": 0.005, "spool_position": 0.003e-3}
OFFSET = {"pressure": 0.5e5, "current": 0.01, "spool_position": 0.005e-3}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--solver", nargs="+", default=["stepper", "fast"], choices=("stepper", "fast", "radau"))
    ap.add_argument("--model", choices=("simplified", "full"), default="simplified")
    ap.add_argument("--fit", default=",".join(TRUTH), help="keys to fit (default: %(default)s)")
    args = ap.parse_args(argv)
    p0 = default_params()
    truth = p0
    for key, value in TRUTH.items():
        truth = replace_param(truth, key, value)
    print(f"# {platform.machine()}, Python {platform.python_version()}, {time.strftime('%Y-%m-%d')}")
    with tempfile.TemporaryDirectory() as tmp:
        csv = write_rig_csv(Path(tmp) / "rig.csv", truth, DUTIES, hold_s=0.5, lag_s=LAG, noise=NOISE,
                            offset=OFFSET, seed=2, model=args.model if args.model == "simplified" else "full")
        import_csv(csv, Path(tmp) / "rig", skip_bad_rows=True)
        rec = load_recording(Path(tmp) / "rig")
        fit = [fit_parameter(p0, k) for k in args.fit.split(",")]
        print("| model (solver) | fitted | wall [s] | evaluations | simulations | recovered (truth) +- 95 % | "
              "pressure fit % before -> after |")
        print("|---|---|---|---|---|---|---|")
        for solver in args.solver:
            t0 = time.perf_counter()
            res = calibrate([rec], p0, fit, model=args.model, solver=solver)
            wall = time.perf_counter() - t0
            got = "; ".join(f"{e.name} {e.value:.5g} ({TRUTH.get(e.name, float('nan')):.4g}) +- {e.half_width_95:.2g}"
                            for e in res.parameters)
            pres = next(s for s in res.signals if s.role == "pressure")
            print(f"| {args.model} ({solver}) | {len(fit)} + {len(res.lags)} delays + {len(res.time_constants)} time "
                  f"constants + {len(res.offsets)} offsets | "
                  f"{wall:.1f} | {res.evaluations} | {res.simulations} | {got} | "
                  f"{pres.fit_before_percent:.2f} -> {pres.fit_after_percent:.2f} |")
            sys.stdout.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())
