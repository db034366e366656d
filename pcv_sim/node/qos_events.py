"""The QoS of a node's endpoints: the interface registry's (`pcv_sim.io.topics.qos_of`) as rclpy's
profiles (`ros_qos`, `topic_qos`), and their incompatibility events for a node that runs without an
executor: the callbacks its endpoints are made with (`output_events`, `input_events`), polled by
`_poll_events` with the service requests (`pcv_sim.node.services`), each logged with what the other
side must change to connect."""

from __future__ import annotations

from typing import Any

from rclpy.event_handler import PublisherEventCallbacks, SubscriptionEventCallbacks
from rclpy.exceptions import InvalidHandle
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSPolicyKind, QoSProfile, ReliabilityPolicy

from pcv_sim.io.bag import Qos
from pcv_sim.io.topics import qos_of

__all__ = ["COMMAND_HINT", "SAMPLE_HINT", "QosEvents", "ros_qos", "topic_qos"]

SAMPLE_HINT = ("subscribe best effort (QoSProfile(depth=1000, reliability=BEST_EFFORT); "
               "ros2 topic echo --qos-reliability best_effort)")
COMMAND_HINT = "subscribe with a compatible QoS (reliable, volatile)"


def ros_qos(qos: Qos) -> QoSProfile:
    """A QoS of the registry as rclpy's profile (the other policies rclpy's defaults, as in a bag's
    metadata)."""
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST if qos.history == "keep_last" else HistoryPolicy.KEEP_ALL,
        depth=qos.depth,
        reliability=ReliabilityPolicy.RELIABLE if qos.reliability == "reliable" else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.VOLATILE if qos.durability == "volatile" else DurabilityPolicy.TRANSIENT_LOCAL)


def topic_qos(topic: str) -> QoSProfile:
    """The profile of a node's endpoint on a relative topic: the registry's (ValueError for a topic it
    does not list)."""
    return ros_qos(qos_of(topic))


class QosEvents(Node):
    """The QoS event part of the package's node (`pcv_sim.node.base.NodeBase`)."""

    _event_handlers: list[Any]

    def _init_qos_events(self) -> None:
        self._event_handlers = []

    def output_events(self, topic: str, hint: str = COMMAND_HINT) -> PublisherEventCallbacks:
        return PublisherEventCallbacks(incompatible_qos=lambda info: self._incompatible(
            topic, "a subscriber", info, hint))

    def input_events(self, topic: str) -> SubscriptionEventCallbacks:
        return SubscriptionEventCallbacks(incompatible_qos=lambda info: self._incompatible(
            topic, "a publisher", info, "publish reliable (the default of ros2 topic pub and of QoSProfile(depth=10))"))

    def _incompatible(self, topic: str, them: str, info: Any, hint: str) -> None:
        try:
            policy = QoSPolicyKind(info.last_policy_kind).name
        except ValueError:
            policy = str(info.last_policy_kind)
        self.get_logger().warning(
            f"QoS incompatible on {topic!r}: {them} has a {policy} policy the node's endpoint cannot match; no "
            f"messages flow between them ({info.total_count} such endpoint(s) so far). To connect: {hint}")

    def collect_event_handlers(self) -> None:
        """After the endpoints are made: the QoS event handlers `_poll_events` takes."""
        self._event_handlers = [h for e in (*self.publishers, *self.subscriptions)
                                for h in getattr(e, "event_handlers", ())]

    def _poll_events(self) -> None:
        """Run the QoS event callbacks (no executor runs them here): take each event's status, call back
        when its count changed. ~2 us per endpoint; polled with the services."""
        for handler in self._event_handlers:
            try:
                handler._ready_to_take_data = True     # what a wait set would mark; then rclpy's own take
                info = handler.take_data()
            except (InvalidHandle, AttributeError, RuntimeError):
                continue
            if info is not None and getattr(info, "total_count_change", 0) > 0:
                handler.callback(info)
