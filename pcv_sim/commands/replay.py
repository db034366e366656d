"""Replay a bag: drive the model with the recorded duty command (and load flow / supply
pressure when recorded), each command taking effect at its timestamp, and compare the model's
pressure, current and spool position with the recorded ones: per duty step (rise time,
overshoot, settling time, steady-state error) and over the whole run (RMSE, max error, NRMSE
fit %). Gaps in the recorded outputs (an emulator that skipped steps, a logger that lost samples)
are listed, and the samples from each gap until --resync-ms after it are not compared. Exit
status 1 when a --fail-above / --fail-below threshold is crossed or the bag was not closed
properly (unless --allow-unclosed), 2 on bad input."""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from pathlib import Path

from pcv_sim.commands.common import emit_json, metric_limits, params_from
from pcv_sim.replay import ReplayError, check_thresholds, load_recording, parse_topic_map, replay
from pcv_sim.replay.compare import RESYNC_S
from pcv_sim.replay.report import plot_signals, render_html, render_markdown, render_text

NAME = "replay"
HELP = "replay a bag's inputs through the model and compare with its recorded outputs"


def _limits(items: list[str] | None, flag: str) -> dict[str, float]:
    return metric_limits(items, flag, ReplayError, "pressure_rmse_bar=0.5")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("bag", type=Path, metavar="BAG", help="rosbag2 directory (metadata.yaml + .mcap) or one .mcap file")
    p.add_argument("--model", choices=("full", "simplified"), default="full",
                   help="full: with the damping chamber (Sec. 4.2); simplified: without (Sec. 4.3) "
                        "(default: %(default)s)")
    p.add_argument("--solver", choices=("auto", "stepper", "fast", "radau"), default="auto",
                   help="auto/stepper: the emulator's own engine (compiled, 0.1 ms: Heun for simplified, "
                        "exponential Heun for full), so a bag of the emulator replays exactly; fast: the same; "
                        "radau: the stiff variable-step reference (default: %(default)s)")
    p.add_argument("--topic", action="append", metavar="ROLE=/TOPIC",
                   help="where a signal is in the bag, e.g. pressure=/rig/p (roles: duty_cycle, load_flow, "
                        "supply_pressure, pressure, current, spool_position; aliases duty, position); repeatable")
    p.add_argument("--namespace", metavar="NS",
                   help="the device to replay in a bag of several (the rig node's: one namespace per valve), e.g. "
                        "left or /rig/left (the full namespace or its last part); an unknown one is refused naming "
                        "the bag's device namespaces")
    p.add_argument("--load-volume", type=float, metavar="M3",
                   help="the oil volume at the load port (m^3) instead of the valve YAML's circuit.load_volume, "
                        "e.g. a rig valve's chamber: dead + hose + A (x0 - stroke_min), 2.08e-4 for the shipped "
                        "config/rig.yaml")
    p.add_argument("--report", type=Path, metavar="OUT.md|OUT.html", help="write a Markdown or HTML report with plots")
    p.add_argument("--plot-dir", type=Path, metavar="DIR",
                   help="write the plots (PNG) here; default for a Markdown report: OUT_plots/ beside it")
    p.add_argument("--json", action="store_true", help="print machine-readable JSON (SI units) instead of text")
    p.add_argument("--resync-ms", type=float, default=RESYNC_S * 1e3, metavar="MS",
                   help="after a gap in the recorded outputs, leave this long out of the comparison while "
                        "model and device re-synchronise (default: %(default)g)")
    p.add_argument("--fail-above", action="append", metavar="METRIC=LIMIT",
                   help="exit 1 if METRIC > LIMIT, e.g. pressure_rmse_bar=0.5 (comma-separated or repeated); "
                        "metrics: <signal>_rmse_<u>, _max_error_<u>, _steady_state_error_<u>, _rise_time_error_ms, "
                        "_overshoot_error_percent, _settling_time_error_ms with u = bar, a, mm; gaps, gap_max_ms; "
                        "closed_cleanly (1 or 0)")
    p.add_argument("--fail-below", action="append", metavar="METRIC=LIMIT",
                   help="exit 1 if METRIC < LIMIT, e.g. pressure_fit_percent=99")
    p.add_argument("--allow-unclosed", action="store_true",
                   help="accept a bag that was not closed properly (a writer killed, a file cut short): replay "
                        "its readable part and exit 0 if no limit is crossed; without it such a bag fails the run "
                        "(exit 1, metric closed_cleanly = 0 < 1)")


