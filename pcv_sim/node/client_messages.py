"""The device client's handlers (`pcv_sim.node.client.DeviceClient`): what it takes of the
device's samples (a valve's pressure and current, the cylinder's joint state, the lockstep
channel's samples) and diagnostics, by the device's names; `poll` takes what is pending without
an executor. The QoS a subscriber that must see every sample uses (`sample_qos`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import FluidPressure, JointState
from std_msgs.msg import Float64

from pcv_sim.io import topics
from pcv_sim.node.client_lockstep import PartialPeriod
from pcv_sim.node.inputs import drain
from pcv_sim.node.lockstep_channel import decode, measurement
from pcv_sim.units import NS_PER_S

__all__ = ["ClientMessages", "PressureSample", "diagnostic_level", "sample_qos", "stamp_ns"]


def sample_qos(depth: int = 10000) -> QoSProfile:
    """Best effort (matches the node's sensor-data publishers) with a deep queue."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth, reliability=ReliabilityPolicy.BEST_EFFORT)


def stamp_ns(msg: Any) -> int:
    """A stamped message's header.stamp in ns (the sample's model time)."""
    return int(msg.header.stamp.sec) * NS_PER_S + int(msg.header.stamp.nanosec)


def diagnostic_level(status: Any) -> int:
    """A DiagnosticStatus's level as a number (rclpy gives it as bytes of one)."""
    level = status.level
    return level[0] if isinstance(level, (bytes, bytearray)) else int(level)


@dataclass(frozen=True)
class PressureSample:
    stamp_ns: int          # header.stamp: the sample's model time (anchored to the ROS clock in real time)
    pressure: float        # Pa
    source_ns: int         # DDS source timestamp (when the node published it)
    received_ns: int       # DDS reception timestamp at this client


class ClientMessages:
    """The client's message handlers and what they collect (see the module docstring)."""

    valves: tuple[str, ...]
    lone_valve: bool
    lockstep: bool
    history: bool
    device_name: str
    samples: list[PressureSample]
    outputs: dict[str, list[tuple[int, float]]]
    currents: dict[str, list[tuple[int, float]]]
    statuses: list[dict[str, tuple[int, str, dict[str, str]]]]
    diagnostics: list[dict[str, str]]
    diagnostic_levels: list[int]
    diagnostic_messages: list[str]
    diagnostic_statuses: list[dict[str, tuple[int, str]]]
    key: Callable[[str, str], str]
    _outputs: tuple[str, ...]
    _on_pressure: Callable[[PressureSample], None] | None
    _currents: bool
    _fresh: dict[str, float]
    _latest: int
    _partial: dict[int, PartialPeriod]
    _samples: list[tuple[int, dict[str, float]]]
    _subs: list[tuple[Any, Callable[..., None]]]

    def _put(self, stamp: int, key: str, value: float) -> None:
        self._partial.setdefault(stamp, PartialPeriod()).values[key] = value
        self._latest = max(self._latest, stamp)

    def _pressure(self, valve: str) -> Callable[[Any, Any], None]:
        key = self.key(valve, topics.PRESSURE)
        lockstep = self.lockstep
        collect = self.lone_valve and topics.PRESSURE in self._outputs

        def take(msg: FluidPressure, info: Any) -> None:
            stamp = stamp_ns(msg)
            if lockstep:
                self._put(stamp, key, msg.fluid_pressure)
            if collect:
                s = PressureSample(stamp, msg.fluid_pressure, info["source_timestamp"], info["received_timestamp"])
                self.samples.append(s)
                if self._on_pressure is not None:
                    self._on_pressure(s)
        return take

    def _current(self, valve: str) -> Callable[[Any, Any], None]:
        key = self.key(valve, topics.CURRENT)
        collect = self.lone_valve and topics.CURRENT in self._outputs

        def take(msg: Float64, info: Any) -> None:
            if collect:
                self.outputs[topics.CURRENT].append((info["source_timestamp"], msg.data))
            if self._currents:
                self._fresh[key] = msg.data
                seen = self.currents[valve]
                if not self.history:
                    seen.clear()
                seen.append((self._latest, msg.data))
        return take

    def _scalar(self, name: str) -> Callable[[Float64, Any], None]:
        def take(msg: Float64, info: Any) -> None:
            self.outputs[name].append((info["source_timestamp"], msg.data))
        return take

    def _joint(self, msg: JointState, _info: Any) -> None:
        stamp = stamp_ns(msg)
        for name, arr in (("position", msg.position), ("velocity", msg.velocity), ("effort", msg.effort)):
            if len(arr):
                self._put(stamp, f"{topics.CYLINDER}.{name}", float(arr[0]))
        self._put(stamp, "joint", 1.0)

    def _sample(self, raw: bytes, _info: Any) -> None:
        stamp, names, values = decode(raw)
        m = measurement(names, values)
        self._samples.append((stamp, m))
        self._latest = max(self._latest, stamp)
        if self._currents:
            for v in self.valves:
                i = m.get(self.key(v, topics.CURRENT))
                if i is not None:
                    seen = self.currents[v]
                    if not self.history:
                        seen.clear()
                    seen.append((stamp, i))

    def _diagnostic(self, msg: DiagnosticArray, _info: Any = None) -> None:
        """The statuses of this client's device node: by name in `statuses`; their values merged (the
        emulator's keys are unique across concerns), the highest level and the messages joined in
        `diagnostics`, `diagnostic_levels`, `diagnostic_messages`, per concern in `diagnostic_statuses`."""
        prefix = self.device_name + ":"
        ours = [st for st in msg.status if st.name.startswith(prefix)]
        if not ours:
            return
        merged: dict[str, str] = {}
        by_name: dict[str, tuple[int, str, dict[str, str]]] = {}
        statuses: dict[str, tuple[int, str]] = {}
        for st in ours:
            values = {kv.key: kv.value for kv in st.values}
            merged.update(values)
            level = diagnostic_level(st)
            by_name[st.name] = (level, st.message, values)
            statuses[st.name[len(prefix):].strip()] = (level, st.message)
        self.statuses.append(by_name)
        self.diagnostics.append(merged)
        self.diagnostic_statuses.append(statuses)
        self.diagnostic_levels.append(max(level for level, _ in statuses.values()))
        self.diagnostic_messages.append("; ".join(m for _, m in statuses.values()))

    def poll(self) -> int:
        """Take every pending message (no executor); returns how many."""
        return drain(self._subs)
