"""Benchmark: what `reset` and a `model.*` change cost the real-time loop, over DDS.

    .venv-kilted/bin/python bench/node_restart.py [--count 20] [--load 2]

Starts `python -m pcv_sim.node.emulator` (default parameters, watchdog off, duty 0.6), then calls
`reset` and sets `model.spool.mass` alternately `--count` times each, and reports: the service
round trip at the client (request sent -> answer received), the late and skipped steps the node
counted over the whole sequence (its /diagnostics), and the largest gap between consecutive
`pressure` samples received meanwhile (a stall of the loop shows there).
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import time

import numpy as np
import rclpy

from pcv_sim.node.client import EmulatorClient


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--count", type=int, default=20)
    ap.add_argument("--load", type=int, default=0, help="CPU-bound processes beside the node")
    ap.add_argument("--domain", type=int, default=120 + os.getpid() % 80)
    opts = ap.parse_args()
    env = {k: v for k, v in os.environ.items() if k != "_ROS_WHEELS_BOOTSTRAP_COMPLETE"}
    env.update(ROS_DOMAIN_ID=str(opts.domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    os.environ.update(ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    hogs = [subprocess.Popen([sys.executable, "-c", "while True: pass"], env=env) for _ in range(opts.load)]
    cmd = [sys.executable, "-m", "pcv_sim.node.emulator", "--ros-args", "-r", "__ns:=/bench",
           "-p", "watchdog_timeout:=0.0", "-p", "safe_duty:=0.3", "-p", "diagnostics_period:=0.2"]
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    ctx = rclpy.Context()
    rclpy.init(args=[], context=ctx, domain_id=opts.domain)
    c = EmulatorClient("/bench", context=ctx, node_name="bench_restart", sample_depth=100000)
    try:
        if not c.wait_for_emulator(60):
            print("no emulator samples", file=sys.stderr)
            return 1
        c.send_duty(0.6)
        c.spin_for(1.0)
        first = c.wait_for_diagnostics(timeout=5)
        n0 = len(c.samples)
        trips = {"reset": [], "model.spool.mass": []}
        for k in range(opts.count):
            t = time.perf_counter()
            assert c.reset().success
            trips["reset"].append(time.perf_counter() - t)
            t = time.perf_counter()
            assert c.set_parameters({"model.spool.mass": 0.045 if k % 2 == 0 else 0.04})[0].successful
            trips["model.spool.mass"].append(time.perf_counter() - t)
        c.spin_for(0.5)
        last = c.wait_for_diagnostics(timeout=5)
    finally:
        for h in hogs:
            h.kill()
        proc.send_signal(signal.SIGINT)
        proc.wait(20)
        c.close()
        rclpy.try_shutdown(context=ctx)
    received = np.array([s.received_ns for s in c.samples[n0:]], dtype=np.int64)
    gap = float(np.diff(received).max()) / 1e6 if len(received) > 1 else float("nan")
    print(f"| figure ({opts.count} of each, load {opts.load}) | value |")
    print("|---|---|")
    for name, values in trips.items():
        v = np.array(values) * 1e3
        print(f"| {name} round trip p50 / max | {np.median(v):.1f} / {v.max():.1f} ms |")
    late = int(last["late_steps"]) - int(first["late_steps"])
    skipped = int(last["skipped_steps"]) - int(first["skipped_steps"])
    print(f"| late / skipped steps over the sequence | {late} / {skipped} |")
    print(f"| largest gap between received samples | {gap:.1f} ms |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
