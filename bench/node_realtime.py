"""Benchmark: the emulator node in real time, over DDS, from a separate client process.

    .venv-kilted/bin/python bench/node_realtime.py --duration 60
    .venv-kilted/bin/python bench/node_realtime.py --duration 600      # the 10-minute run
    .venv-kilted/bin/python bench/node_realtime.py --duration 60 --load 2 --param overrun:=skip

Starts `python -m pcv_sim.node.emulator` (this interpreter, default parameters, watchdog off)
in its own ROS domain on localhost, subscribes to `pressure` best-effort with a deep queue, and
measures, after a 2 s warm-up:

- publish period: differences of the DDS source timestamps of consecutive samples (when the
  node handed them to DDS), p50 / p99 / max; lost samples from gaps in the stamps;
- publish lag: source timestamp - header stamp, i.e. how long after its model time each sample
  left the node (the model-vs-wall lag a subscriber sees);
- command -> first changed pressure sample: every ~0.7 s (at a random phase against the 1 ms
  sample grid) the duty steps 0.3 <-> 0.7; latency =
  DDS reception time (at this client) of the first sample whose pressure moved by > 3 Pa from
  the previous one, minus the command's DDS source timestamp (this client's own publication,
  read back from the topic). 0.7 s lets the previous step ring down below 0.1 Pa per sample,
  while the first 0.1 ms step of a new command already moves the pressure by ~16 Pa;
- CPU of the node process (utime + stime from /proc/<pid>/stat over the window / wall time), and
  of it the loop's thread (the main thread) and the others (DDS, a recorder);
- the loop thread's CPU time per wake (mean, largest) and its longest wake-to-wake gap with what
  filled it (the node's /diagnostics: its work, a garbage collection, time off the CPU inside the
  wake, a sleep the OS ended late; the wake's parts), and the diagnostics periods whose longest
  gap exceeded 5 ms, by cause; how long the loop thread, runnable, waited for a CPU
  (/proc/<pid>/task/<pid>/schedstat) and the machine's CPU pressure (/proc/pressure/cpu, "some"),
  as shares of the window: what the OS made of the loop's time;
- late steps, skipped steps, max model lag before/after a batch, from the node's /diagnostics
  (counts as deltas over the window, lags as the max of the per-period maxima).

Prints a Markdown table (and --json FILE writes the raw figures).
"""

from __future__ import annotations

import argparse
import json
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import rclpy
from rclpy.qos import QoSProfile
from std_msgs.msg import Float64

from pcv_sim.node.client import EmulatorClient


