"""Benchmark: the rig node in lockstep over DDS with a Python controller node.

    .venv-kilted/bin/python bench/rig_dds.py [--repeats 3] [--duration 2.0] [--json] [--record DIR]

The rig node (`python -m pcv_sim.node.rig`, two simplified valves + the steering cylinder of
config/rig.yaml at 0.1 ms) in its own process and ROS domain; in this process a controller node
(`pcv_sim.node.client.RigClient`: the example PI position controller, examples/steering.py,
a 20 mm setpoint step at 0.1 s) answers every control period for both valves. Reported per control
period (10 ms = 100 Hz, 1 ms = 1 kHz): the real-time factor (simulated s per wall s, median of the
repeats, the first 50 periods not timed), and the wall time of one period at the controller
(p50 / p99: rig computes and publishes, DDS both ways, the controller). Then the rig node's own
work in one 1 ms period, timed in this process without a DDS partner (the rest of a period is
DDS delivery, the two processes' polling and the controller's side). The machine's load
average is printed with the figures: on a shared machine it changes them.

Then the same with the example controller NODE (`ros2 run pcv_sim steering_controller`, its own
process: `python -m pcv_sim.node.steering_controller`) as a scenario runs it: the scenario runner
(`pcv_sim.node.scenario_host`) hosts the rig node in this process, publishes the setpoint every
period and takes the node's flags (controller/flags); the real-time factor of the scenario's run
(its `RigRun`, from the first sample to the last, start-up not counted), median of the repeats.
`--only node` runs this part alone.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import signal
import statistics
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "examples"))
VALVES = ("left", "right")
WARMUP = 50


def _child_env(domain: int) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k != "_ROS_WHEELS_BOOTSTRAP_COMPLETE"}
    env.update(ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    return env


def one_run(context, domain: int, period: float, duration: float, k: int, record: str = "") -> dict[str, float]:
    from steering import PositionController

    from pcv_sim.node.client import RigClient

    ns = f"/bench{os.getpid()}_{k}"
    log = open(os.devnull, "w")
    proc = subprocess.Popen([sys.executable, "-m", "pcv_sim.node.rig", "--ros-args", "-r", f"__ns:={ns}",
                             "-p", f"control_period:={period!r}",
                             *(["-p", "record.enabled:=true", "-p", f"record.directory:={record}"] if record else [])],
                            env=_child_env(domain), cwd=REPO,
                            stdout=log, stderr=subprocess.STDOUT)
    client = RigClient(ns, VALVES, context=context, node_name=f"bench_ctl_{k}", currents=True)
    try:
        if not client.wait_for_rig(60):
            raise RuntimeError("the rig node did not come up")
        ctrl = PositionController(period=period)

        def controller(t: float, m: dict[str, float]) -> dict[str, float]:
            m["setpoint"] = 0.02 if t >= 0.1 else 0.0
            out = ctrl(t, m)
            return {v: out[v] for v in VALVES}

        client.run(controller, WARMUP, timeout=60)
        n = round(duration / period)
        walls = []
        last = time.perf_counter()
        t0 = last

        def tick(_k: int) -> None:
            nonlocal last
            now = time.perf_counter()
            walls.append(now - last)
            last = now

        client.run(controller, n, timeout=600, before=tick)
        wall = time.perf_counter() - t0
        walls.sort()
        return {"rtf": n * period / wall, "period_p50_us": walls[len(walls) // 2] * 1e6,
                "period_p99_us": walls[int(len(walls) * 0.99)] * 1e6}
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(30)
        client.close()


def node_controller_run(domain: int, period: float, duration: float, tmp: Path) -> dict[str, float]:
    """One scenario run with the steering_controller node in its own process: its real-time factor
    and the wall time of one period (sample to sample, p50 / p99), the first WARMUP periods not timed."""
    import yaml

    from pcv_sim.node.scenario_host import run_ros_scenario
    from pcv_sim.rig.scenario import scenario_from_mapping

    rig = yaml.safe_load((REPO / "config" / "rig.yaml").read_text())
    rig["rig"]["control_period"] = period
    for v in rig["valves"].values():
        v["config"] = str(REPO / "config" / v["config"])
    rig_file = tmp / f"rig_{period:g}.yaml"
    rig_file.write_text(yaml.safe_dump(rig))
    cmd = ["{python}", "-m", "pcv_sim.node.steering_controller", "--ros-args", "-r", "__ns:={namespace}",
           "-p", f"period:={period!r}"]
    sc = scenario_from_mapping({
        "name": f"bench_{period:g}", "rig": str(rig_file), "duration": duration,
        "controller": {"ros": {"namespace": "/bench", "command": cmd, "wait": 60}},
        "setpoint": [{"t": 0.0, "value": 0.0}, {"t": 0.1, "value": 0.02}],
        "assertions": [{"type": "never_above", "signal": "controller.fault_detected", "max": 0.0}]}, path=tmp / "x.yaml")
    result = run_ros_scenario(sc, domain=domain)
    if not result.passed or result.run is None or result.run.sample_walls is None:
        raise RuntimeError(result.summary())
    walls = result.run.sample_walls
    per = sorted(walls[WARMUP + 1:] - walls[WARMUP:-1])
    return {"rtf": (len(walls) - 1 - WARMUP) * period / (walls[-1] - walls[WARMUP]),
            "period_p50_us": per[len(per) // 2] * 1e6, "period_p99_us": per[int(len(per) * 0.99)] * 1e6}


def node_controller(domain: int, repeats: int, duration: float) -> dict[str, dict[str, object]]:
    import tempfile

    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        for period in (1e-2, 1e-3):
            runs = [node_controller_run(domain, period, duration, Path(tmp)) for _ in range(repeats)]
            rtfs = [r["rtf"] for r in runs]
            out[f"{period * 1e3:g}ms"] = {
                "rtf_median": statistics.median(rtfs), "rtf_best": max(rtfs), "rtf_all": rtfs,
                "period_p50_us": statistics.median(r["period_p50_us"] for r in runs),
                "period_p99_us": statistics.median(r["period_p99_us"] for r in runs)}
    return out


def node_parts(context, n: int = 2000) -> dict[str, float]:
    """The rig node's own work in one 1 ms period, in this process (no DDS partner), in us."""
    from rclpy.parameter import Parameter

    from pcv_sim.node.rig import rig_node

    node = rig_node(argv=["rig"], context=context, parameter_overrides=[Parameter("time_mode", value="real")])
    rig = node.device
    node._publish(rig.present_sample())     # a sample to publish again and again below
    try:
        def timed(fn) -> float:
            t0 = time.perf_counter()
            for _ in range(n):
                fn()
            return (time.perf_counter() - t0) / n * 1e6

        return {"10_steps": timed(lambda: rig.advance_to(rig.steps + 10)),
                "sample_and_sensors": timed(lambda: rig.sensors.measure(rig.time, rig.sample())),
                "publish_period": timed(node._send_samples),
                "take_inputs_none_pending": timed(node._drain)}
    finally:
        node.destroy_node()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--duration", type=float, default=2.0, help="simulated s per run")
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--record", metavar="DIR", default="",
                    help="the rig node records a bag into DIR (record.enabled): the cost of recording")
    ap.add_argument("--only", choices=("client", "node"), default=None,
                    help="client: the controller in this process only; node: the controller node only")
    args = ap.parse_args()

    import rclpy

    from pcv_sim.jit import backend
    from pcv_sim.node.tuning import tighten_timer_slack

    tighten_timer_slack()       # the controller polls in 20 us sleeps, as the rig node does
    domain = 150 + os.getpid() % 50
    os.environ.update(ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain)
    out: dict[str, object] = {"backend": backend(), "python": platform.python_version(), "cpus": os.cpu_count(),
                              "load_before": os.getloadavg()[0], "record": bool(args.record)}
    try:
        k = 0
        for period in (1e-2, 1e-3) if args.only != "node" else ():
            runs = []
            for _ in range(args.repeats):
                runs.append(one_run(context, domain, period, args.duration, k, args.record))
                k += 1
            best = max(runs, key=lambda r: r["rtf"])
            out[f"{period * 1e3:g}ms"] = {
                "rtf_median": statistics.median(r["rtf"] for r in runs), "rtf_best": best["rtf"],
                "period_p50_us": statistics.median(r["period_p50_us"] for r in runs),
                "period_p99_us": statistics.median(r["period_p99_us"] for r in runs)}
        if args.only != "node":
            out["node_parts_us"] = node_parts(context)
    finally:
        rclpy.try_shutdown(context=context)
    if args.only != "client":
        out["controller_node"] = node_controller(domain, args.repeats, args.duration)
    out["load_after"] = os.getloadavg()[0]
    if args.json:
        json.dump(out, sys.stdout, indent=2)
        print()
        return
    print(f"backend {out['backend']}, Python {out['python']}, {out['cpus']} CPUs, load average "
          f"{out['load_before']:.1f} -> {out['load_after']:.1f}{', recording' if args.record else ''}")
    if args.only != "node":
        print("rig node process + RigClient controller in this process:")
        print(f"| control period | real-time factor (median of {args.repeats}) | best | one period p50 / p99 |")
        print("|---|---|---|---|")
        for label, key in (("10 ms (100 Hz)", "10ms"), ("1 ms (1 kHz)", "1ms")):
            r = out[key]
            print(f"| {label} | {r['rtf_median']:.1f}x | {r['rtf_best']:.1f}x | "            # type: ignore[index]
                  f"{r['period_p50_us']:.0f} / {r['period_p99_us']:.0f} µs |")                # type: ignore[index]
        parts = out["node_parts_us"]
        print("the rig node's own work in a 1 ms period: " + ", ".join(f"{k} {v:.1f} µs"          # type: ignore[union-attr]
                                                                    for k, v in parts.items()))    # type: ignore[union-attr]
    if args.only != "client":
        print("scenario runner hosting the rig node + the steering_controller node process:")
        print(f"| control period | real-time factor (median of {args.repeats}) | best | all | one period p50 / p99 |")
        print("|---|---|---|---|---|")
        for label, key in (("10 ms (100 Hz)", "10ms"), ("1 ms (1 kHz)", "1ms")):
            r = out["controller_node"][key]                                                    # type: ignore[index]
            print(f"| {label} | {r['rtf_median']:.1f}x | {r['rtf_best']:.1f}x | "
                  + ", ".join(f"{x:.1f}x" for x in r["rtf_all"])
                  + f" | {r['period_p50_us']:.0f} / {r['period_p99_us']:.0f} µs |")


if __name__ == "__main__":
    main()
