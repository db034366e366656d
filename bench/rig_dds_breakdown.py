"""Benchmark: where one control period of the lockstep over DDS goes, on both sides.

    .venv-kilted/bin/python bench/rig_dds_breakdown.py [--period 0.001] [--duration 1.5] [--repeats 3]

The setup of `pcv-sim scenario run examples/ros/step.yaml`: the scenario runner hosts the rig node
in this process (`pcv_sim.node.scenario_host`), the example controller node
(`python -m pcv_sim.node.steering_controller`) runs in its own process. Both sides are timed with
the monotonic clock (one clock for both processes) at the points a period passes through, by
wrapping the nodes' methods (this script's, not the package's: the package has no tracing):

    rig:        publish start (setpoint, /clock, the samples)  -> publish end
    controller: the period's first sample taken -> joint_states taken (the period complete; on the
                lockstep channel both are the one lockstep/sample)
                -> the control law called -> flags and duties published (lockstep/command)
    rig:        the last valve's duty taken -> the next period's publish start (the model's steps)

and reports the median and p90 of each stretch (µs) and of the whole period, the real-time factor,
and how many polls found nothing on each side per period. The stretches between the two sides'
points are DDS delivery plus the time until the receiving side polls.
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "examples"))
mono_ns = time.monotonic_ns


# --- the controller process ----------------------------------------------------------------------


def _controller_child(out: str, argv: list[str]) -> int:
    """The steering_controller node with its RigClient's points timed; the trace written at exit."""
    from pcv_sim.node import client as clients
    from pcv_sim.node import steering_controller

    trace: dict[int, list[int]] = {}            # stamp -> [first taken, joint taken, law called, law done, sent,
    polls = [0, 0]                              #           process CPU ns then]; polls in all, polls that found nothing

    def at(stamp: int) -> list[int]:
        row = trace.get(stamp)
        if row is None:
            row = trace[stamp] = [mono_ns(), 0, 0, 0, 0, time.process_time_ns()]
        return row

    cls = clients.RigClient
    orig_pressure, orig_joint, orig_poll, orig_send, orig_run = (
        cls._pressure, cls._joint, cls.poll, cls._send, cls.run)
    orig_sample = getattr(cls, "_sample", None)

    def _pressure(self, valve):
        take = orig_pressure(self, valve)

        def timed(msg, info):
            at(msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec)
            take(msg, info)
        return timed

    def _joint(self, msg, info):
        row = at(msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec)
        row[1] = mono_ns()
        orig_joint(self, msg, info)

    def _sample(self, raw, info):                 # the lockstep channel: the whole period in one message
        orig_sample(self, raw, info)
        stamp = self._samples[-1][0]
        row = at(stamp)
        row[1] = mono_ns()

    def poll(self):
        n = orig_poll(self)
        polls[0] += 1
        polls[1] += n == 0
        return n

    last = [0]

    def _send(self, duties, *args):
        orig_send(self, duties, *args)
        row = trace.get(last[0])
        if row is not None and not row[4]:
            row[4] = mono_ns()

    def run(self, controller, *args, **kwargs):
        def timed(t, measured):
            stamp = round(t * 1e9)
            row = at(stamp)
            last[0] = stamp
            row[2] = mono_ns()
            res = controller(t, measured)
            row[3] = mono_ns()
            return res
        return orig_run(self, timed, *args, **kwargs)

    cls._pressure, cls._joint, cls.poll, cls._send, cls.run = _pressure, _joint, poll, _send, run
    if orig_sample is not None:
        cls._sample = _sample
    try:
        return steering_controller.main(argv)
    finally:
        Path(out).write_text(json.dumps({"trace": trace, "polls": polls}))


# --- the rig side (this process) -------------------------------------------------------------------


