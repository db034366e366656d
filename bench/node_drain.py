"""Benchmark: the cost of taking pending messages once per wake, take_message polling vs executor.

    .venv-kilted/bin/python bench/node_drain.py [--wakes 5000]

One node with the emulator's three input subscriptions and its services (7 parameter services
plus reset). Per wake, (a) `take_message` on each subscription until empty, (b)
`executor.spin_once(timeout_sec=0)` repeated until a call runs no callback, (c) polling every
service with `service_take_request`. Measured with no message pending and with one duty
message pending (published 0.5 ms before the wake). Prints a Markdown table of microseconds
per wake (median).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import QoSProfile
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import FluidPressure
from std_msgs.msg import Float64
from std_srvs.srv import Trigger


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--wakes", type=int, default=5000)
    opts = ap.parse_args()
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    rclpy.init(domain_id=200 + os.getpid() % 30, signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node("drain_bench")
    got = []
    qos = QoSProfile(depth=10)
    subs = [node.create_subscription(Float64, "duty_cycle", lambda m, i=None: got.append(m), qos),
            node.create_subscription(Float64, "load_flow", lambda m, i=None: got.append(m), qos),
            node.create_subscription(FluidPressure, "supply_pressure", lambda m, i=None: got.append(m), qos)]
    node.create_service(Trigger, "reset", lambda req, resp: resp)
    pub = node.create_publisher(Float64, "duty_cycle", qos)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    time.sleep(1.0)

    def take() -> None:
        for sub in subs:
            while True:
                with sub.handle:
                    m = sub.handle.take_message(sub.msg_type, sub.raw)
                if m is None:
                    break
                sub.callback(*m)

    def spin() -> None:
        while True:
            n = len(got)
            executor.spin_once(timeout_sec=0)
            if len(got) == n:
                break

    services = list(node.services)

    def poll_services() -> None:
        for srv in services:
            with srv.handle:
                srv.handle.service_take_request(srv.srv_type.Request)

    rows = []
    for name, fn in (("take_message polling (3 topics)", take), ("spin_once(0) until idle", spin),
                     (f"service polling ({len(services)} services)", poll_services)):
        for pending in (False, True):
            if "service" in name and pending:
                continue
            times = []
            for _ in range(opts.wakes if not pending else opts.wakes // 5):
                if pending:
                    pub.publish(Float64(data=0.5))
                    time.sleep(0.0005)
                t = time.perf_counter()
                fn()
                times.append((time.perf_counter() - t) * 1e6)
            rows.append((name, "1 duty message" if pending else "none", statistics.median(times)))
    node.destroy_node()
    rclpy.try_shutdown()
    print("| per wake | pending | µs (median) |")
    print("|---|---|---|")
    for name, pending, us in rows:
        print(f"| {name} | {pending} | {us:.1f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
