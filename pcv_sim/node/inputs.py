"""A node's inputs without an executor: the device's input topics and the `faults` topic taken by
`take_message` polling (`drain`, `_drain`: a few us per empty topic, against ~125 us for an
executor's `spin_once`; BENCHMARKS.md), each value checked by the device on arrival and acting from
the step `acting_step` gives (the device's `InputTiming`: from the DDS reception time in real time,
from the first step not shown otherwise); refused inputs counted by the device and logged at most
once per reject_log_period per input; fault commands logged with their publisher's node name
(`publisher_name`); the device's log (watchdogs, faults, resets) forwarded once per event."""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable, Sequence
from functools import partial
from operator import attrgetter
from typing import Any

from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.exceptions import InvalidHandle
from rclpy.node import Node
from sensor_msgs.msg import FluidPressure, JointState
from std_msgs.msg import Float64, String

from pcv_sim.device.device import Device
from pcv_sim.device.inputs import InputTiming
from pcv_sim.io.bag import FLOAT64, FLUID_PRESSURE
from pcv_sim.io.topics import DUTY_CYCLE, FAULTS, InputTopic
from pcv_sim.node.lockstep_channel import COMMAND_TOPIC
from pcv_sim.node.qos_events import topic_qos
from pcv_sim.node.services import SERVICE_POLL_PERIOD
from pcv_sim.simulation.clock import RealTimeSchedule

__all__ = ["KEPT", "NodeInputs", "drain", "publisher_name"]

KEPT = "the last valid value stays in force"            # what a refused input leaves
#: An input topic's message type -> (message class, what it carries).
_INPUT_MESSAGES: dict[str, tuple[Any, Callable[[Any], Any]]] = {
    FLOAT64: (Float64, attrgetter("data")), FLUID_PRESSURE: (FluidPressure, attrgetter("fluid_pressure"))}


def drain(subscriptions: Iterable[tuple[Any, Callable[..., None]]]) -> int:
    """Take every pending message of each (subscription, handler) pair, in order; how many."""
    taken = 0
    for sub, handler in subscriptions:
        while True:
            try:
                with sub.handle:
                    got = sub.handle.take_message(sub.msg_type, sub.raw)
            except InvalidHandle:            # destroyed during shutdown
                break
            if got is None:
                break
            handler(*got)
            taken += 1
    return taken


