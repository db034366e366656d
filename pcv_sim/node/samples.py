"""A device's samples as messages, by its output table (`pcv_sim.io.topics.output_topics`): one
publisher per topic, its message made once and refilled (publish serializes it at once).

A value that is not finite (a sensor fault dropped it) is not published; a JointState leaves such
a field empty. A topic without a matched subscriber is not written: no reader would get it (sensor
data is volatile), and a lockstep controller on the lockstep channel reads that alone.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

from sensor_msgs.msg import FluidPressure, JointState
from std_msgs.msg import Float64, Header

from pcv_sim.io.bag import FLOAT64, FLUID_PRESSURE
from pcv_sim.io.topics import JOINT_NAME, JOINT_STATE, OutputTopic
from pcv_sim.units import NS_PER_S

__all__ = ["SamplePublisher"]

_FLOAT, _PRESSURE, _JOINT = 0, 1, 2
_KINDS = {FLOAT64: _FLOAT, FLUID_PRESSURE: _PRESSURE, JOINT_STATE: _JOINT}


class SamplePublisher:
    """Publishes a sample (values in the order of `signals`) on the topics of `table`.
    `make(msg_type, topic)` creates a publisher (the node's, with its QoS event callbacks)."""

    def __init__(self, table: Sequence[OutputTopic], signals: Sequence[str], frame_id: str,
                 make: Callable[[Any, str], Any]) -> None:
        self.table = tuple(table)
        #: (kind, publisher, message, indices into the sample)
        self._plan: list[tuple[int, Any, Any, tuple[int, ...]]] = []
        for out in self.table:
            kind = _KINDS[out.type]
            msg: Any
            if kind == _FLOAT:
                msg, msg_type = Float64(), Float64
            elif kind == _PRESSURE:
                msg, msg_type = FluidPressure(header=Header(frame_id=out.frame_id or frame_id)), FluidPressure
            else:
                msg = JointState(header=Header(frame_id=out.frame_id or frame_id), name=[JOINT_NAME])
                msg_type = JointState
            self._plan.append((kind, make(msg_type, out.topic), msg, tuple(signals.index(s) for s in out.signals)))

    @property
    def topics(self) -> tuple[str, ...]:
        return tuple(out.topic for out in self.table)

    def publisher(self, topic: str) -> Any:
        """The publisher of `topic` (KeyError for a topic not in the table)."""
        for out, (_, pub, _, _) in zip(self.table, self._plan):
            if out.topic == topic:
                return pub
        raise KeyError(topic)

    def set_frame_id(self, frame_id: str) -> None:
        """The node's frame_id changed: the stamped messages without a frame of their own take it."""
        for (kind, _, msg, _), out in zip(self._plan, self.table):
            if kind != _FLOAT and not out.frame_id:
                msg.header.frame_id = frame_id

    def publish(self, stamp_ns: int, y: Sequence[float]) -> None:
        sec, nsec = divmod(stamp_ns, NS_PER_S)
        isfinite = math.isfinite
        for kind, pub, msg, idx in self._plan:
            if kind == _FLOAT:
                v = y[idx[0]]
                if isfinite(v) and pub.get_subscription_count():
                    msg.data = v
                    pub.publish(msg)
            elif kind == _PRESSURE:
                v = y[idx[0]]
                if isfinite(v) and pub.get_subscription_count():
                    msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nsec
                    msg.fluid_pressure = v
                    pub.publish(msg)
            elif pub.get_subscription_count():
                pos, vel, eff = (y[i] for i in idx)
                msg.position = [pos] if isfinite(pos) else []
                msg.velocity = [vel] if isfinite(vel) else []
                msg.effort = [eff] if isfinite(eff) else []
                msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nsec
                pub.publish(msg)
