"""Fit named valve parameters to one or more recorded bags (step responses, static points where
inputs hold) by bounded, robust nonlinear least squares, estimating each signal's sensor lag and
offset as nuisance parameters. Writes a valve YAML that --config, replay and the emulator's
valve_config accept as is, and optionally a report (fit per signal and per step before and after,
95 % intervals, correlations, warnings for parameters the data cannot separate).
Exit status: 0 done, 1 the fit did not converge or a --fail-above/--fail-below limit was crossed
(the YAML is written all the same), 2 bad input."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import yaml

from pcv_sim.analysis.in_force import in_force, with_damping
from pcv_sim.calibration import CalibrationError, calibrate, fit_parameter
from pcv_sim.calibration.fit import LAG_BOUNDS, TIME_CONSTANT_BOUNDS
from pcv_sim.calibration.report import (
    fitted_yaml,
    plot_fit,
    render_html,
    render_markdown,
    render_text,
    step_fits,
    step_rows,
)
from pcv_sim.commands.common import damping_option, emit_json, metric_limits, params_from
from pcv_sim.io.topics import OUTPUT_ROLES, role_of
from pcv_sim.params import DEFAULT_CONFIG, params_to_mapping
from pcv_sim.replay import detect_steps, input_timeline, load_recording, parse_topic_map

NAME = "calibrate"
HELP = "fit valve parameters (e.g. spool.spring_preload) to recorded bags; write the fitted valve YAML"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("bags", type=Path, nargs="+", metavar="BAG", help="rosbag2 directories or .mcap files")
    p.add_argument("--fit", action="append", required=True, metavar="KEY[=LO:HI][,KEY...]",
                   help="valve parameters to fit, by their path in the valve YAML, e.g. "
                        "spool.spring_preload,calibration.net_area or fluid.bulk_modulus=5e8:2e9 (bounds optional); "
                        "none: estimate only the sensors, to check how well the configured valve explains the bags")
    p.add_argument("-o", "--output", type=Path, required=True, metavar="FITTED.yaml", help="fitted valve YAML to write")
    p.add_argument("--model", choices=("simplified", "full"), default="simplified",
                   help="simplified: the emulator's model (default); full: with damping chamber (slower)")
    p.add_argument("--solver", choices=("auto", "stepper", "fast", "radau"), default="auto",
                   help="as for replay (default: the emulator's own engine, for either model)")
    p.add_argument("--damping", type=damping_option, default=None, metavar="equivalent|paper|NS_PER_M",
                   help="simplified model's damping to start from (default: the config's)")
    p.add_argument("--signals", metavar="ROLES", help="outputs to fit, e.g. pressure,current (default: all recorded)")
    p.add_argument("--topic", action="append", metavar="ROLE=/TOPIC", help="as for replay; repeatable")
    p.add_argument("--sensor", choices=("both", "delay", "first-order", "none"), default="both",
                   help="sensor lag model estimated per signal: a delay, a first-order time constant, both "
                        "(default) or none")
    p.add_argument("--no-offset", action="store_true", help="do not estimate sensor offsets (fix them at 0)")
    p.add_argument("--max-evaluations", type=int, default=100, metavar="N",
                   help="model evaluations the optimiser may use (default: %(default)s)")
    p.add_argument("--fail-above", action="append", metavar="METRIC=LIMIT",
                   help="exit 1 if a metric after the fit exceeds LIMIT, e.g. pressure_rmse_bar=0.5 "
                        "(metrics: <signal>_fit_percent, <signal>_rmse_<bar|a|mm>, worst over the bags)")
    p.add_argument("--fail-below", action="append", metavar="METRIC=LIMIT",
                   help="exit 1 if a metric after the fit is below LIMIT, e.g. pressure_fit_percent=99 "
                        "(with --fit none: a check of the configured valve against the recordings)")
    p.add_argument("--report", type=Path, metavar="OUT.html|OUT.md", help="write an HTML or Markdown report with plots")
    p.add_argument("--json", action="store_true", help="print machine-readable JSON (SI units) instead of text")


def _limits(items: list[str] | None, flag: str) -> dict[str, float]:
    return metric_limits(items, flag, CalibrationError, "pressure_fit_percent=99")


def _progress(k: int, cost: float, elapsed: float) -> None:
    sys.stderr.write(f"\rcalibrate: evaluation {k}, cost {cost:.6g}, {elapsed:.1f} s   ")
    sys.stderr.flush()


def run(args: argparse.Namespace) -> int:
    if args.report is not None and args.report.suffix.lower() not in (".md", ".html", ".htm"):
        raise CalibrationError(f"--report {str(args.report)!r}: the file name must end in .md or .html")
    if args.output.suffix.lower() not in (".yaml", ".yml"):
        raise CalibrationError(f"-o {str(args.output)!r}: the fitted valve YAML's name must end in .yaml or .yml")
    if args.max_evaluations < 2:
        raise CalibrationError(f"--max-evaluations {args.max_evaluations}: accepted is an integer >= 2")
    above, below = _limits(args.fail_above, "--fail-above"), _limits(args.fail_below, "--fail-below")
    roles = None
    if args.signals:
        roles = []
        for name in args.signals.split(","):
            role = role_of(name.strip())
            if role not in OUTPUT_ROLES:
                raise CalibrationError(f"--signals {name!r}: accepted are pressure, current, position (spool_position)")
            roles.append(role)
    params = with_damping(params_from(args), args.damping)
    specs = [spec for item in args.fit for spec in item.split(",") if spec.strip()]
    if specs == ["none"]:  # the sensors only: does the configured valve explain the recordings?
        specs = []
    fit = [fit_parameter(params, spec) for spec in specs]
    topic_map = parse_topic_map(args.topic)
    recordings = [load_recording(b, topic_map) for b in args.bags]
    tty = sys.stderr.isatty()
    result = calibrate(recordings, params, fit, model=args.model, solver=args.solver, roles=roles,
                       lag_bounds=LAG_BOUNDS if args.sensor in ("both", "delay") else None,
                       time_constant_bounds=TIME_CONSTANT_BOUNDS if args.sensor in ("both", "first-order") else None,
                       fit_offsets=not args.no_offset,
                       max_evaluations=args.max_evaluations, progress=_progress if tty else None)
    if tty:
        sys.stderr.write("\n")
    source = Path(args.config) if args.config is not None else DEFAULT_CONFIG
    if source.is_file():
        source_text = source.read_text("utf-8")
    else:  # an ament install without the source tree: the loaded values, without comments
        source_text = yaml.safe_dump(params_to_mapping(params_from(args)), sort_keys=False)
    overrides = {} if args.damping is None else \
        {"spool.viscous_friction_simplified": params.spool.viscous_friction_simplified}
    text = fitted_yaml(source_text, result, [str(b) for b in args.bags], overrides)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(text, "utf-8")
    print(f"wrote {args.output}", file=sys.stderr)
    state = in_force(result.params, args.model)

    per_bag = []
    if args.report is not None or args.json:
        for b, rec in enumerate(recordings):
            timeline, _ = input_timeline(rec.inputs, 0.0, params.circuit.supply_pressure)
            found, _ = detect_steps(timeline, rec.end_ns)
            per_bag.append((str(args.bags[b]), step_fits(result, b, found)))
    steps = [(bag, step_rows(fits)) for bag, fits in per_bag]
    if args.report is not None:
        pngs = plot_fit(result, [str(b) for b in args.bags])
        args.report.parent.mkdir(parents=True, exist_ok=True)
        if args.report.suffix.lower() == ".md":
            plot_dir = args.report.with_name(args.report.stem + "_plots")
            plot_dir.mkdir(parents=True, exist_ok=True)
            paths = {}
            for name, data in pngs.items():
                paths[name] = plot_dir / f"{name}.png"
                paths[name].write_bytes(data)
            args.report.write_text(render_markdown(result, steps, paths, args.report.parent, state.text()), "utf-8")
        else:
            args.report.write_text(render_html(result, steps, pngs, state.text()), "utf-8")
        print(f"wrote {args.report}", file=sys.stderr)
    converged = result.status_code > 0
    metrics = result.scalar_metrics()
    failures = []
    for kind, limits in (("above", above), ("below", below)):
        for key, limit in limits.items():
            if key not in metrics:
                raise CalibrationError(f"unknown metric {key!r} for --fail-{kind}; this fit has: {', '.join(sorted(metrics))}")
            value = metrics[key]
            if (value > limit) if kind == "above" else (value < limit):
                failures.append(f"{key} = {value:.6g} {'>' if kind == 'above' else '<'} {limit:g}")
    if args.json:
        out = result.as_dict()
        out.update(output=str(args.output), in_force=state.as_dict(), converged=converged, failed=failures,
                    steps=[{"bag": bag, "steps": [f.as_dict() for f in fits]} for bag, fits in per_bag])
        emit_json(out)
    else:
        print(render_text(result))
        print(f"  in force: {state.text()}")
    for f in failures:
        print(f"pcv-sim calibrate: FAILED: {f}", file=sys.stderr)
    if not converged:
        print(f"pcv-sim calibrate: the fit did not converge in {result.evaluations} evaluations "
              f"({result.status}); raise --max-evaluations or narrow the bounds", file=sys.stderr)
    return 1 if failures or not converged else 0
