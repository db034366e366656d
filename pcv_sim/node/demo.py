"""`demo`: drive a duty step sequence against a running emulator and print what came back.

    make run                      # terminal 1: the emulator
    make demo                     # terminal 2: python -m pcv_sim.node.demo
    python -m pcv_sim.node.demo --namespace /left --duties 0.3,0.7 --hold 0.5

Starts nothing itself: it finds the emulator's topics in `--namespace`, sends each duty of the
sequence (repeated at 50 Hz, as a controller would, so the watchdog stays fed), records the
pressure samples, and prints per step the commanded duty, the settled pressure (bar, mean over
the last 10 % of the step), the 10-90 % rise time and the overshoot. Meant for the real-time
mode; against a simulated-time emulator in lockstep it would advance one sample per command.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from typing import TextIO

import numpy as np
import rclpy
from rclpy.signals import SignalHandlerOptions
from rclpy.utilities import remove_ros_args, try_shutdown

from pcv_sim.analysis.metrics import step_metrics
from pcv_sim.node.client import EmulatorClient

__all__ = ["main", "run_demo"]

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


def run_demo(client: EmulatorClient, duties: list[float], hold: float, out: TextIO = sys.stdout) -> list[dict[str, float]]:
    """Send the sequence, return one row of metrics per step (and print the table)."""
    steps = []
    for duty in duties:
        t_step = time.time_ns()
        start = len(client.samples)
        end = time.monotonic() + hold
        while time.monotonic() < end:
            client.send_duty(duty)
            client.spin_for(min(COMMAND_PERIOD, max(0.0, end - time.monotonic())))
        steps.append((duty, t_step, client.samples[start:]))
    rows = []
    print(f"{'step':>4}  {'duty':>5}  {'settled [bar]':>13}  {'rise 10-90 % [ms]':>17}  {'overshoot [%]':>13}  "
          f"{'samples':>7}", file=out)
    previous = client.samples[0].pressure if client.samples else math.nan
    for k, (duty, t_step, samples) in enumerate(steps, 1):
        if len(samples) < 10:
            print(f"{k:>4}  {duty:>5.2f}  {'(no samples)':>13}", file=out)
            continue
        t = np.array([s.stamp_ns for s in samples], dtype=np.int64)
        y = np.array([previous] + [s.pressure for s in samples]) / 1e5
        tt = np.concatenate([[t[0] - 1_000_000], t])
        m = step_metrics((tt - t_step) / 1e9, y, 0.0)
        previous = samples[-1].pressure
        row = {"duty": duty, "settled_bar": m.final, "rise_time_ms": m.rise_time * 1e3,
               "overshoot_percent": m.overshoot_percent, "samples": len(samples)}
        rows.append(row)
        rise = "-" if math.isnan(m.rise_time) else f"{m.rise_time * 1e3:.1f}"
        print(f"{k:>4}  {duty:>5.2f}  {m.final:>13.2f}  {rise:>17}  {m.overshoot_percent:>13.1f}  {len(samples):>7}",
              file=out)
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
        run_demo(client, opts.duties, opts.hold)
        return 0
    except KeyboardInterrupt:
        return 130
    finally:
        if client is not None:
            client.close()
        try_shutdown()


if __name__ == "__main__":
    sys.exit(main())
