"""Benchmark: the rig node in real time (two valves + cylinder) against one emulator, over DDS.

    .venv-kilted/bin/python bench/rig_realtime.py --duration 30 [--load 0] [--json FILE]

Runs, one after the other, each in its own ROS domain on localhost:

- one emulator (`python -m pcv_sim.node.emulator`, default parameters, watchdog off),
- the rig node (`python -m pcv_sim.node.rig -p time_mode:=real`, config/rig.yaml: two
  simplified valves + the steering cylinder at 0.1 ms, samples every 1 ms),

and drives each the same way from this process: a duty command for every valve at 100 Hz (a
square wave 0.3 <-> 0.7, period 1.4 s: what a controller at 100 Hz would send), every valve's
`pressure` taken best effort with a deep queue (polled with take_message, so the client stays
cheap beside the node on 2 cores). After a 3 s warm-up, over the window:

- CPU of the node's process (utime + stime from /proc over the window / wall time), and of it
  the loop's thread and the others,
- the loop thread's CPU time per wake and its longest wake-to-wake gap with what filled it (the
  node's /diagnostics), the loop thread's wait for a CPU and the machine's CPU pressure
  (`bench/node_realtime.py` says how),
- late steps and skipped steps (deltas of the node's /diagnostics counters), and the largest
  model lag behind wall time the node reported,
- pressure samples received per valve, against the window's 1 ms grid.

`--load N` starts N CPU-bound processes beside the node (as the tests' cpu_load).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from node_realtime import _cpu_seconds, _thread_cpu_seconds, _waiting, wake_figures, wake_rows  # bench/ on sys.path
from rclpy.qos import QoSProfile
from sensor_msgs.msg import FluidPressure
from std_msgs.msg import Float64

from pcv_sim.node.client import sample_qos
from pcv_sim.node.inputs import drain


def _ignore(_msg: object) -> None:
    """Subscriptions need a callback; messages are taken by `drain`."""


def measure(kind: str, duration: float, domain: int) -> dict[str, object]:
    env = {k: v for k, v in os.environ.items() if k != "_ROS_WHEELS_BOOTSTRAP_COMPLETE"}
    env.update(ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    if kind == "emulator":
        cmd = [sys.executable, "-m", "pcv_sim.node.emulator", "--ros-args", "-r", "__ns:=/bench",
               "-p", "watchdog_timeout:=0.0"]
        valves = [""]
    else:
        cmd = [sys.executable, "-m", "pcv_sim.node.rig", "--ros-args", "-r", "__ns:=/bench",
               "-p", "time_mode:=real"]
        valves = ["left/", "right/"]
    log = open(f"/tmp/pcv_bench_{kind}_{os.getpid()}.log", "w")
    proc = subprocess.Popen(cmd, env=env, stdout=log, stderr=subprocess.STDOUT)
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=domain)
    node = rclpy.create_node("bench_client", namespace="/bench", context=ctx)
    counts = dict.fromkeys(valves, 0)
    diags: list[dict[str, str]] = []

    def on_pressure(v: str):
        def take(_msg: FluidPressure, _info: object) -> None:
            counts[v] += 1
        return take

    def on_diag(msg: DiagnosticArray, _info: object) -> None:
        flat: dict[str, str] = {}
        for st in msg.status:
            flat.update({kv.key: kv.value for kv in st.values})
        if "late_steps" in flat:
            diags.append(flat)

    subs = [(node.create_subscription(FluidPressure, f"{v}pressure", _ignore, sample_qos(100000)), on_pressure(v))
            for v in valves]
    subs.append((node.create_subscription(DiagnosticArray, "/diagnostics", _ignore, QoSProfile(depth=100)), on_diag))
    pubs = [node.create_publisher(Float64, f"{v}duty_cycle", QoSProfile(depth=10)) for v in valves]
    try:
        end = time.monotonic() + 60.0
        while not all(counts.values()):
            drain(subs)
            for p in pubs:
                p.publish(Float64(data=0.3))
            time.sleep(0.01)
            if time.monotonic() > end:
                raise RuntimeError(f"{kind}: no samples within 60 s (log {log.name})")
        duty, t_switch = 0.3, time.monotonic()
        warm_end = time.monotonic() + 3.0
        start = None
        n0: dict[str, int] = {}
        d0 = 0
        cpu0 = 0.0
        threads0 = waited0 = (0.0, 0.0)
        next_cmd = time.monotonic()
        while True:
            now = time.monotonic()
            if start is None and now >= warm_end and diags:
                start, cpu0, n0, d0 = now, _cpu_seconds(proc.pid), dict(counts), len(diags)
                threads0, waited0 = _thread_cpu_seconds(proc.pid), _waiting(proc.pid)
            if start is not None and now >= start + duration and len(diags) > d0:
                break
            if now >= next_cmd:
                if now - t_switch >= 0.7:
                    duty, t_switch = (0.7 if duty == 0.3 else 0.3), now
                for p in pubs:
                    p.publish(Float64(data=duty))
                next_cmd += 0.01
            drain(subs)
            time.sleep(0.001)
        wall = time.monotonic() - start
        cpu = _cpu_seconds(proc.pid) - cpu0
        threads1, waited1 = _thread_cpu_seconds(proc.pid), _waiting(proc.pid)
        first, last = diags[d0 - 1], diags[-1]
        lags = [float(d.get("period_max_lag_ms") or d.get("max_lag_ms") or "nan") for d in diags[d0:]]
        return {
            "kind": kind, "window_s": wall, "cpu_percent": 100.0 * cpu / wall,
            "cpu_loop_thread_percent": 100.0 * (threads1[0] - threads0[0]) / wall,
            "cpu_other_threads_percent": 100.0 * (threads1[1] - threads0[1]) / wall,
            "wakes": wake_figures(diags[d0:]),
            "loop_waiting_for_cpu_percent": 100.0 * (waited1[0] - waited0[0]) / wall,
            "cpu_pressure_some_percent": 100.0 * (waited1[1] - waited0[1]) / wall,
            "late_steps": int(last["late_steps"]) - int(first["late_steps"]),
            "skipped_steps": int(last["skipped_steps"]) - int(first["skipped_steps"]),
            "steps": round(wall / 1e-4),
            "max_lag_ms": max(lags) if lags else float("nan"),
            "samples_per_valve": {v.rstrip("/") or "valve": counts[v] - n0[v] for v in valves},
            "samples_expected": int(wall / 1e-3),
        }
    finally:
        node.destroy_node()
        rclpy.shutdown(context=ctx)
        proc.send_signal(2)
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
        log.close()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--duration", type=float, default=30.0, help="measurement window per node, s")
    ap.add_argument("--load", type=int, default=0, help="CPU-bound processes beside the node")
    ap.add_argument("--json", type=Path, help="write the figures here")
    opts = ap.parse_args()
    os.environ.update(ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    hogs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(opts.load)]
    base = 120 + os.getpid() % 60
    try:
        load0 = os.getloadavg()[0]
        results = [measure("emulator", opts.duration, base), measure("rig", opts.duration, base + 1)]
        load1 = os.getloadavg()[0]
    finally:
        for h in hogs:
            h.kill()
    if opts.json:
        opts.json.write_text(json.dumps({"results": results, "load": [load0, load1], "hogs": opts.load}, indent=2))
    print(f"{opts.duration:g} s window each, {opts.load} CPU hogs, load average {load0:.1f} -> {load1:.1f}")
    print("| figure | one emulator | rig: two valves + cylinder |")
    print("|---|---|---|")
    e, r = results

    def row(name: str, fmt) -> None:
        print(f"| {name} | {fmt(e)} | {fmt(r)} |")

    row("node CPU, % of one core", lambda x: f"{x['cpu_percent']:.1f}")
    row("late steps (of the window's steps)", lambda x: f"{x['late_steps']} of {x['steps']} "
        f"({100.0 * x['late_steps'] / x['steps']:.2f} %)")
    row("skipped steps", lambda x: f"{x['skipped_steps']}")
    row("largest model lag reported, ms", lambda x: f"{x['max_lag_ms']:.2f}")
    we, wr = wake_rows(e), wake_rows(r)
    for name in dict.fromkeys([*we, *wr]):
        print(f"| {name} | {we.get(name, '-')} | {wr.get(name, '-')} |")
    row("pressure samples received per valve (1 ms grid)", lambda x: ", ".join(
        f"{n}" for n in x["samples_per_valve"].values()) + f" of {x['samples_expected']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
