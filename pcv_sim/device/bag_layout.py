"""A device's bag layout (`BagLayout`): where each of its names goes in a bag, derived from the
device's own names (`signals`, `input_names`, `valve_names`, `lone_valve`, its valves' chambers)
through the interface registry (`pcv_sim.io.topics`): each valve's six roles under its namespace
(`<ns>/<valve>/pressure`; the emulator's lone valve named by its roles alone, `<ns>/pressure`), so
that one valve of a rig bag replays like an emulator's bag; the plant's inputs as their topics and
its signals as one JointState (`cylinder/joint_states`); the chambers' pressures; the valve
options' inputs and outputs; the fault commands and the device's log (`faults`, `rig/events`)
where asked. One layout serves the live recording and offline writing
(`pcv_sim.device.recording.DeviceRecorder`).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Final, Literal

from pcv_sim.errors import BagError
from pcv_sim.io.bag import COMMAND_QOS, FLOAT64, Qos
from pcv_sim.io.topics import (
    CYLINDER,
    DUTY_CYCLE,
    EVENTS,
    FAULTS,
    INPUT_ROLES,
    JOINT_STATE,
    LOAD_FLOW,
    OPTION_INTERFACE,
    ROLE_ALIASES,
    ROLE_TYPES,
    ROLES,
    STRING,
    bag_topic,
    input_topics,
    output_topics,
    qos_of,
    role_of,
    topic_of,
)

__all__ = ["RECORDABLE", "BagLayout", "Topic", "check_signals"]

#: Signals the emulator's recording can select, by role (`record.signals`).
RECORDABLE: Final = ROLES
_OPTION_DIRECTION: Final = {e.name: e.direction for e in OPTION_INTERFACE}


def _qos(relative: str) -> Qos:
    """The QoS of a relative topic (``left/pressure``: the role's) from the registry; a topic only bags
    have (the events) as a command's."""
    return qos_of(relative, COMMAND_QOS)


def check_signals(signals: Iterable[str]) -> tuple[str, ...]:
    """Roles to record, in the canonical order; aliases (``duty``, ``position``) accepted.

    Raises:
        BagError: an unknown name, a non-string, or nothing selected.
    """
    if isinstance(signals, str):
        signals = [signals]
    accepted = f"{', '.join(RECORDABLE)} (aliases: {', '.join(sorted(ROLE_ALIASES))})"
    chosen: set[str] = set()
    for s in signals:
        role = role_of(s) if isinstance(s, str) else None
        if role is None:
            msg = f"record signal {s!r} is not a device signal; accepted are {accepted}"
            raise BagError(msg)
        chosen.add(role)
    if not chosen:
        msg = f"no signal selected to record; accepted are {accepted}"
        raise BagError(msg)
    return tuple(r for r in RECORDABLE if r in chosen)


@dataclass(frozen=True)
class Topic:
    """One topic of a bag: the device's name whose values it carries, where, and how.

    `kind`: ``input`` (on change), ``column`` (a value per row: Float64 or FluidPressure),
    ``joint`` (the plant's signals as one JointState), ``text`` (std_msgs/String). `source`: for an
    input the name its value comes under (a `record_values` key at model steps, an `on_input` name
    with the samples); for a column or the joint the index (indices) of its value(s) in a row."""

    kind: Literal["input", "column", "joint", "text"]
    name: str
    topic: str
    type: str
    qos: Qos
    frame_id: str = ""
    source: str | tuple[int, ...] = ""


@dataclass(frozen=True)
class BagLayout:
    """Where each of a device's names goes in a bag (see the module docstring): `topics` in the bag's
    order; `row` the names of a row's values (a column's `source` indexes it); `every` the model
    steps between records (None: with each sample shown); `flows` the valves' load flows recorded as
    their means over each sample period (in the order of the valves); `prefix` the bag name's."""

    topics: tuple[Topic, ...]
    row: tuple[str, ...]
    every: int | None
    flows: tuple[str, ...] = ()
    prefix: str = "rig"

    @classmethod
    def of(cls, device: Any, *, namespace: str = "/", chambers: Mapping[str, str] | None = None,
           every: int | None = None, record: Iterable[str] = RECORDABLE, frame_id: str = "load_port",
           faults: bool = True, events: bool = True) -> BagLayout:
        """The layout of `device` (its `valve_names`, `signals`, `input_names`, `lone_valve`); see `of_names`."""
        return cls.of_names(device.valve_names, device.signals, device.input_names, namespace=namespace,
                            chambers=chambers, every=every, record=record, frame_id=frame_id, faults=faults,
                            events=events, lone_valve=device.lone_valve)

    @classmethod
    def of_names(cls, valves: Sequence[str], signals: Sequence[str], inputs: Sequence[str], *, namespace: str = "/",
                 chambers: Mapping[str, str] | None = None, every: int | None = None,
                 record: Iterable[str] = RECORDABLE, frame_id: str = "load_port", faults: bool = True,
                 events: bool = True, options: bool = True, extra: Sequence[tuple[str, str]] = (),
                 lone_valve: bool = False) -> BagLayout:
        """The layout of a device with these names, in `namespace` (the node's; "/" offline).

        A row carries the device's `signals` (in their order) and then the `extra` values; a name
        a row carries is a column (a message per row), a recorded input it does not carry is
        recorded on change.

        Args:
            valves, signals, inputs: The device's `valve_names`, `signals` and `input_names`.
            lone_valve: The device's `lone_valve`: its one valve's names and topics are its roles
                alone (the emulator's bag), else `<valve>.<role>` (the rig's).
            chambers: valve -> chamber (a | b) of the valves on the plant's chambers.
            every: Record at every `every`-th model step (the device's per-step hook); None: with
                each sample shown (inputs as they act, load flows as period means).
            record: The roles of each valve to record (:func:`check_signals`).
            frame_id: header.frame_id of the valves' pressure and supply pressure.
            faults, events: Record the fault commands (``faults``), the device's log (``rig/events``).
            options: Record the valve options' inputs and outputs.
            extra: (name, relative topic) of further Float64 values a row carries after the signals
                (offline: a valve's duty as ``<valve>.duty_cycle``, the setpoint, the flags).
        """
        if every is not None and (isinstance(every, bool) or not isinstance(every, int) or every < 1):
            msg = f"every {every!r}: accepted is an integer >= 1 (model steps between output samples)"
            raise BagError(msg)
        roles = check_signals(record)
        valves, signals, inputs = tuple(valves), tuple(signals), tuple(inputs)
        chambers = dict(chambers or {})
        lone = lone_valve
        prefix = {v: "" if lone else f"{v}." for v in valves}
        row = signals + tuple(name for name, _ in extra)
        relative = dict(extra)
        input_topic = {e.input: e for e in input_topics(inputs, valves)}
        out_topic = {o.signals: o for o in output_topics(signals, chambers)}
        topics: list[Topic] = []

        def add(kind: Literal["input", "column", "joint", "text"], name: str, where: str, msgtype: str,
                frame: str = "", source: str | tuple[int, ...] = "") -> None:
            topics.append(Topic(kind, name, bag_topic(where, namespace), msgtype, _qos(where), frame, source))

        def stamped(msgtype: str) -> str:
            return frame_id if msgtype != FLOAT64 else ""

        for v in valves:
            for role in (r for r in ROLES if r in roles):
                name = f"{prefix[v]}{role}"
                where, msgtype = relative.get(name, topic_of(name)), ROLE_TYPES[role]
                if name in row:
                    add("column", name, where, msgtype, stamped(msgtype), (row.index(name),))
                elif role in INPUT_ROLES:
                    # At model steps the duty is the one the model used (after the fall-rate limiter).
                    key = f"{prefix[v]}duty" if every is not None and role == DUTY_CYCLE else name
                    add("input", name, where, msgtype, stamped(msgtype), key)
            if v in chambers:
                o = out_topic[(f"{v}.pressure",)]
                add("column", o.signals[0], o.topic, o.type, o.frame_id, (row.index(o.signals[0]),))
        for o in out_topic.values():
            if o.type == JOINT_STATE:
                add("joint", CYLINDER, o.topic, o.type, o.frame_id, tuple(row.index(s) for s in o.signals))
        for name in inputs:                         # the plant's
            owner = name.rpartition(".")[0]
            if owner and owner not in valves:
                e = input_topic[name]
                add("input", name, e.topic, e.type, stamped(e.type), name)
        if options:
            for name in (n for n in inputs if n.rpartition(".")[2] in _OPTION_DIRECTION):
                add("input", name, input_topic[name].topic, FLOAT64, "", name)
            for name in (s for s in signals if s.rpartition(".")[2] in _OPTION_DIRECTION):
                add("column", name, topic_of(name), FLOAT64, "", (row.index(name),))
        named = {t.name for t in topics}
        for name, where in extra:
            if name not in named:
                add("column", name, where, FLOAT64, "", (row.index(name),))
        if faults:
            add("text", FAULTS, FAULTS, STRING)
        if events:
            add("text", EVENTS, EVENTS, STRING)
        flows = tuple(f"{prefix[v]}{LOAD_FLOW}" for v in valves if every is None and LOAD_FLOW in roles)
        return cls(tuple(topics), row, every, flows, "emulator" if lone else "rig")

    def of_kind(self, kind: str) -> tuple[Topic, ...]:
        """The topics of one kind, in the bag's order."""
        return tuple(t for t in self.topics if t.kind == kind)

    def topic(self, name: str, kind: str | None = None) -> str:
        """The bag topic of a name (an input, a column's, ``faults``, ``rig/events``)."""
        for t in self.topics:
            if t.name == name and (kind is None or t.kind == kind):
                return t.topic
        msg = f"{name!r} is not in this bag; it has {', '.join(t.name for t in self.topics)}"
        raise BagError(msg)