def _cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _thread_cpu_seconds(pid: int) -> tuple[float, float]:
    """(the main thread's, every other thread's) CPU seconds of process `pid`: the node's loop runs
    in its main thread; DDS, the recorder and the rest-state worker in others."""
    main = others = 0.0
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            fields = (task / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:             # a thread that ended meanwhile
            continue
        seconds = (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
        if task.name == str(pid):
            main += seconds
        else:
            others += seconds
    return main, others


def _waiting(pid: int) -> tuple[float, float]:
    """(s the node's loop thread has waited for a CPU while runnable, s some task on the machine
    has: `/proc/<pid>/task/<pid>/schedstat`, `/proc/pressure/cpu`), (nan, nan) where unreadable:
    what the OS, not the loop, made of its time."""
    try:
        loop = int(Path(f"/proc/{pid}/task/{pid}/schedstat").read_text().split()[1]) / 1e9
    except (OSError, IndexError, ValueError):
        loop = float("nan")
    try:
        some = Path("/proc/pressure/cpu").read_text().splitlines()[0]
        machine = int(some.rsplit("total=", 1)[1]) / 1e6
    except (OSError, IndexError, ValueError):
        machine = float("nan")
    return loop, machine


def wake_figures(diags: list[dict[str, str]]) -> dict[str, object]:
    """From the node's /diagnostics of a window: the loop thread's CPU time per wake (the mean over
    the window, the largest), the garbage collection in its wakes, its longest wake-to-wake gap
    with its cause and parts, and how many diagnostics periods had their longest gap over 5 ms,
    by cause."""
    diags = [d for d in diags if d.get("period_max_wake_gap_ms")]
    if not diags:
        return {}
    gaps = [(float(d["period_max_wake_gap_ms"]), d["period_max_wake_gap_cause"], d["period_max_wake_gap"])
            for d in diags]
    longest = max(gaps)
    over: dict[str, int] = {}
    for ms, cause, _ in gaps:
        if ms > 5.0:
            over[cause] = over.get(cause, 0) + 1
    return {
        "wake_cpu_mean_ms": float(np.mean([float(d["period_mean_wake_cpu_ms"]) for d in diags])),
        "wake_cpu_max_ms": max(float(d["period_max_wake_cpu_ms"]) for d in diags),
        "gc_ms": sum(float(d["period_gc_ms"]) for d in diags),
        "longest_wake_gap_ms": longest[0], "longest_wake_gap_cause": longest[1], "longest_wake_gap": longest[2],
        "periods_with_a_gap_over_5ms_by_cause": over, "periods": len(diags),
        "per_period": [{"max_wake_cpu_ms": float(d["period_max_wake_cpu_ms"]), "longest_gap_ms": ms,
                        "cause": cause, "parts": parts} for d, (ms, cause, parts) in zip(diags, gaps)],
    }


def wake_rows(res: dict[str, Any]) -> dict[str, str]:
    """Table rows (figure -> value) of the thread CPU split and `wake_figures`."""
    w = res.get("wakes") or {}
    rows = {"node CPU: loop thread / other threads": f"{res['cpu_loop_thread_percent']:.1f} / "
                                                     f"{res['cpu_other_threads_percent']:.1f} % of one core",
            "loop thread runnable but waiting for a CPU / machine's CPU pressure (some)":
                f"{res['loop_waiting_for_cpu_percent']:.1f} / {res['cpu_pressure_some_percent']:.1f} % of the window"}
    if w:
        over = w["periods_with_a_gap_over_5ms_by_cause"]
        rows.update({
            "loop CPU per wake, mean / largest": f"{w['wake_cpu_mean_ms']:.4f} / {w['wake_cpu_max_ms']:.3f} ms",
            "garbage collection in the loop's wakes over the window": f"{w['gc_ms']:.3f} ms",
            "longest wake-to-wake gap (cause: parts)": f"{w['longest_wake_gap_cause']}: {w['longest_wake_gap']}",
            f"diagnostics periods (of {w['periods']}) whose longest gap > 5 ms, by cause":
                ", ".join(f"{k} {v}" for k, v in over.items()) or "none",
        })
    return rows


def _pct(values: np.ndarray, q: float) -> float:
    return float(np.percentile(values, q)) if len(values) else float("nan")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--duration", type=float, default=60.0, help="measurement window, s (default 60)")
    ap.add_argument("--spacing", type=float, default=0.7, help="s between duty steps (default 0.7)")
    ap.add_argument("--domain", type=int, default=120 + os.getpid() % 80)
    ap.add_argument("--json", type=Path, help="write the figures here")
    ap.add_argument("--param", action="append", default=[], help="extra emulator parameter NAME:=VALUE")
    ap.add_argument("--load", type=int, default=0, help="CPU-bound processes beside the node (as test's cpu_load)")
    opts = ap.parse_args()

    env = {k: v for k, v in os.environ.items() if k != "_ROS_WHEELS_BOOTSTRAP_COMPLETE"}
    env.update(ROS_DOMAIN_ID=str(opts.domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    os.environ.update(ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    cmd = [sys.executable, "-m", "pcv_sim.node.emulator", "--ros-args", "-r", "__ns:=/bench",
           "-p", "watchdog_timeout:=0.0", "-p", "safe_duty:=0.3"]
    for p in opts.param:
        cmd += ["-p", p]
    hogs = [subprocess.Popen([sys.executable, "-c", "while True: pass"], env=env) for _ in range(opts.load)]
    log = open(f"/tmp/pcv_bench_emulator_{os.getpid()}.log", "w")
    proc = subprocess.Popen(cmd, env=env, stdout=log, stderr=subprocess.STDOUT)
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=opts.domain)
    client = EmulatorClient("/bench", context=ctx, node_name="bench_client", sample_depth=100000)
    commands: list[tuple[float, int]] = []
    client.node.create_subscription(Float64, "duty_cycle",
                                    lambda m, info: commands.append((m.data, info["source_timestamp"])),
                                    QoSProfile(depth=100))
    try:
        if not client.wait_for_emulator(60):
            print("no emulator samples", file=sys.stderr)
            return 1
        client.spin_for(2.0)                                  # warm-up
        first_diag = client.wait_for_diagnostics(timeout=20)
        cpu0, threads0, wall0 = _cpu_seconds(proc.pid), _thread_cpu_seconds(proc.pid), time.monotonic()
        waited0 = _waiting(proc.pid)
        n0, d0 = len(client.samples), len(client.diagnostics)
        rng = random.Random(1)
        duty = 0.3
        end = wall0 + opts.duration
        next_cmd = wall0 + opts.spacing
        while time.monotonic() < end:
            now = time.monotonic()
            if now >= next_cmd:
                duty = 0.7 if duty == 0.3 else 0.3
                time.sleep(rng.uniform(0.0, 0.001))       # a random phase against the 1 ms sample grid
                client.send_duty(duty)
                next_cmd = now + opts.spacing + rng.uniform(0.0, 0.05)
            client.executor.spin_once(timeout_sec=0.005)
        cpu1, threads1, wall1 = _cpu_seconds(proc.pid), _thread_cpu_seconds(proc.pid), time.monotonic()
        waited1 = _waiting(proc.pid)
        last_diag = client.wait_for_diagnostics(timeout=20)
        client.spin_for(0.2)
    finally:
        for h in hogs:
            h.kill()
        proc.send_signal(signal.SIGINT)
        rc = proc.wait(20)
        client.close()
        rclpy.try_shutdown(context=ctx)
        log.close()

    samples = client.samples[n0:]
    stamps = np.array([s.stamp_ns for s in samples], dtype=np.int64)
    src = np.array([s.source_ns for s in samples], dtype=np.int64)
    rec = np.array([s.received_ns for s in samples], dtype=np.int64)
    pres = np.array([s.pressure for s in samples])
    period_ms = np.diff(src) / 1e6
    expected = int((stamps[-1] - stamps[0]) // 1_000_000) + 1
    lag_ms = (src - stamps) / 1e6

    latencies = []
    for _value, sent in commands:
        if sent < src[0] or sent > src[-1] - 100_000_000:
            continue
        k = int(np.searchsorted(stamps, sent - 2_000_000))     # from just before the command
        moved = np.nonzero(np.abs(np.diff(pres[k:k + 50])) > 3.0)[0]
        if moved.size:
            latencies.append((rec[k + moved[0] + 1] - sent) / 1e6)
    lat = np.array(latencies)

    diags = client.diagnostics[d0:]
    res = {
        "duration_s": wall1 - wall0,
        "samples": len(samples), "samples_expected": expected, "samples_lost": expected - len(samples),
        "period_ms": {"p50": _pct(period_ms, 50), "p99": _pct(period_ms, 99), "max": float(period_ms.max())},
        "publish_lag_ms": {"p50": _pct(lag_ms, 50), "p99": _pct(lag_ms, 99), "max": float(lag_ms.max())},
        "latency_ms": {"n": len(lat), "p50": _pct(lat, 50), "p99": _pct(lat, 99),
                       "max": float(lat.max()) if len(lat) else float("nan")},
        "cpu_percent": 100.0 * (cpu1 - cpu0) / (wall1 - wall0),
        "cpu_loop_thread_percent": 100.0 * (threads1[0] - threads0[0]) / (wall1 - wall0),
        "cpu_other_threads_percent": 100.0 * (threads1[1] - threads0[1]) / (wall1 - wall0),
        "wakes": wake_figures(diags),
        "loop_waiting_for_cpu_percent": 100.0 * (waited1[0] - waited0[0]) / (wall1 - wall0),
        "cpu_pressure_some_percent": 100.0 * (waited1[1] - waited0[1]) / (wall1 - wall0),
        "late_steps": int(last_diag["late_steps"]) - int(first_diag["late_steps"]),
        "skipped_steps": int(last_diag["skipped_steps"]) - int(first_diag["skipped_steps"]),
        "steps": round((wall1 - wall0) * 1e4),
        "max_lag_before_batch_ms": max(float(d["period_max_lag_ms"]) for d in diags),
        "max_lag_after_batch_ms": max(float(d["period_max_lag_after_step_ms"]) for d in diags),
        "node_exit_code": rc,
        "distro_rclpy": _rclpy_version(),
    }
    if opts.json:
        opts.json.write_text(json.dumps(res, indent=2))
    p, lg, la = res["period_ms"], res["publish_lag_ms"], res["latency_ms"]
    print(f"| figure ({res['duration_s']:.0f} s, rclpy {res['distro_rclpy']}) | value |")
    print("|---|---|")
    print(f"| publish period p50 / p99 / max | {p['p50']:.3f} / {p['p99']:.3f} / {p['max']:.3f} ms |")
    print(f"| samples lost (of {expected}) | {res['samples_lost']} |")
    print(f"| publish lag (sent - stamp) p50 / p99 / max | {lg['p50']:.3f} / {lg['p99']:.3f} / {lg['max']:.3f} ms |")
    print(f"| command -> first changed sample p50 / p99 / max (n = {la['n']}) | "
          f"{la['p50']:.3f} / {la['p99']:.3f} / {la['max']:.3f} ms |")
    print(f"| node CPU | {res['cpu_percent']:.1f} % of one core |")
    for name, value in wake_rows(res).items():
        print(f"| {name} | {value} |")
    print(f"| late steps / skipped steps (of ~{res['steps']}) | {res['late_steps']} / {res['skipped_steps']} |")
    print(f"| max model lag before / after a batch | {res['max_lag_before_batch_ms']:.3f} / "
          f"{res['max_lag_after_batch_ms']:.3f} ms |")
    return 0


def _rclpy_version() -> str:
    try:
        from importlib.metadata import version

        for name in ("ros-rclpy", "ros-jazzy-rclpy"):
            try:
                return version(name)
            except Exception:
                continue
    except ImportError:
        pass
    return "?"


if __name__ == "__main__":
    sys.exit(main())