def _rig_patches() -> tuple[dict[int, list[int]], list[int]]:
    """Time the rig node's publish and its taking of the answers; (trace by stamp, polls)."""
    from pcv_sim.node import device_node, scenario_host

    trace: dict[int, list[int]] = {}            # stamp -> [publish start, publish end, answer complete, CPU ns]
    polls = [0, 0]
    node_cls, host_cls = device_node.DeviceNode, scenario_host._Host
    orig_sampled, orig_send, orig_duty, orig_drain = (
        host_cls.sampled, node_cls._send_samples, node_cls._on_input, node_cls._drain)
    orig_command = getattr(node_cls, "_on_command", None)
    shown = [0]

    def sampled(self, true, measured):            # the hook runs before the samples go out
        node = self.node
        stamp = node.device.stamp_ns()
        shown[0] = stamp
        trace[stamp] = [mono_ns(), 0, 0, time.process_time_ns()]
        orig_sampled(self, true, measured)

    def _send_samples(self):
        orig_send(self)
        row = trace.get(shown[0])
        if row is not None and not row[1]:
            row[1] = mono_ns()

    def _on_input(self, entry, value_of, msg, info=None):
        orig_duty(self, entry, value_of, msg, info)
        if len(self._answered) == len(self.device.valve_names):
            row = trace.get(shown[0])
            if row is not None and not row[2]:
                row[2] = mono_ns()

    def _on_command(self, raw, info=None):
        orig_command(self, raw, info)
        if len(self._answered) == len(self.device.valve_names):
            row = trace.get(shown[0])
            if row is not None and not row[2]:
                row[2] = mono_ns()

    def _drain(self):
        n = orig_drain(self)
        polls[0] += 1
        polls[1] += n == 0
        return n

    host_cls.sampled, node_cls._send_samples, node_cls._on_input, node_cls._drain = (
        sampled, _send_samples, _on_input, _drain)
    if orig_command is not None:
        node_cls._on_command = _on_command
    return trace, polls


def one_run(period: float, duration: float, domain: int, tmp: Path, k: int) -> dict:
    import yaml

    from pcv_sim.node.scenario_host import run_ros_scenario
    from pcv_sim.rig.scenario import scenario_from_mapping

    rig_trace, rig_polls = _rig_patches.cache  # type: ignore[attr-defined]
    rig_trace.clear()
    rig_polls[:] = [0, 0]
    rig = yaml.safe_load((REPO / "config" / "rig.yaml").read_text())
    rig["rig"]["control_period"] = period
    for v in rig["valves"].values():
        v["config"] = str(REPO / "config" / v["config"])
    rig_file = tmp / f"rig_{period:g}.yaml"
    rig_file.write_text(yaml.safe_dump(rig))
    out = tmp / f"controller_{k}.json"
    cmd = ["{python}", str(Path(__file__).resolve()), "--_controller", str(out), "--", "steering_controller",
           "--ros-args", "-r", "__ns:={namespace}", "-p", f"period:={period!r}"]
    sc = scenario_from_mapping({
        "name": f"breakdown_{k}", "rig": str(rig_file), "duration": duration,
        "controller": {"ros": {"namespace": "/bench", "command": cmd, "wait": 60}},
        "setpoint": [{"t": 0.0, "value": 0.0}, {"t": 0.1, "value": 0.02}],
        "assertions": [{"type": "never_above", "signal": "controller.fault_detected", "max": 0.0}]}, path=tmp / "x.yaml")
    result = run_ros_scenario(sc, domain=domain)
    if not result.passed or result.run is None:
        raise RuntimeError(result.summary())
    for _ in range(100):
        if out.exists():
            break
        time.sleep(0.05)
    ctl = json.loads(out.read_text())
    c_trace = {int(s): row for s, row in ctl["trace"].items()}
    stamps = sorted(s for s, r in rig_trace.items() if all(r))[50:]          # warm-up left out
    parts: dict[str, list[float]] = {k: [] for k in (
        "rig publish", "-> controller has the first sample", "-> controller has joint_states (period complete)",
        "-> law called", "law", "-> flags and duties published", "-> rig has both duties",
        "-> rig's next publish (steps, hook)", "period")}
    for a, b in itertools.pairwise(stamps):
        r, rn, c = rig_trace[a], rig_trace[b], c_trace.get(a)
        if c is None or not all(c):
            continue
        us = [(r[1] - r[0]), (c[0] - r[1]), (c[1] - c[0]), (c[2] - c[1]), (c[3] - c[2]), (c[4] - c[3]),
              (r[2] - c[4]), (rn[0] - r[2]), (rn[0] - r[0])]
        for key, v in zip(parts, us):
            parts[key].append(v / 1e3)
    walls = result.run.sample_walls
    rtf = (len(walls) - 1 - 50) * period / (walls[-1] - walls[50])
    n = max(1, len(stamps))
    both = [s for s in stamps if s in c_trace]
    cpu = {"rig process": (rig_trace[stamps[-1]][3] - rig_trace[stamps[0]][3]) / 1e3 / (len(stamps) - 1),
           "controller process": (c_trace[both[-1]][5] - c_trace[both[0]][5]) / 1e3 / (len(both) - 1)}
    return {"rtf": rtf, "parts": parts, "cpu_us_per_period": cpu, "rig_polls_per_period": rig_polls[0] / n,
            "rig_empty_polls_per_period": rig_polls[1] / n,
            "controller_polls_per_period": ctl["polls"][0] / n, "controller_empty_polls_per_period": ctl["polls"][1] / n}


