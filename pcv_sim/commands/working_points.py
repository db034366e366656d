"""The model at the paper's two working points (70 % duty), as printed (net area A_c - A_cc,
Table 1's preload) and as calibrated (the config), each point with the coil resistance that gives
the table's current (1.50 A, 1.49 A; Sec. 6.1) unless --coil config. --fit refits the calibration
(--kind net_area, force_offset or both) to the table; --write puts it into --config (default: the
shipped config/valve.yaml). See pcv_sim/analysis/calibrate.py."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from pcv_sim.analysis.calibrate import (
    CALIBRATION_KINDS,
    compare_working_points,
    fit_calibration,
    report,
    required_constants,
    write_calibration,
)
from pcv_sim.analysis.in_force import TABLE1_SPRING_PRELOAD, in_force
from pcv_sim.commands.common import add_output_options, emit_json, params_from
from pcv_sim.errors import UsageError
from pcv_sim.params import DEFAULT_CONFIG, replace_param

NAME = "working-points"
HELP = "model vs the paper's working-point table, as printed and calibrated; --fit refits the calibration"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--coil", choices=("table", "config"), default="table",
                   help="table: each point's coil resistance gives the table's current (R = D V / i, Sec. 6.1); "
                        "config: the config's resistance at both (default: %(default)s)")
    p.add_argument("--fit", action="store_true", help="fit the calibration constant(s) of --kind to the table")
    p.add_argument("--kind", choices=CALIBRATION_KINDS, default="net_area",
                   help="with --fit: net_area (calibration.net_area), force_offset (net area as printed, the offset "
                        "in spool.spring_preload) or both (default: %(default)s)")
    p.add_argument("--write", action="store_true", help="with --fit: write the fitted values into --config "
                                                        "(default: the shipped config/valve.yaml)")
    add_output_options(p, plot=False)


def run(args: argparse.Namespace) -> int:
    if args.write and not args.fit:
        raise UsageError("--write needs --fit (it writes the fitted calibration)")
    params = params_from(args)
    printed = replace_param(replace_param(params, "calibration.net_area", None), "spool.spring_preload",
                            TABLE1_SPRING_PRELOAD)
    as_printed, calibrated = compare_working_points(printed, args.coil), compare_working_points(params, args.coil)
    state = in_force(params)
    fit = fit_calibration(params, args.kind, args.coil) if args.fit else None
    if args.json:
        data = {"coil": args.coil, "in_force": state.as_dict(),
                "as_printed": {"net_area_m2": printed.net_area, "points": [r.as_dict() for r in as_printed]},
                "calibrated": {"net_area_m2": params.net_area, "calibration_kind": state.calibration_kind,
                               "force_offset_N": state.force_offset_N,
                               "points": [r.as_dict() for r in calibrated]},
                "required_constants": required_constants(printed, args.coil)}
        if fit is not None:
            data["fit"] = fit.as_dict()
        emit_json(data)
    else:
        coil = "coil resistance per point: the table's currents" if args.coil == "table" else \
            f"coil resistance {params.solenoid.coil_resistance:g} ohm at both points"
        print(f"Working points at 70 % duty ({coil})")
        print(report(f"As printed (net area {printed.net_area:.4g} m^2, preload {TABLE1_SPRING_PRELOAD:g} N):",
                     as_printed))
        print(report(f"Calibrated: {state.text()}", calibrated))
        print("Constant that alone balances each table point:")
        for row in required_constants(printed, args.coil):
            print(f"  {row['name']} ({row['current_A']:.3f} A): force offset {row['force_offset_N']:+.3f} N, "
                  f"or net area {row['net_area_m2']:.5g} m^2")
        if fit is not None:
            vals = ", ".join(f"{k} = {'null' if v is None else f'{v:.4g}'}" for k, v in fit.values.items())
            print(report(f"Fitted ({fit.kind}): {vals}", fit.results))
    if fit is not None and args.write:
        path = Path(args.config) if args.config is not None else DEFAULT_CONFIG
        write_calibration(path, fit.values)
        print(f"wrote {', '.join(fit.values)} to {path}", file=sys.stderr)
    return 0
