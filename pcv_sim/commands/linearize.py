"""Linear analysis (Sec. 5, appendix A.1) at the paper's two working points: K_e = K - K_fx +
K_ff, the flow gains, eigenvalues, and the gain and phase margins of the hydro-mechanical loop
gain (Fig. 7), with its Bode plot. Each point runs with the coil resistance that gives the table's
current (1.50 A, 1.49 A; Sec. 6.1) unless --coil config; --damping names the simplified model's
damping (equivalent: B + A_cc^2/K_d, the default; paper: Table 1's 223.6 Ns/m; or a number).
The gain margin is the one nearest to instability over all phase crossovers (negative when the
loop is unstable)."""

from __future__ import annotations

import argparse

import numpy as np

from pcv_sim.analysis.calibrate import point_params
from pcv_sim.analysis.in_force import in_force, with_damping
from pcv_sim.analysis.linear import linearize
from pcv_sim.analysis.paper import WORKING_POINT_DUTY, WORKING_POINTS
from pcv_sim.commands.common import add_output_options, damping_option, emit_json, params_from, save
from pcv_sim.model.valve import ValveModel
from pcv_sim.plotting import pyplot
from pcv_sim.units import MM_PER_M, bar

NAME = "linearize"
HELP = "Sec. 5 linear model at both working points, margins, Bode plot of the loop gain"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--damping", type=damping_option, default=None, metavar="equivalent|paper|NS_PER_M",
                   help="the simplified model's damping (default: the config's)")
    p.add_argument("--coil", choices=("table", "config"), default="table",
                   help="table: each point's coil resistance gives the table's current; config: the config's "
                        "(default: %(default)s)")
    add_output_options(p)


def run(args: argparse.Namespace) -> int:
    params = with_damping(params_from(args), args.damping)
    state = in_force(params)
    lins = {wp.name: linearize(ValveModel(point_params(params, wp, args.coil)), WORKING_POINT_DUTY, wp.spool_position)
            for wp in WORKING_POINTS}
    keys = ("K_fi", "K_fx", "K_ff", "K", "K_e", "K_q", "K_c", "K_cps", "inductance")
    if args.json:
        data = {name: {**{k: getattr(lin, k) for k in keys},
                       "pressure_Pa": lin.point.pressure, "spool_position_m": lin.point.spool_position,
                       "current_A": lin.point.current,
                       "eigenvalues": [[e.real, e.imag] for e in lin.eigenvalues],
                       "stable": bool(np.all(lin.eigenvalues.real < 0)),
                       "margins": lin.margins.__dict__}
                for name, lin in lins.items()}
        emit_json({**data, "in_force": {**state.as_dict(), "coil": args.coil}})
    else:
        print(f"In force: {state.text()}; coil: {'the table current per point' if args.coil == 'table' else 'config'}")
        for name, lin in lins.items():
            m = lin.margins
            print(f"{name}: x = {lin.point.spool_position * MM_PER_M:+.4f} mm, p = {bar(lin.point.pressure):.2f} bar, "
                  f"i = {lin.point.current:.3f} A")
            print(f"  K_e = K - K_fx + K_ff = {lin.K:.0f} - ({lin.K_fx:.0f}) + ({lin.K_ff:.0f}) = {lin.K_e:.0f} N/m")
            print(f"  K_fi = {lin.K_fi:.2f} N/A, K_q = {lin.K_q:.4g} m^2/s, K_c = {lin.K_c:.4g} m^3/(s Pa), "
                  f"K_cps = {lin.K_cps:.4g} m^3/(s Pa), L = {lin.inductance * 1e3:.1f} mH")
            print("  eigenvalues [1/s]: " + ", ".join(f"{e.real:.1f}{e.imag:+.1f}j" for e in lin.eigenvalues)
                  + ("  (stable)" if np.all(lin.eigenvalues.real < 0) else "  (UNSTABLE)"))
            assert m is not None                     # linearize() always computes the margins
            at = "DC" if m.phase_crossover == 0.0 else f"{m.phase_crossover:.0f} rad/s"
            print(f"  loop gain: gain margin {m.gain_margin_db:.1f} dB at {at}, "
                  f"phase margin {m.phase_margin_deg:.1f} deg at {m.gain_crossover:.0f} rad/s")
    if args.plot:
        plt = pyplot()
        w = np.logspace(0, 5, 2000)
        fig, (ax_m, ax_p) = plt.subplots(2, 1, figsize=(8, 7), sharex=True)
        for (name, lin), style in zip(lins.items(), ("-", "--")):
            resp = lin.loop_gain(w)
            ax_m.semilogx(w, 20 * np.log10(np.abs(resp)), style, label=name)
            ax_p.semilogx(w, np.degrees(np.unwrap(np.angle(resp))), style, label=name)
            mg = lin.margins
            assert mg is not None
            ax_m.plot([mg.gain_crossover], [0.0], "o")
            ax_p.plot([mg.gain_crossover], [mg.phase_margin_deg - 180.0], "o")
        ax_m.axhline(0, color="k", lw=0.5)
        ax_p.axhline(-180, color="k", lw=0.5)
        ax_m.set(ylabel="|L| [dB]", title="loop gain (cf. Fig. 7): P1 solid, P2 dashed")
        ax_p.set(ylabel="phase [deg]", xlabel="frequency [rad/s]")
        for ax in (ax_m, ax_p):
            ax.grid(True, which="both", alpha=0.3)
            ax.legend()
        save(fig, args.plot)
    return 0