def main() -> int:
    if len(sys.argv) > 2 and sys.argv[1] == "--_controller":
        out, rest = sys.argv[2], sys.argv[sys.argv.index("--") + 1:]
        return _controller_child(out, rest)
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--period", type=float, default=1e-3, help="control period, s (default 1 ms)")
    ap.add_argument("--duration", type=float, default=1.5, help="simulated s per run (default 1.5)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--json", type=Path, help="write the raw figures here")
    opts = ap.parse_args()
    os.environ.pop("_ROS_WHEELS_BOOTSTRAP_COMPLETE", None)
    _rig_patches.cache = _rig_patches()  # type: ignore[attr-defined]
    domain = 150 + os.getpid() % 50
    load0 = os.getloadavg()
    runs = []
    with tempfile.TemporaryDirectory(prefix="pcv_breakdown_") as tmp:
        for k in range(opts.repeats):
            runs.append(one_run(opts.period, opts.duration, domain, Path(tmp), k))
    load1 = os.getloadavg()
    print(f"lockstep over DDS, scenario runner + steering_controller node, control period {opts.period * 1e3:g} ms, "
          f"{opts.duration:g} s simulated x {opts.repeats}; load average {load0[0]:.2f} -> {load1[0]:.2f}")
    print("real-time factor per run: " + ", ".join(f"{r['rtf']:.2f}x" for r in runs))
    print("polls per period (empty): rig " + ", ".join(
        f"{r['rig_polls_per_period']:.1f} ({r['rig_empty_polls_per_period']:.1f})" for r in runs)
        + "; controller " + ", ".join(
        f"{r['controller_polls_per_period']:.1f} ({r['controller_empty_polls_per_period']:.1f})" for r in runs))
    print("CPU per period [µs]: " + "; ".join(
        f"{k} " + ", ".join(f"{r['cpu_us_per_period'][k]:.0f}" for r in runs) for k in runs[0]["cpu_us_per_period"]))
    print("\n| stretch of a period | median [µs] | p90 [µs] |\n|---|---|---|")
    for key in runs[0]["parts"]:
        vals = sorted(v for r in runs for v in r["parts"][key])
        if vals:
            print(f"| {key} | {statistics.median(vals):.0f} | {vals[int(0.9 * len(vals))]:.0f} |")
    if opts.json:
        opts.json.write_text(json.dumps(runs))
    return 0


if __name__ == "__main__":
    sys.exit(main())
