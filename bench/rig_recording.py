"""Benchmark: does recording make the rig node's real-time steps late? Recording off vs on.

    .venv-kilted/bin/python bench/rig_recording.py [--duration 10] [--rounds 2] [--json]

The rig node (`pcv_sim.node.rig.rig_node`, the shipped config/rig.yaml: two valves + the
cylinder at 0.1 ms, samples every 1 ms) in this process, `time_mode: real`, run by its own loop
(`DeviceNode.run`) for duration / rounds s per configuration and round, alternately without and with
`record.enabled` (the rig's `DeviceRecorder`: every valve under its namespace, the cylinder, 1 kHz samples;
its writer thread serialises the joint states message by message). No controller: the duties stay
at their initial values until the watchdog, so the work per period is the rig's and the
recorder's. Reported per configuration: late steps (late_threshold 1 ms) and skipped steps summed
over the rounds, the largest model lag behind wall time, the bag's messages and drops, the
process CPU share. On a shared machine the load average (printed) changes the figures.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import threading
import time
from pathlib import Path


class _Stop:
    requested = False


def one(context, duration: float, record: str) -> dict[str, float]:
    from rclpy.parameter import Parameter

    from pcv_sim.node.rig import rig_node

    params = [Parameter("time_mode", value="real"), Parameter("diagnostics_period", value=100.0)]
    if record:
        params += [Parameter("record.enabled", value=True), Parameter("record.directory", value=record)]
    node = rig_node(argv=["rig"], context=context, parameter_overrides=params)
    stop = _Stop()
    timer = threading.Timer(duration, lambda: setattr(stop, "requested", True))
    cpu0, wall0 = time.process_time(), time.monotonic()
    try:
        timer.start()
        node.run(stop)
        timer.join()
        sched = node._schedule
        assert sched is not None
        st = node.recorder.status() if node.recorder is not None else None
        return {"steps": node.device.steps, "late_steps": sched.late_steps, "skipped_steps": sched.skipped_steps,
                "max_lag_ms": sched.max_lag * 1e3, "messages": st.messages if st else 0,
                "dropped": st.dropped if st else 0,
                "cpu_percent": 100 * (time.process_time() - cpu0) / (time.monotonic() - wall0)}
    finally:
        node.destroy_node()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=10.0, help="s per configuration (over all rounds)")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--per-round", action="store_true", help="print every round")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()

    import rclpy

    domain = 150 + os.getpid() % 50
    os.environ.update(ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain)
    tmp = Path(tempfile.mkdtemp(prefix="rig_recording_"))
    sums: dict[str, dict[str, float]] = {}
    load_before = os.getloadavg()[0]
    try:
        for _ in range(args.rounds):
            for label in ("off", "record"):
                r = one(context, args.duration / args.rounds, str(tmp) if label == "record" else "")
                if args.per_round:
                    print(label, {k: round(v, 1) for k, v in r.items()}, f"load {os.getloadavg()[0]:.1f}", flush=True)
                acc = sums.setdefault(label, {})
                for k, v in r.items():
                    acc[k] = max(acc.get(k, 0.0), v) if k in ("max_lag_ms", "cpu_percent") else acc.get(k, 0.0) + v
    finally:
        rclpy.try_shutdown(context=context)
        shutil.rmtree(tmp, ignore_errors=True)
    out = {"load_before": load_before, "load_after": os.getloadavg()[0], **sums}
    if args.json:
        json.dump(out, sys.stdout, indent=2)
        print()
        return
    print(f"load average {out['load_before']:.1f} -> {out['load_after']:.1f}; {args.duration:g} s per configuration")
    print("| recording | steps | late steps | skipped | max lag | bag messages | dropped | CPU (max of rounds) |")
    print("|---|---|---|---|---|---|---|---|")
    for label, r in sums.items():
        print(f"| {label} | {r['steps']:.0f} | {r['late_steps']:.0f} ({100 * r['late_steps'] / r['steps']:.2f} %) | "
              f"{r['skipped_steps']:.0f} | {r['max_lag_ms']:.1f} ms | {r['messages']:.0f} | {r['dropped']:.0f} | "
              f"{r['cpu_percent']:.0f} % |")


if __name__ == "__main__":
    main()
