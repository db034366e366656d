"""A lockstep controller of the rig node over DDS: a starting point for a controller in Python.

Used by the tests and `bench/rig_dds.py`. Like the node it polls its subscriptions with
`take_message` instead of spinning an executor (~125 us per `spin_once`, against a control period
of 1 ms), so what it measures is the rig and DDS, not rclpy's executor.

A control period is complete when every valve's `pressure` and the cylinder's `joint_states`
stamped with the same model time have arrived; the controller is then called with the
measurements (`<valve>.pressure` Pa, with `currents` also `<valve>.current` A: the latest
received, as std_msgs/Float64 carries no stamp; `cylinder.position` m, `cylinder.velocity` m/s,
`cylinder.effort` N) and its duties are published on every valve's `duty_cycle`. A sample the rig
publishes again (unanswered for 0.5 s) is answered again, with the same duties.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import QoSProfile
from sensor_msgs.msg import FluidPressure, JointState
from std_msgs.msg import Float64, String
from std_srvs.srv import Trigger

from pcv_sim.io.topics import (
    CURRENT, CYLINDER, DIAGNOSTICS, DUTY_CYCLE, FAULTS, JOINT_STATES, PRESSURE, RESET, valve_topic,
)
from pcv_sim.node.polling import drain
from pcv_sim.node.client import sample_qos

__all__ = ["RigClient", "Period"]

POLL = 2e-5             # s between polls; with the default 50 us timer slack a sleep lasts ~100 us
                        # (the caller may tighten it, as bench/rig_dds.py does)
RigController = Callable[[float, Mapping[str, float]], Mapping[str, float]]


@dataclass
class Period:
    """One answered control period: the model time (ns), what was measured, what was commanded."""

    stamp_ns: int
    measured: dict[str, float]
    duties: dict[str, float]


@dataclass
class _Partial:
    values: dict[str, float] = field(default_factory=dict)


class RigClient:
    """Talks to the rig node in `namespace` (its valves named `valves`) from its own node."""

    def __init__(self, namespace: str, valves: tuple[str, ...], *, context: Any = None,
                 node_name: str = "rig_controller", currents: bool = False) -> None:
        self.valves = valves
        self.node = rclpy.create_node(node_name, namespace=namespace, context=context)
        node = self.node
        cmd = QoSProfile(depth=10)
        self.duty_pubs = {v: node.create_publisher(Float64, valve_topic(v, DUTY_CYCLE), cmd) for v in valves}
        self.fault_pub = node.create_publisher(String, FAULTS, cmd)
        self.force_pub = node.create_publisher(Float64, f"{CYLINDER}/external_force", cmd)
        # Services on a node of their own, spun only while a call waits (spinning this node would
        # take the samples that `poll` takes).
        self._srv_node = rclpy.create_node(f"{node_name}_services", namespace=namespace, context=context)
        self._reset: Any = self._srv_node.create_client(Trigger, RESET)
        self._srv_executor = SingleThreadedExecutor(context=self._srv_node.context)
        self._srv_executor.add_node(self._srv_node)
        qos = sample_qos(1000)
        self._subs: list[tuple[Any, Callable[[Any, Any], None]]] = []
        for v in valves:
            self._subs.append((node.create_subscription(FluidPressure, valve_topic(v, PRESSURE), _ignore, qos),
                               self._pressure(v)))
            if currents:
                self._subs.append((node.create_subscription(Float64, valve_topic(v, CURRENT), _ignore, qos),
                                   self._current(v)))
        self._subs.append((node.create_subscription(JointState, f"{CYLINDER}/{JOINT_STATES}", _ignore, qos),
                           self._joint))
        self._subs.append((node.create_subscription(DiagnosticArray, DIAGNOSTICS, _ignore, QoSProfile(depth=50)),
                           self._diagnostic))
        self.currents: dict[str, list[tuple[int, float]]] = {v: [] for v in valves}   # (latest stamp seen, A)
        self.diagnostics: list[dict[str, tuple[int, str, dict[str, str]]]] = []        # status name -> ...
        self.periods: list[Period] = []
        self._partial: dict[int, _Partial] = {}
        self._answers: dict[int, dict[str, float]] = {}
        self._latest = -1
        self._need = len(valves) + 1

    # --- taking messages --------------------------------------------------------------------

    def _put(self, stamp: int, key: str, value: float) -> None:
        self._partial.setdefault(stamp, _Partial()).values[key] = value
        self._latest = max(self._latest, stamp)

    def _pressure(self, valve: str) -> Callable[[Any, Any], None]:
        key = f"{valve}.pressure"

        def take(msg: FluidPressure, _info: Any) -> None:
            self._put(msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec, key, msg.fluid_pressure)
        return take

    def _current(self, valve: str) -> Callable[[Any, Any], None]:
        def take(msg: Float64, _info: Any) -> None:
            self.currents[valve].append((self._latest, msg.data))
        return take

    def _joint(self, msg: JointState, _info: Any) -> None:
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        for name, arr in (("position", msg.position), ("velocity", msg.velocity), ("effort", msg.effort)):
            if len(arr):
                self._put(stamp, f"{CYLINDER}.{name}", float(arr[0]))
        self._put(stamp, "joint", 1.0)

    def _diagnostic(self, msg: DiagnosticArray, _info: Any) -> None:
        self.diagnostics.append({st.name: (st.level[0] if isinstance(st.level, (bytes, bytearray)) else int(st.level),
                                           st.message, {kv.key: kv.value for kv in st.values}) for st in msg.status})

    def poll(self) -> int:
        """Take every pending message; returns how many."""
        return drain(self._subs)

    # --- lockstep ---------------------------------------------------------------------------

    def wait_for_rig(self, timeout: float = 30.0) -> bool:
        """Until every duty_cycle publisher is matched with the rig's subscription."""
        end = time.monotonic() + timeout
        while not all(p.get_subscription_count() > 0 for p in self.duty_pubs.values()):
            if time.monotonic() > end:
                return False
            time.sleep(0.01)
        return True

    def _complete(self, stamp: int) -> bool:
        p = self._partial.get(stamp)
        return p is not None and "joint" in p.values and all(f"{v}.pressure" in p.values for v in self.valves)

    def run(self, controller: RigController, periods: int, *, timeout: float = 60.0,
            before: Callable[[int], None] | None = None) -> list[Period]:
        """Answer `periods` control periods with `controller(t, measured) -> {valve: duty}`;
        `before(k)` runs before the k-th answer (e.g. to inject a fault). The answered periods."""
        end = time.monotonic() + timeout
        answered = len(self.periods)
        goal = answered + periods
        while len(self.periods) < goal:
            if time.monotonic() > end:
                raise TimeoutError(f"rig lockstep: {len(self.periods) - answered} of {periods} periods answered in "
                                   f"{timeout} s")
            if not self.poll():
                time.sleep(POLL)
                continue
            for stamp in sorted(s for s in self._partial if self._complete(s)):
                values = self._partial.pop(stamp).values
                values.pop("joint")
                for v, seen in self.currents.items():
                    if seen:           # Float64 has no stamp: the latest received (published before joint_states)
                        values[f"{v}.current"] = seen[-1][1]
                again = self._answers.get(stamp)
                if again is not None:                 # published again by the rig: same answer
                    self._send(again)
                    continue
                if len(self.periods) >= goal:
                    continue
                if before is not None:
                    before(len(self.periods))
                duties = {v: float(d) for v, d in controller(stamp * 1e-9, values).items()}
                self._answers = {stamp: duties}
                self.periods.append(Period(stamp, values, duties))
                self._send(duties)
        return self.periods[answered:]

    def _send(self, duties: Mapping[str, float]) -> None:
        for v, d in duties.items():
            self.duty_pubs[v].publish(Float64(data=d))

    def send_fault(self, text: str) -> None:
        self.fault_pub.publish(String(data=text))

    def send_external_force(self, newton: float) -> None:
        self.force_pub.publish(Float64(data=newton))

    def reset(self, timeout: float = 10.0) -> Any:
        """Call the rig's `reset` service; its response (TimeoutError if none within `timeout` s)."""
        end = time.monotonic() + timeout
        if not self._reset.wait_for_service(timeout_sec=timeout):
            raise TimeoutError(f"no reset service within {timeout} s")
        future = self._reset.call_async(Trigger.Request())
        self._srv_executor.spin_until_future_complete(future, timeout_sec=max(0.0, end - time.monotonic()))
        if not future.done():
            raise TimeoutError(f"reset: no response within {timeout} s")
        return future.result()

    def close(self) -> None:
        self._srv_executor.shutdown()
        self._srv_node.destroy_node()
        self.node.destroy_node()


def _ignore(_msg: Any) -> None:
    """Subscriptions need a callback; messages are taken by `poll` instead (no executor)."""