def run(args: argparse.Namespace) -> int:
    above = _limits(args.fail_above, "--fail-above")
    below = _limits(args.fail_below, "--fail-below")
    if args.report is not None and args.report.suffix.lower() not in (".md", ".html", ".htm"):
        msg = f"--report {str(args.report)!r}: the file name must end in .md or .html"
        raise ReplayError(msg)
    if not (math.isfinite(args.resync_ms) and args.resync_ms >= 0):
        msg = f"--resync-ms {args.resync_ms:g}: accepted is a finite number >= 0 (ms)"
        raise ReplayError(msg)
    params = params_from(args)
    if args.load_volume is not None:
        if not (math.isfinite(args.load_volume) and 1e-6 <= args.load_volume <= 1.0):
            msg = f"--load-volume {args.load_volume:g}: accepted is a volume in m^3 within 1e-06 .. 1 (0.1 L = 1e-4)"
            raise ReplayError(msg)
        params = dataclasses.replace(params, circuit=dataclasses.replace(params.circuit, load_volume=args.load_volume))
    recording = load_recording(args.bag, parse_topic_map(args.topic), namespace=args.namespace)
    if not args.allow_unclosed:   # a damaged recording passes no gate unless accepted by name
        below.setdefault("closed_cleanly", 1.0)
    result = replay(recording, params, model=args.model, solver=args.solver, resync=args.resync_ms / 1e3)
    failures = check_thresholds(result, above, below)
    if not recording.closed_cleanly:   # the reader's warning below says what was lost and where
        if args.allow_unclosed:
            print(f"pcv-sim replay: warning: {args.bag} was not closed properly; its readable part "
                  f"({result.duration_s:.3f} s) is replayed, accepted by --allow-unclosed", file=sys.stderr)
        else:
            print(f"pcv-sim replay: error: {args.bag} was not closed properly: its readable part "
                  f"({result.duration_s:.3f} s) is replayed but the run fails (exit 1); --allow-unclosed "
                  f"accepts a partial recording", file=sys.stderr)
    for w in result.warnings:
        print(f"pcv-sim replay: warning: {w}", file=sys.stderr)
    if result.gaps:
        longest = max(g.duration for g in result.gaps) * 1e3
        print(f"pcv-sim replay: warning: {len(result.gaps)} gap(s) in the recorded outputs (longest "
              f"{longest:.1f} ms); not compared until {result.resync_s * 1e3:g} ms after each", file=sys.stderr)

    plots: dict[str, Path] = {}
    pngs: dict[str, bytes] = {}
    plot_dir = args.plot_dir
    if plot_dir is None and args.report is not None and args.report.suffix.lower() == ".md":
        plot_dir = args.report.with_name(args.report.stem + "_plots")
    if plot_dir is not None or args.report is not None:
        pngs = plot_signals(result)
    if plot_dir is not None:
        plot_dir.mkdir(parents=True, exist_ok=True)
        for role, data in pngs.items():
            path = plot_dir / f"{Path(result.bag).name}_{role}.png"
            path.write_bytes(data)
            plots[role] = path
    if args.report is not None:
        args.report.parent.mkdir(parents=True, exist_ok=True)
        if args.report.suffix.lower() == ".md":
            text = render_markdown(result, plots, failures, args.report.parent)
        else:
            text = render_html(result, pngs, failures)
        args.report.write_text(text, "utf-8")
        print(f"wrote {args.report}", file=sys.stderr)

    if args.json:
        out = result.as_dict()
        out["thresholds"] = {"above": above, "below": below, "failed": [str(f) for f in failures]}
        emit_json(out)
    else:
        print(render_text(result, failures))
    return 1 if failures else 0
