"""`demo`: drive a duty step sequence against a running emulator and print what came back.

    make run                      # terminal 1: the emulator
    make demo                     # terminal 2: python -m pcv_sim.node.demo
    python -m pcv_sim.node.demo --namespace /left --duties 0.3,0.7 --hold 0.5

Starts nothing itself: it finds the emulator's topics in `--namespace`, sends each duty of the
sequence (repeated at 50 Hz, as a controller would, so the watchdog stays fed), records the
pressure samples, and prints per step the commanded duty, the settled pressure (bar, mean over
the last 10 % of the step), the 10-90 % rise time and the overshoot, from the samples stamped
within each step. A step it could not measure (too few samples: the emulator stopped or lagged
far behind) says why; the exit status is 1 when no step was measured. Meant for the real-time
mode; against a simulated-time emulator in lockstep it would advance one sample per command.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from typing import Any, TextIO

import numpy as np
import rclpy
from rclpy.signals import SignalHandlerOptions
from rclpy.utilities import remove_ros_args, try_shutdown

from pcv_sim.analysis.metrics import step_metrics
from pcv_sim.node.client import EmulatorClient, PressureSample
from pcv_sim.units import PA_PER_BAR

__all__ = ["exit_status", "main", "measure_steps", "run_demo"]

COMMAND_PERIOD = 0.02   # s, 50 Hz


def _duties(text: str) -> list[float]:
    try:
        values = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: accepted is a comma-separated list of duty fractions") from None
    if not values or not all(math.isfinite(v) and 0.0 <= v <= 1.0 for v in values):
        raise argparse.ArgumentTypeError(f"{text!r}: each duty is a fraction 0..1 (0.7, not 70)")
    return values


def _positive(text: str) -> float:
    v = float(text)
    if not (math.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f"{text!r}: accepted is a number > 0")
    return v


#: s the demo listens at most after the last step for its samples: until one stamped after the step
#: has come (the emulator's samples come in order, so the step's are in: a lagging loop publishes
#: them late, a loaded demo takes them late).
GRACE = 2.0
#: A step with fewer samples stamped in it is not measured.
MIN_SAMPLES = 10


def measure_steps(steps: list[tuple[float, int, int]], samples: list[PressureSample]) -> list[dict[str, Any]]:
    """Metrics per step from the samples *stamped* in it (not by when they arrived: a lagging
    emulator publishes a step's samples late, or a burst of an earlier step's during a later one).

    `steps`: (duty, start ns, end ns) in the samples' time (the ROS clock); one row per step with
    ``duty``, ``samples`` and either the metrics (``settled_bar``, ``rise_time_ms``,
    ``overshoot_percent``) or ``reason``: why it could not be measured."""
    t_all = np.array([s.stamp_ns for s in samples], dtype=np.int64)
    order = np.argsort(t_all, kind="stable")
    t_all = t_all[order]
    p_all = np.array([samples[k].pressure for k in order], dtype=float)
    rate = 1e9 / float(np.median(np.diff(t_all))) if len(t_all) > 1 else math.nan
    rows: list[dict[str, Any]] = []
    for duty, t0, t1 in steps:
        a, b = np.searchsorted(t_all, t0), np.searchsorted(t_all, t1)
        row: dict[str, Any] = {"duty": duty, "samples": int(b - a)}
        rows.append(row)
        expected = f" of ~{(t1 - t0) * 1e-9 * rate:.0f} expected" if math.isfinite(rate) else ""
        if b - a < MIN_SAMPLES:
            row["reason"] = (f"{b - a} samples stamped in the step{expected} (at least {MIN_SAMPLES} needed): the "
                             "emulator published none for it (stopped, or so far behind wall time that it skipped "
                             "steps; see its timing diagnostics)")
            continue
        if a == 0:
            row["reason"] = "no sample before the step: the pressure it started from is unknown"
            continue
        t = (t_all[a - 1:b] - t0) / 1e9
        m = step_metrics(t, p_all[a - 1:b] / PA_PER_BAR, 0.0)
        row.update(settled_bar=m.final, rise_time_ms=m.rise_time * 1e3, overshoot_percent=m.overshoot_percent)
        if math.isfinite(rate) and b - a < 0.5 * (t1 - t0) * 1e-9 * rate:
            row["note"] = f"only {b - a} samples{expected}"
    return rows


def exit_status(rows: list[dict[str, Any]], err: TextIO = sys.stderr) -> int:
    """1 when no step was measured, else 0; says which steps were not measured."""
    missing = [k for k, row in enumerate(rows, 1) if "reason" in row]
    if len(missing) == len(rows):
        print(f"demo: measured none of the {len(rows)} steps (see the table for why)", file=err)
        return 1
    if missing:
        print(f"demo: step(s) {', '.join(map(str, missing))} not measured (see the table for why)", file=err)
    return 0


def run_demo(client: EmulatorClient, duties: list[float], hold: float, out: TextIO = sys.stdout) -> list[dict[str, Any]]:
    """Send the sequence, return one row per step (`measure_steps`) and print the table."""
    steps = []
    for duty in duties:
        t_step = client.node.get_clock().now().nanoseconds     # the samples' clock (real time: the ROS clock)
        end = time.monotonic() + hold
        while time.monotonic() < end:
            client.send_duty(duty)
            client.spin_for(min(COMMAND_PERIOD, max(0.0, end - time.monotonic())))
        steps.append((duty, t_step, client.node.get_clock().now().nanoseconds))
    if steps:
        last_end = steps[-1][2]
        client.spin_until(lambda: bool(client.samples) and client.samples[-1].stamp_ns >= last_end, GRACE)
    rows = measure_steps(steps, client.samples)
    print(f"{'step':>4}  {'duty':>5}  {'settled [bar]':>13}  {'rise 10-90 % [ms]':>17}  {'overshoot [%]':>13}  "
          f"{'samples':>7}", file=out)
    for k, row in enumerate(rows, 1):
        if "reason" in row:
            print(f"{k:>4}  {row['duty']:>5.2f}  {'not measured':>13}  {row['reason']}", file=out)
            continue
        rise = "-" if math.isnan(row["rise_time_ms"]) else f"{row['rise_time_ms']:.1f}"
        note = f"  ({row['note']})" if "note" in row else ""
        print(f"{k:>4}  {row['duty']:>5.2f}  {row['settled_bar']:>13.2f}  {rise:>17}  {row['overshoot_percent']:>13.1f}  "
              f"{row['samples']:>7}{note}", file=out)
    return rows


def main(args: list[str] | None = None) -> int:
    argv = list(sys.argv if args is None else args)
    parser = argparse.ArgumentParser(prog="demo", description=__doc__.split("\n\n")[0])
    parser.add_argument("--namespace", default="/", help="the emulator's namespace (default /)")
    parser.add_argument("--duties", type=_duties, default=_duties("0.3,0.5,0.7,0.5,0.3"),
                        help="duty fractions to step through (default 0.3,0.5,0.7,0.5,0.3)")
    parser.add_argument("--hold", type=_positive, default=0.5, help="seconds per step (default 0.5)")
    parser.add_argument("--timeout", type=_positive, default=15.0,
                        help="seconds to wait for the emulator (default 15)")
    opts = parser.parse_args(remove_ros_args(argv)[1:])
    rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    client = None
    try:
        client = EmulatorClient(opts.namespace, node_name="pcv_demo")
        if not client.wait_for_emulator(opts.timeout):
            print(f"demo: no emulator answering on {client.emulator_name.rsplit('/', 1)[0] or ''}/pressure within "
                  f"{opts.timeout:g} s: start one first (make run)", file=sys.stderr)
            return 1
        print(f"demo: emulator {client.emulator_name}, {len(opts.duties)} duty steps of {opts.hold:g} s")
        return exit_status(run_demo(client, opts.duties, opts.hold))
    except KeyboardInterrupt:
        return 130
    finally:
        if client is not None:
            client.close()
        try_shutdown()


if __name__ == "__main__":
    sys.exit(main())
