"""Static characteristic: the zero-flow equilibrium per duty, and the pressure-flow curves for
30..100 % duty in reducing (load flow > 0) and relieving (load flow < 0) mode, as Fig. 10."""

from __future__ import annotations

import argparse

import numpy as np

from pcv_sim.analysis.static import pressure_flow_curve, zero_flow_equilibrium
from pcv_sim.commands.common import add_output_options, emit_json, fraction, params_from, progress, save
from pcv_sim.errors import UsageError
from pcv_sim.model.valve import ValveModel
from pcv_sim.plotting import pyplot
from pcv_sim.units import M3S_PER_LPM, MM_PER_M, PA_PER_BAR

NAME = "static"
HELP = "zero-flow equilibria and pressure-flow curves (Fig. 10)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--duties", type=fraction, nargs="+", default=[0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0],
                   metavar="D", help="duty fractions (default: 0.3 .. 1.0 in steps of 0.1)")
    p.add_argument("--points", type=int, default=100, help="points per curve over the stroke (default: %(default)s)")
    p.add_argument("--flow-range-lpm", type=float, default=20.0,
                   help="plot load flows within +- this many L/min (default: %(default)s)")
    add_output_options(p)


def run(args: argparse.Namespace) -> int:
    if args.points < 2:
        raise UsageError(f"--points {args.points}: accepted is an integer >= 2")
    model = ValveModel(params_from(args))
    rest = [zero_flow_equilibrium(model, d) for d in args.duties]
    curves = [pressure_flow_curve(model, d, args.points) for d in progress(args.duties, len(args.duties), "curves")]
    if args.json:
        emit_json({
            "zero_flow": [{"duty": r.duty, "current_A": r.current, "spool_position_m": r.spool_position,
                           "pressure_Pa": r.pressure, "pump_leakage_m3s": r.pump_flow} for r in rest],
            "curves": [{"duty": c.duty, "spool_position_m": c.spool_position, "pressure_Pa": c.pressure,
                        "load_flow_m3s": c.load_flow} for c in curves],
        })
    else:
        print("Zero load flow (the spool sits on the tank side, x < 0):")
        print("  duty   current [A]   spool x [mm]   pressure [bar]   pump leakage [L/min]")
        for r in rest:
            print(f"  {r.duty:4.2f}   {r.current:11.3f}   {r.spool_position * MM_PER_M:+12.4f}   {r.pressure / PA_PER_BAR:14.2f}"
                  f"   {r.pump_flow / M3S_PER_LPM:20.3f}")
        print("Pressure-flow curves (reducing: q > 0, relieving: q < 0): pressure [bar] at load flow [L/min]")
        grid = np.array([-10.0, -5.0, -2.0, 0.0, 2.0, 5.0, 10.0, 15.0])
        print("  duty " + "".join(f"{q:+8.0f}" for q in grid))
        for c in curves:
            q = c.load_flow / M3S_PER_LPM
            order = np.argsort(q)
            vals = np.interp(grid, q[order], c.pressure[order] / PA_PER_BAR, left=np.nan, right=np.nan)
            print(f"  {c.duty:4.2f} " + "".join(f"{v:8.1f}" for v in vals))
    if args.plot:
        plt = pyplot()
        fig, (ax_p, ax_x) = plt.subplots(1, 2, figsize=(11, 4.5))
        lim = args.flow_range_lpm
        for c in curves:
            q = c.load_flow / M3S_PER_LPM
            keep = np.abs(q) <= lim
            ax_p.plot(q[keep], c.pressure[keep] / PA_PER_BAR, label=f"{c.duty * 100:.0f} %")
            ax_x.plot(q[keep], c.spool_position[keep] * MM_PER_M, label=f"{c.duty * 100:.0f} %")
        ax_p.set(xlabel="load flow [L/min]  (relieving < 0 < reducing)", ylabel="load pressure [bar]",
                 title="pressure vs flow (cf. Fig. 10a)")
        ax_x.set(xlabel="load flow [L/min]", ylabel="spool position [mm]  (+ opens pump)",
                 title="spool position vs flow (cf. Fig. 10b)")
        for ax in (ax_p, ax_x):
            ax.grid(True, alpha=0.3)
            ax.axvline(0.0, color="k", lw=0.5)
        ax_p.legend(title="duty", fontsize=8)
        save(fig, args.plot)
    return 0