class NodeInputs(Node):
    """The input part of the package's node (`pcv_sim.node.base.NodeBase`)."""

    settings: Any
    device: Device
    _schedule: RealTimeSchedule | None                          # pcv_sim.node.loops: real time only
    _poll_services: Callable[[], None]                          # pcv_sim.node.services
    _pump: Callable[[], None]
    input_events: Callable[[str], SubscriptionEventCallbacks]   # pcv_sim.node.qos_events
    #: The keys a lockstep waits for, one per answering command: its subscription is `_inputs[k]`
    #: (made first), its handler adds the key to `_answered`.
    lockstep_keys: tuple[str, ...] = ()

    def _init_inputs(self) -> None:
        self._last_reject_log: dict[str, float] = {}
        self._suppressed: dict[str, int] = {}
        self._inputs: list[tuple[Any, Any]] = []    # (subscription, handler(msg, info)), taken by `_drain`
        self._answer_subs: list[Any] = []           # the lockstep_keys' commands, in their order
        self._channel_sub: Any = None               # the lockstep channel's command, when subscribed
        self._duty_topics: dict[str, str] = {}      # valve -> its duty's topic (the watchdog's message)
        self._logged = 0                            # device.log entries forwarded to the logger
        self._next_service_poll = 0.0               # monotonic s of the next service poll
        self._answered: set[str] = set()            # lockstep: keys heard since the last sample
        self._shown = 0                             # the last step whose sample was published

    def log_rejection(self, key: str, topic: str, reason: str, outcome: str = KEPT) -> None:
        """One log line per `key` per reject_log_period for refused inputs (the device counts them all)."""
        now = time.monotonic()
        if now - self._last_reject_log.get(key, -math.inf) < self.settings.reject_log_period:
            self._suppressed[key] = self._suppressed.get(key, 0) + 1
            return
        more = self._suppressed.pop(key, 0)
        self._last_reject_log[key] = now
        tail = f" ({more} more rejected since the last message)" if more else ""
        self.get_logger().warning(f"rejected {topic}: {reason}; {outcome}{tail}")

    def subscribe_inputs(self, table: Sequence[InputTopic], on_command: Callable[..., None] | None = None) -> None:
        """The device's input topics (`pcv_sim.io.topics.input_topics`), each taken into the device's
        `submit`. The valves' duties first, then, given `on_command`, the lockstep channel's command
        (raw CDR): the lockstep waits on these (`lockstep_keys`, `_lockstep_answers`)."""
        duties = [e for e in table if e.answers]
        self.lockstep_keys = tuple(e.answers for e in duties)
        for entry in (*duties, None, *(e for e in table if not e.answers)):
            if entry is None:
                if on_command is not None:
                    sub = self.create_subscription(JointState, COMMAND_TOPIC, on_command, topic_qos(COMMAND_TOPIC), raw=True,
                                                   event_callbacks=self.input_events(COMMAND_TOPIC))
                    self._inputs.append((sub, on_command))
                    self._channel_sub = sub
                continue
            msg_type, value_of = _INPUT_MESSAGES[entry.type]
            handler = partial(self._on_input, entry, value_of)
            sub = self.create_subscription(msg_type, entry.topic, handler, topic_qos(entry.topic),
                                           event_callbacks=self.input_events(entry.topic))
            self._inputs.append((sub, handler))
            if entry.answers:
                self._answer_subs.append(sub)
                self._duty_topics[entry.answers] = entry.topic

    def _on_input(self, entry: InputTopic, value_of: Callable[[Any], Any], msg: Any, info: Any = None) -> None:
        if entry.answers:
            self._answered.add(entry.answers)        # valid or not: the lockstep's answer
        self.take_input(entry.input, entry.topic, value_of(msg), info)

    def take_input(self, name: str, topic: str, value: Any, info: Any) -> None:
        """An input of the device (its name; `topic` for the log), checked now by the device and
        acting from the step an input taken now acts from (`acting_step`); a refused one logged."""
        dev = self.device
        at = self.acting_step(dev.timing, name, self.first_open_step(), dev.origin_ns, info)
        reason = dev.submit(name, value, at)
        if reason is not None:
            self.log_rejection(name, topic, reason)
        else:
            dev.timing.took(name, at)

    def first_open_step(self) -> int:
        """The first step whose sample nobody has seen: an input taken now acts from there at the earliest."""
        return max(self.device.first_open_step(), self._shown + 1)

    def acting_step(self, timing: InputTiming, name: str, first: int, origin_ns: int, info: Any) -> int:
        """The step an input of `name` taken now acts from (`InputTiming`, the devices' one rule; `first`:
        the first step not shown): in real time from its DDS reception time, otherwise from `first`."""
        sched = self._schedule
        if sched is None:
            return timing.step(name, first)
        r_ns = info.get("received_timestamp", 0) if isinstance(info, dict) else 0
        return timing.step(name, first, received_ns=r_ns, origin_ns=origin_ns, elapsed=time.monotonic() - sched.t0)

    def subscribe_faults(self) -> None:
        """The `faults` topic, with faults.enabled only: any node on the domain could break the bench."""
        if self.settings.faults_enabled:
            sub = self.create_subscription(String, FAULTS, self._on_fault, topic_qos(FAULTS),
                                           event_callbacks=self.input_events(FAULTS))
            self._inputs.append((sub, self._on_fault))

    def _on_fault(self, msg: String, info: Any = None) -> None:
        """A fault command, logged with its publisher; the device's part (`_take_fault`) checks it and
        lets it act as an input taken now would."""
        self.get_logger().info(f"fault command {msg.data!r} from {self.publisher_of(FAULTS, info)}")
        self._take_fault(msg.data, info)

    def _take_fault(self, text: str, info: Any) -> None:
        """Checked by the device now, acting as an input taken now."""
        dev = self.device
        at = self.acting_step(dev.timing, FAULTS, self.first_open_step(), dev.origin_ns, info)
        reason = dev.submit_fault(text, at)
        if reason is not None:
            self.log_rejection(FAULTS, FAULTS, reason, "nothing changed")
        else:
            dev.timing.took(FAULTS, at)

    def forward_log(self) -> None:
        """What the device did that a user must hear about (its log: watchdogs, faults, resets), once
        per event: a watchdog firing as a warning saying what to send, the rest as information."""
        dev = self.device
        log = dev.log
        if self._logged > len(log):
            self._logged = 0                # the device started its log anew
        while self._logged < len(log):
            t, text = log[self._logged]
            self._logged += 1
            valve, _, what = text.partition(": ")
            watchdog = dev.watchdogs.get(valve)
            if watchdog is not None and what.startswith("watchdog fired"):
                topic = self._duty_topics.get(valve, DUTY_CYCLE)
                timeout = watchdog.timeout_steps * dev.dt
                self.get_logger().warning(
                    f"t = {t:.4f} s: {text}; watchdog: no valid {topic} command for {timeout:g} s (model time): the "
                    f"duty fell to safe_duty {dev.safe_duty:g}. Send the duty at least every {timeout:g} s (a "
                    f"controller does; by hand: ros2 topic pub -r 10 {topic} std_msgs/msg/Float64 '{{data: 0.7}}'), "
                    "or raise watchdog_timeout (0 = off). The next valid command resumes.")
            elif watchdog is not None and what.startswith("watchdog cleared"):
                self.get_logger().info(f"t = {t:.4f} s: {text}; watchdog: duty commands resumed, duty "
                                       f"{dev.duties[valve]:g}")
            else:
                self.get_logger().info(f"t = {t:.4f} s: {text}")

    def publisher_of(self, topic: str, info: Any) -> str:
        """The node that published a message on `topic` (`publisher_name`)."""
        return publisher_name(self.get_publishers_info_by_topic(topic), info)

    def _drain(self) -> int:
        """Take every pending input message (no executor: `take_message` polling); every
        SERVICE_POLL_PERIOD also the service requests, and in between a deferred request's answer
        if one is ready (`_pump`)."""
        n = drain(self._inputs)
        now = time.monotonic()
        if now >= self._next_service_poll:
            self._next_service_poll = now + SERVICE_POLL_PERIOD
            self._poll_services()
        else:
            self._pump()
        return n


def publisher_name(endpoints: Any, info: Any) -> str:
    """Who published a message, for the log: the node whose endpoint GID is the publisher GID in the
    message's MessageInfo (Kilted's rclpy gives it). Where the MessageInfo carries no GID (Jazzy's
    rclpy), the topic's publishers tell it when there is only one of them, and narrow it otherwise."""
    def name(e: Any) -> str:
        return f"{e.node_namespace.rstrip('/')}/{e.node_name}"

    endpoints = list(endpoints)
    gid = info.get("publisher_gid") if isinstance(info, dict) else None
    data = list(gid.get("data", ())) if isinstance(gid, dict) else []
    if any(data):
        for e in endpoints:
            known = list(e.endpoint_gid)
            n = min(len(known), len(data))
            if n and known[:n] == data[:n]:
                return f"node {name(e)}"
        return "a publisher DDS did not name"
    if len(endpoints) == 1:
        return f"node {name(endpoints[0])} (the topic's only publisher; DDS gave no publisher GID)"
    if endpoints:
        return f"one of the nodes {', '.join(sorted(name(e) for e in endpoints))} (DDS gave no publisher GID)"
    return "a publisher DDS did not name"
