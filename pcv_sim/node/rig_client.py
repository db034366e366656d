"""A lockstep controller of the rig node over DDS: a starting point for a controller in Python.

Used by the tests and `bench/rig_dds.py`. Like the node it takes its messages with `take_message`
instead of spinning an executor (~125 us per `spin_once`, against a control period of 1 ms), so
what it measures is the rig and DDS, not rclpy's executor; between periods it blocks in an rcl
wait set on `joint_states` alone (`pcv_sim.node.polling.Waiter`).

A control period is complete when the cylinder's `joint_states` stamped with its model time has
arrived (the rig publishes it last) and the topics published before it have been taken once more;
the controller is then called with the measurements of that period: `<valve>.pressure` Pa (by
stamp), with `currents` also `<valve>.current` A (std_msgs/Float64 carries no stamp: the one
received since the last answer, published by the rig before joint_states), `cylinder.position` m,
`cylinder.velocity` m/s, `cylinder.effort` N; a sample the rig dropped (a sensor fault) is absent,
as in the in-process lockstep. Its duties are published on every valve's `duty_cycle`; flags it
returns (`{"flags": {name: value}}`) go to `on_flags`. A sample the rig publishes again
(unanswered for 0.5 s) is answered again, with the same duties. A sample stamped before the last
one answered is a new run (the rig restarted): `rewind` gives a fresh controller.

With `channel` it talks over the lockstep channel instead (`pcv_sim.node.lockstep_channel`): a
period is one `lockstep/sample` (every signal of the rig, and the scenario's `setpoint`, the
controller's `measured` as a callable gets it) and one `lockstep/command` back (the duties and the
flags, stamped with the sample it answers); the other topics are taken every FULL_POLL s.

`RigClient` is a `DeviceClient` (the fault topic, the reset service): it makes its own node, or
works on a node it is given (`node=`: the `steering_controller` node, with its parameters and its
own inputs added by `add_input`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import QoSProfile
from sensor_msgs.msg import FluidPressure, JointState
from std_msgs.msg import Float64

from pcv_sim.io.topics import (
    CURRENT,
    CYLINDER,
    DIAGNOSTICS,
    DUTY_CYCLE,
    EXTERNAL_FORCE,
    JOINT_STATES,
    PRESSURE,
    cylinder_topic,
    valve_topic,
)
from pcv_sim.node.client import DeviceClient, diagnostic_level, sample_qos, stamp_ns
from pcv_sim.node.inputs import drain
from pcv_sim.node.lockstep_channel import (
    COMMAND_TOPIC,
    DUTY_SUFFIX,
    FLAG_PREFIX,
    SAMPLE_TOPIC,
    NamedVector,
    decode,
    measurement,
)
from pcv_sim.node.polling import Waiter

__all__ = ["Period", "RigClient"]

FULL_POLL = 1e-2        # s between polls of every topic while waiting for a period's last one
RigController = Callable[[float, Mapping[str, float]], Mapping[str, Any]]


@dataclass
class Period:
    """One answered control period: the model time (ns), what was measured, what was commanded."""

    stamp_ns: int
    measured: dict[str, float]
    duties: dict[str, float]
    flags: dict[str, float] = field(default_factory=dict)


@dataclass
class _Partial:
    values: dict[str, float] = field(default_factory=dict)


class RigClient(DeviceClient):
    """Talks to the rig node in `namespace` (its valves named `valves`) from its own node, or
    from `node` (then `namespace` and `context` are the node's)."""

    def __init__(self, namespace: str | None, valves: tuple[str, ...], *, context: Any = None,
                 node_name: str = "rig_controller", currents: bool = False, node: Any = None,
                 history: bool = True, channel: bool = False) -> None:
        super().__init__(namespace, context=context, node_name=node_name, node=node)
        self.valves = valves
        node = self.node
        #: keep every answered Period and every current received (a long-running node: False)
        self.history = history
        cmd = QoSProfile(depth=10)
        self.channel = channel
        self.duty_pubs = {} if channel else {
            v: node.create_publisher(Float64, valve_topic(v, DUTY_CYCLE), cmd) for v in valves}
        self.command_pub = node.create_publisher(JointState, COMMAND_TOPIC, cmd) if channel else None
        self._commands: dict[tuple[str, ...], NamedVector] = {}
        self._samples: list[tuple[int, dict[str, float]]] = []      # channel: samples taken, not answered
        self._duty_msg = Float64()
        self.force_pub = node.create_publisher(Float64, cylinder_topic(EXTERNAL_FORCE), cmd)
        self._srv: tuple[Any, SingleThreadedExecutor] | None = None     # the services' node (_service_node)
        qos = sample_qos(1000)
        self._subs: list[tuple[Any, Callable[..., None]]] = []
        last: tuple[Any, Callable[..., None]]
        if channel:
            last = (node.create_subscription(JointState, SAMPLE_TOPIC, _ignore, cmd, raw=True), self._sample)
        else:
            for v in valves:
                self._subs.append((node.create_subscription(FluidPressure, valve_topic(v, PRESSURE), _ignore, qos),
                                   self._pressure(v)))
                if currents:
                    self._subs.append((node.create_subscription(Float64, valve_topic(v, CURRENT), _ignore, qos),
                                       self._current(v)))
            last = (node.create_subscription(JointState, cylinder_topic(JOINT_STATES), _ignore, qos), self._joint)
        self._subs.append(last)
        self._completing = [last]            # the rig publishes joint_states last: it completes a period
        self._waiter = Waiter([last[0]], node.context)
        if history:
            self._subs.append((node.create_subscription(DiagnosticArray, DIAGNOSTICS, _ignore, QoSProfile(depth=50)),
                               self._diagnostic))
        self.currents: dict[str, list[tuple[int, float]]] = {v: [] for v in valves}   # (latest stamp seen, A)
        self.diagnostics: list[dict[str, tuple[int, str, dict[str, str]]]] = []        # status name -> ...
        self.periods: list[Period] = []
        self.answered = 0                    # periods answered (once each), history or not
        self._partial: dict[int, _Partial] = {}
        self._fresh: dict[str, float] = {}   # <valve>.current received since the last answer
        self._answers: dict[int, dict[str, float]] = {}
        self._flags_sent: dict[str, float] = {}
        self._last_answered = -1
        self._latest = -1
        self._currents = currents

    def add_input(self, subscription: Any, handler: Callable[..., None]) -> None:
        """Take `subscription`'s messages with `handler(msg, info)` in every poll, after the rig's."""
        self._subs.append((subscription, handler))

    # --- taking messages --------------------------------------------------------------------

    def _put(self, stamp: int, key: str, value: float) -> None:
        self._partial.setdefault(stamp, _Partial()).values[key] = value
        self._latest = max(self._latest, stamp)

    def _pressure(self, valve: str) -> Callable[[Any, Any], None]:
        key = f"{valve}.pressure"

        def take(msg: FluidPressure, _info: Any) -> None:
            self._put(stamp_ns(msg), key, msg.fluid_pressure)
        return take

    def _current(self, valve: str) -> Callable[[Any, Any], None]:
        key = f"{valve}.current"

        def take(msg: Float64, _info: Any) -> None:
            self._fresh[key] = msg.data
            seen = self.currents[valve]
            if not self.history:
                seen.clear()
            seen.append((self._latest, msg.data))
        return take

    def _joint(self, msg: JointState, _info: Any) -> None:
        stamp = stamp_ns(msg)
        for name, arr in (("position", msg.position), ("velocity", msg.velocity), ("effort", msg.effort)):
            if len(arr):
                self._put(stamp, f"{CYLINDER}.{name}", float(arr[0]))
        self._put(stamp, "joint", 1.0)

    def _sample(self, raw: bytes, _info: Any) -> None:
        stamp, names, values = decode(raw)
        m = measurement(names, values)
        self._samples.append((stamp, m))
        self._latest = max(self._latest, stamp)
        if self._currents:
            for v in self.valves:
                i = m.get(f"{v}.current")
                if i is not None:
                    seen = self.currents[v]
                    if not self.history:
                        seen.clear()
                    seen.append((stamp, i))

    def _diagnostic(self, msg: DiagnosticArray, _info: Any) -> None:
        self.diagnostics.append({st.name: (diagnostic_level(st), st.message, {kv.key: kv.value for kv in st.values})
                                 for st in msg.status})

    def poll(self) -> int:
        """Take every pending message; returns how many."""
        return drain(self._subs)

    # --- lockstep ---------------------------------------------------------------------------

    def wait_for_rig(self, timeout: float = 30.0) -> bool:
        """Until every duty_cycle publisher (the lockstep command's) is matched with the rig's subscription."""
        end = time.monotonic() + timeout
        pubs = [self.command_pub] if self.command_pub is not None else self.duty_pubs.values()
        while not all(p.get_subscription_count() > 0 for p in pubs):
            if time.monotonic() > end:
                return False
            time.sleep(0.01)
        return True

    def _all_there(self, values: dict[str, float]) -> bool:
        return all(f"{v}.pressure" in values for v in self.valves) and (
            not self._currents or all(f"{v}.current" in self._fresh for v in self.valves))

    def _take_complete(self) -> list[tuple[int, dict[str, float]]]:
        """The periods whose joint_states arrived, oldest first, with what was published before it
        (taken once more when something is missing: it left the rig before joint_states); on the
        channel the samples taken."""
        if self.channel:
            out, self._samples = self._samples, []
            return out
        done = sorted(s for s, p in self._partial.items() if "joint" in p.values)
        if not done:
            return []
        if not all(self._all_there(self._partial[s].values) for s in done):
            self.poll()
        out = []
        for stamp in done:
            values = self._partial.pop(stamp).values
            values.pop("joint")
            out.append((stamp, values))
        for stale in [s for s in self._partial if s < done[-1]]:
            del self._partial[stale]              # an incomplete period the rig will not finish (lost joint)
        return out

    def run(self, controller: RigController, periods: int | None, *, timeout: float | None = 60.0,
            before: Callable[[int], None] | None = None, stop: Any = None,
            on_flags: Callable[[int, Mapping[str, float]], None] | None = None,
            rewind: Callable[[], RigController] | None = None) -> list[Period]:
        """Answer `periods` control periods (None: until `stop.requested`) with
        `controller(t, measured) -> {valve: duty, "flags": {name: value}}`; `before(k)` runs
        before the k-th answer (e.g. to inject a fault), `on_flags(stamp_ns, flags)` before the
        duties are published. The answered periods (kept only with `history`)."""
        end = math.inf if timeout is None else time.monotonic() + timeout
        answered = self.answered
        first = len(self.periods)
        goal = math.inf if periods is None else answered + periods
        next_full = 0.0
        while self.answered < goal and not (stop is not None and stop.requested):
            now = time.monotonic()
            if now > end:
                raise TimeoutError(f"rig lockstep: {self.answered - answered} of {periods} periods answered in "
                                   f"{timeout} s")
            # Waiting, for the period's last topic only, blocked in an rcl wait set (not polling: two
            # polling processes kept both cores busy, ~1 ms of CPU a period each, and the DDS threads
            # that deliver the messages waited for a core); every topic once it came, and every
            # FULL_POLL s whatever came.
            if not drain(self._completing) and now < next_full:
                self._waiter.wait(next_full - now)
                continue
            if now >= next_full or not self.channel:      # on the channel a sample is the whole period
                next_full = now + FULL_POLL
                if not self.poll() and not self._partial and not self._samples:
                    continue
            for stamp, values in self._take_complete():
                if self._currents and not self.channel:
                    values.update(self._fresh)
                    self._fresh.clear()
                again = self._answers.get(stamp)
                if again is not None:                 # published again by the rig: same answer
                    self._send(again, stamp, self._flags_sent)
                    continue
                if stamp < self._last_answered:       # the rig started again from 0: a new run
                    self._answers.clear()
                    if rewind is not None:
                        controller = rewind()
                if self.answered >= goal:
                    continue
                if before is not None:
                    before(self.answered)
                out = controller(stamp * 1e-9, values)
                flags = {str(k): float(f) for k, f in dict(out.get("flags") or {}).items()}
                duties = {v: float(d) for v, d in out.items() if v != "flags"}
                self._answers = {stamp: duties}
                self._flags_sent = flags
                self._last_answered = stamp
                self.answered += 1
                if self.history:
                    self.periods.append(Period(stamp, values, duties, flags))
                if flags and on_flags is not None:
                    on_flags(stamp, flags)
                self._send(duties, stamp, flags)
        return self.periods[first:]

    def _send(self, duties: Mapping[str, float], stamp: int, flags: Mapping[str, float]) -> None:
        if self.command_pub is not None:
            names = (*(v + DUTY_SUFFIX for v in duties), *(FLAG_PREFIX + f for f in flags))
            writer = self._commands.get(names)
            if writer is None:
                writer = self._commands[names] = NamedVector(names)
            self.command_pub.publish(writer.encode(stamp, (*duties.values(), *flags.values())))
            return
        msg = self._duty_msg                 # refilled: publish serializes it at once
        for v, d in duties.items():
            msg.data = d
            self.duty_pubs[v].publish(msg)

    def send_external_force(self, newton: float) -> None:
        self.force_pub.publish(Float64(data=newton))

    def _service_node(self) -> tuple[Any, Any]:
        """A node of its own for the service clients, made at the first call and spun only while a
        call waits (spinning self.node would take the samples that `poll` takes)."""
        if self._srv is None:
            node = rclpy.create_node(f"{self.node.get_name()}_services", namespace=self.node.get_namespace(),
                                     context=self.node.context)
            executor = SingleThreadedExecutor(context=node.context)
            executor.add_node(node)
            self._srv = (node, executor)
        return self._srv

    def close(self) -> None:
        if self._srv is not None:
            self._srv[1].shutdown()
            self._srv[0].destroy_node()
            self._srv = None
        self._clients.clear()
        super().close()


def _ignore(_msg: Any) -> None:
    """Subscriptions need a callback; messages are taken by `poll` instead (no executor)."""
