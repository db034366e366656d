"""The model at the paper's two working points (70 % duty), as printed (net area A_c - A_cc)
and calibrated (the config's calibration.net_area). See pcv_sim/analysis/calibrate.py."""

from __future__ import annotations

import argparse

from pcv_sim.analysis.calibrate import _report, compare_working_points, required_constants
from pcv_sim.commands.common import add_output_options, emit_json, params_from
from pcv_sim.params import replace_param

NAME = "working-points"
HELP = "model vs the paper's working-point table, as printed and calibrated"


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_output_options(p, plot=False)


def run(args: argparse.Namespace) -> int:
    params = params_from(args)
    printed = replace_param(params, "calibration.net_area", None)
    as_printed, calibrated = compare_working_points(printed), compare_working_points(params)
    if args.json:
        emit_json({"as_printed": {"net_area_m2": printed.net_area, "points": [r.as_dict() for r in as_printed]},
                   "calibrated": {"net_area_m2": params.net_area, "points": [r.as_dict() for r in calibrated]},
                   "required_constants": required_constants(printed)})
        return 0
    print(_report(f"As printed (net area {printed.net_area:.4g} m^2):", as_printed))
    print(_report(f"Calibrated (net area {params.net_area:.4g} m^2):", calibrated))
    return 0
