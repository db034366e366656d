"""The rig's bag layout, beside the rig: where each signal of the rig goes in a bag, for the rig
node's live recording (`RigRecorder`) and the offline bag of a lockstep run
(`pcv_sim.rig.record.write_bag`) alike; topic names from `pcv_sim.io.topics`.

`RigBagLayout`: one namespace per valve holding the emulator's topics (so that one valve of a rig
bag replays like an emulator's bag, `pcv-sim replay --namespace`), the cylinder's topics, the fault
commands and the rig's events, all under the node's namespace. `RigRecorder`: the live recording on
`pcv_sim.io.recorder.QueuedBag` (the one generic queued bag writer: queue, writer process, drop
accounting, finalisation).
"""

from __future__ import annotations

import math
import os
import struct
from collections.abc import Iterable, Mapping
from typing import Any, Final

import numpy as np

from pcv_sim.errors import BagError
from pcv_sim.io.bag import COMMAND_QOS, FLOAT64, FLUID_PRESSURE, SENSOR_DATA_QOS, Qos, cdr
from pcv_sim.io.recorder import ROLE_QOS, STRING, WRITER_DEFAULTS, QueuedBag, WriterSettings, bag_name
from pcv_sim.io.topics import (
    CURRENT,
    CYLINDER,
    EVENTS,
    FAULTS,
    INPUT_ROLES,
    JOINT_NAME,
    JOINT_STATE,
    JOINT_STATES,
    LOAD_FLOW,
    OPTION_INTERFACE,
    PRESSURE,
    ROLE_TYPES,
    ROLES,
    SPOOL_POSITION,
    SUPPLY_PRESSURE,
    bag_topic,
    chamber_topic,
    cylinder_topic,
    valve_topic,
)
from pcv_sim.io.topics import EXTERNAL_FORCE as EXTERNAL_FORCE_ROLE
from pcv_sim.rig.rig import CYLINDER_SIGNALS, EXTERNAL_FORCE

__all__ = ["JOINT_NAME", "JOINT_STATE", "STRING", "RigBagLayout", "RigRecorder"]



class RigBagLayout:
    """The rig's topics in a bag under `namespace` (the node's; "/" offline)."""

    def __init__(self, namespace: str = "/") -> None:
        self.namespace = namespace

    def valve(self, valve: str, role: str) -> str:
        """``<ns>/<valve>/<role>``: a valve's topic, as the emulator's under the valve's name."""
        return bag_topic(valve_topic(valve, role), self.namespace)

    def chamber(self, chamber: str) -> str:
        """``<ns>/cylinder/pressure_a|b``."""
        return bag_topic(chamber_topic(chamber), self.namespace)

    def cylinder(self, name: str) -> str:
        """``<ns>/cylinder/<name>``."""
        return bag_topic(cylinder_topic(name), self.namespace)

    @property
    def joint_states(self) -> str:
        return self.cylinder(JOINT_STATES)

    @property
    def faults(self) -> str:
        return bag_topic(FAULTS, self.namespace)

    @property
    def events(self) -> str:
        return bag_topic(EVENTS, self.namespace)


_IN: Final = 0       # queue item (_IN, topic, t_ns, value)
_TEXT: Final = 2     # queue item (_TEXT, topic, t_ns, text)
_STAMP_PACK: Final = struct.Struct("<iI")
_JOINT_PACK: Final = struct.Struct("<d")
_ROW: Final = 3      # queue item (_ROW, t_ns, measured values, load flows)


class RigRecorder(QueuedBag):
    """The rig node's recorder: every valve's topics under its own namespace exactly as the
    emulator records them (:class:`BagRecorder`: same names, types, QoS, stamps), so that one
    valve of the bag replays like an emulator's bag (``pcv-sim replay --namespace``); and the
    cylinder's and the rig's own topics. ``namespace`` is the node's; topics (``<ns>`` = it):

        <ns>/<valve>/duty_cycle, supply_pressure              inputs, at the start then on change,
                                                             stamped at the step they act from
        <ns>/<valve>/load_flow                                the chamber's mean flow over each
                                                             sample period, stamped at its start
        <ns>/<valve>/pressure, current, spool_position        the samples as published (measured)
        <ns>/cylinder/joint_states, pressure_a|b              the samples as published
        <ns>/cylinder/external_force                          input, on change
        <ns>/<valve>/ambient_temperature, oil_temperature      the valve options' inputs (K), on change,
                                                             stamped at the step they act from
        <ns>/<valve>/coil_temperature, coil_resistance,       the valve options' outputs (K, ohm, m)
                     core_position                            with every sample, as published
        <ns>/faults                                           the fault commands, at the step they acted
        <ns>/rig/events                                       the rig's log: faults, clears, watchdog, reset

    The duty is the one in force (after the watchdog). The load flow is continuous in the rig; the
    bag holds it held over each sample period, as the mean over that period (the change of the
    load volume / the period, stamped at the period's start, written when its end is sampled): a
    replay then feeds the valve exactly the volume the chamber took (pressure fit 99 %; the
    instantaneous flow at each sample gave 98 %). :meth:`restart_flows` leaves the period of a
    jump (a reset) out. A dropped or non-finite measurement has no message, as on the wire. The loop side: :meth:`start`,
    :meth:`input`, :meth:`sample`, :meth:`text`; the rest as :class:`BagRecorder`.

    Args:
        valves: (name, chamber) per valve, in the order of `signals`; chamber ``a``, ``b`` or
            anything else (on its own load volume: no chamber topic).
        signals: The rig's signal names (``<valve>.pressure`` ..., ``cylinder.position`` ...), the
            order of the measured values given to :meth:`sample`.
        options: The valve options' signals the rig has (``<valve>.<name>``, `Rig.option_inputs` and
            `Rig.option_outputs`; :data:`pcv_sim.io.topics.OPTION_INTERFACE`): inputs recorded on
            change, outputs with every sample, in this order after the inputs.
        max_items: Queue bound (items: one per sample, input change or text).
        writing: How the bag is written (:class:`pcv_sim.io.recorder.WriterSettings`).
        Others: as :class:`BagRecorder`.
    """

    def __init__(
        self,
        directory: str | os.PathLike[str],
        *,
        valves: Iterable[tuple[str, str]],
        signals: Iterable[str],
        options: Iterable[str] = (),
        name: str | None = None,
        namespace: str = "/",
        max_items: int = 100_000,
        writing: WriterSettings = WRITER_DEFAULTS,
    ) -> None:
        if name is None:
            name = bag_name(namespace, prefix="rig")
        self.valves = tuple(valves)
        self.signals = tuple(signals)
        self.options = tuple(options)
        layout = RigBagLayout(namespace)
        topics: dict[str, str] = {}
        qos: dict[str, Qos] = {}

        def add(topic: str, msgtype: str, profile: Qos) -> str:
            topics[topic] = msgtype
            qos[topic] = profile
            return topic

        #: input name (as `Rig.on_input` gives it) -> topic
        self._input_topic: dict[str, str] = {}
        #: per valve: (pressure, current, spool_position, load_flow) topics and signal indices
        self._valve_out: list[tuple[str, str, str, str, int, int, int]] = []
        self._chambers: list[tuple[str, str, int]] = []
        for v, chamber in self.valves:
            for role in ROLES:
                add(layout.valve(v, role), ROLE_TYPES[role], ROLE_QOS[role])
            for role in INPUT_ROLES:
                self._input_topic[f"{v}.{role}"] = layout.valve(v, role)
            self._valve_out.append((layout.valve(v, PRESSURE), layout.valve(v, CURRENT),
                                    layout.valve(v, SPOOL_POSITION), layout.valve(v, LOAD_FLOW),
                                    self.signals.index(f"{v}.pressure"), self.signals.index(f"{v}.current"),
                                    self.signals.index(f"{v}.spool_position")))
            if chamber in ("a", "b"):
                self._chambers.append((add(layout.chamber(chamber), FLUID_PRESSURE, SENSOR_DATA_QOS),
                                       f"chamber_{chamber}", self.signals.index(f"{v}.pressure")))
        #: (frame_id, [(topic, signal index)]) written together by `write_samples`
        self._column_groups: list[tuple[str, list[tuple[str, int]]]] = [
            ("load_port", [(p, jp) for p, _i, _x, _q, jp, _ji, _jx in self._valve_out]),
            ("", [c for _p, i, x, _q, _jp, ji, jx in self._valve_out for c in ((i, ji), (x, jx))]),
            *((frame, [(topic, j)]) for topic, frame, j in self._chambers)]
        self._joint = add(layout.joint_states, JOINT_STATE, SENSOR_DATA_QOS)
        self._joint_i = tuple(self.signals.index(f"{CYLINDER}.{q}") for q in CYLINDER_SIGNALS)
        self._input_topic[EXTERNAL_FORCE] = add(layout.cylinder(EXTERNAL_FORCE_ROLE), FLOAT64, COMMAND_QOS)
        directions = {e.name: e.direction for e in OPTION_INTERFACE}
        #: the options' output topics, in the order of the option values given to `sample`
        self._option_out: list[str] = []
        for option in self.options:
            valve, _, role = option.partition(".")
            if valve not in dict(self.valves) or role not in directions:
                msg = (f"record option signal {option!r}: accepted are <valve>.<name> for a valve of the rig and a "
                       f"name of {', '.join(directions)}")
                raise BagError(msg)
            if directions[role] == "in":
                self._input_topic[option] = add(layout.valve(valve, role), FLOAT64, COMMAND_QOS)
            else:
                self._option_out.append(add(layout.valve(valve, role), FLOAT64, SENSOR_DATA_QOS))
        self.faults_topic = add(layout.faults, STRING, COMMAND_QOS)
        self.events_topic = add(layout.events, STRING, COMMAND_QOS)
        self.topics = dict(topics)
        self._last: dict[str, float] = {}
        self.started = False
        self._volumes: tuple[int, list[float]] | None = None    # (t_ns, load volumes) at the last sample
        self._joint_cdr: tuple[bytes, int, tuple[int, int, int]] | None = None
        self._per_row = 3 * len(self.valves) + len(self._chambers) + 1 + len(self._option_out)
        super().__init__(
            directory, name, topics=topics, qos=qos, max_items=max_items, writing=writing,
            item_bytes=9 * (len(self.signals) + len(self._option_out)) + 48,
            build={"valves": self.valves, "signals": self.signals, "options": self.options, "namespace": namespace,
                   "max_items": max_items})

    # --- a node's side (`pcv_sim.node.device_node`: every device's recorder offers these) ------

    def attach(self, device: Any) -> None:
        """On a `Rig`'s hooks: its inputs as they change (`on_input`), its fault commands as they act."""
        self._logged = 0
        device.on_input = lambda step, name, value: self.input(device.stamp_ns(step), name, value)
        device.on_fault_command = lambda step, text: self.text(self.faults_topic, device.stamp_ns(step), text)

    def begin(self, device: Any) -> str:
        """Start with every input in force at the present model time (the rig at rest); what goes where."""
        self.start(device.stamp_ns(), device.input_values())
        return (f"to {self.path}: every valve under its namespace, the cylinder, faults and events (outputs every "
                "control period, inputs on change)")

    def shown(self, device: Any, sample: Any, measured: Iterable[float]) -> None:
        """A published sample (the rig at its step): measured values, the load volumes, the options'
        true outputs, and the rig's new log entries."""
        self.sample(device.stamp_ns(sample.step), measured, device.load_volumes(), device.option_sample)
        log = device.log
        while self._logged < len(log):
            t, text = log[self._logged]
            self._logged += 1
            self.text(self.events_topic, device.stamp_ns(round(t / device.dt)), text)

    def reset(self, device: Any) -> None:
        """The piston jumped back to rest: no mean flow across the reset."""
        self.restart_flows()

    # --- the model loop's side ----------------------------------------------------------------

    def start(self, t_ns: int, inputs: Mapping[str, float]) -> None:
        """Write every input in force at ``t_ns`` (the rig at rest; names as `Rig.on_input`'s); inputs
        before this are not recorded."""
        self.started = True
        for key, value in inputs.items():
            self._last.pop(key, None)
            self.input(t_ns, key, value)

    def input(self, t_ns: int, name: str, value: float) -> None:
        """An input (``<valve>.duty_cycle``, ``<valve>.supply_pressure``, ``<valve>.load_flow``,
        ``cylinder.external_force``) acting from ``t_ns``; written when it changed."""
        if not self.started or self._last.get(name) == value:
            return
        topic = self._input_topic.get(name)
        if topic is None:
            msg = f"input {name!r}: accepted are {', '.join(self._input_topic)}"
            raise BagError(msg)
        self._last[name] = value
        self._put((_IN, topic, t_ns, value))

    def sample(self, t_ns: int, measured: Iterable[float], load_volumes: Iterable[float],
               options: Iterable[float] = ()) -> None:
        """The sample published at ``t_ns`` (measured, in the order of `signals`; NaN: dropped), the
        valves' load volumes then (m^3, in the order of `valves`): the mean load flow of the period
        since the last sample is written (on change), stamped at its start; and the options' outputs
        (in the order of the output names in `options`)."""
        if not self.started:
            return
        volumes = [float(v) for v in load_volumes]
        last = self._volumes
        if last is not None and t_ns > last[0]:
            t0, before = last
            for (v, _), a, b in zip(self.valves, before, volumes):
                self.input(t0, f"{v}.{LOAD_FLOW}", (b - a) * 1e9 / (t_ns - t0))
        self._volumes = (t_ns, volumes)
        self._put((_ROW, t_ns, tuple(measured), tuple(options)))

    def restart_flows(self) -> None:
        """The load volumes jumped (a reset): no mean flow for the period up to the next sample."""
        self._volumes = None

    def text(self, topic: str, t_ns: int, text: str) -> None:
        """A std_msgs/String on `faults_topic` or `events_topic`."""
        if self.started:
            self._put((_TEXT, topic, t_ns, text))

    # --- the writer's side ------------------------------------------------------------------

    def _count(self, item: tuple[Any, ...]) -> int:
        return self._per_row if item[0] == _ROW else 1

    def _write_batch(self, items: list[tuple[Any, ...]]) -> None:
        """Inputs and texts message by message; the samples per topic as arrays
        (``BagWriter.write_samples``), the joint states message by message."""
        rows = []
        for item in items:
            if item[0] == _ROW:
                rows.append(item)
            else:
                self._guarded(self._write_message, item, 1)
        if rows:
            self._guarded(self._write_rows, rows, len(rows) * self._per_row)

    def _write_message(self, item: tuple[Any, ...]) -> None:
        """An input or a text."""
        w = self._bag
        if item[0] == _TEXT:
            _, topic, t, text = item
            w.write(topic, int(t), {"data": text})
        else:
            _, topic, t, v = item
            if topic.endswith("/" + SUPPLY_PRESSURE):
                w.write_fluid_pressure(topic, int(t), v, 0.0, "load_port")
            else:
                w.write_float64(topic, int(t), v)

    def _write_rows(self, rows: list[tuple[Any, ...]]) -> None:
        w = self._bag
        t = np.array([r[1] for r in rows], dtype=np.int64)
        y = np.array([r[2] for r in rows], dtype=np.float64).reshape(len(rows), len(self.signals))

        groups = self._column_groups
        if np.isfinite(y).all():                 # the usual case: one bulk call per frame_id
            for frame, cols in groups:
                w.write_samples(t, {topic: y[:, j] for topic, j in cols}, frame_id=frame)
        else:
            for frame, cols in groups:
                for topic, j in cols:
                    v = y[:, j]
                    ok = np.isfinite(v)          # a dropped sample: no message (never a NaN measurement)
                    if np.any(ok):
                        w.write_samples(t[ok], {topic: v[ok]}, frame_id=frame)
        if self._option_out:
            o = np.array([r[3] for r in rows], dtype=np.float64).reshape(len(rows), len(self._option_out))
            for j, topic in enumerate(self._option_out):
                ok = np.isfinite(o[:, j])
                if np.any(ok):
                    w.write_samples(t[ok], {topic: o[ok, j]}, frame_id="")
        jp, jv, je = self._joint_i
        template, at_stamp, at_values = self._joint_template()
        pack = _JOINT_PACK.pack_into
        for k in range(len(rows)):
            sec, nsec = divmod(int(t[k]), 1_000_000_000)
            p, v, e = y[k, jp], y[k, jv], y[k, je]
            if math.isfinite(p) and math.isfinite(v) and math.isfinite(e):
                buf = bytearray(template)          # the template filled in: ~1 µs instead of ~50 µs
                _STAMP_PACK.pack_into(buf, at_stamp, sec, nsec)
                for at, value in zip(at_values, (p, v, e)):
                    pack(buf, at, value)
                w.write_serialized(self._joint, int(t[k]), bytes(buf))
                continue
            # A dropped signal is left out of the message (JointState allows empty arrays per field).
            fields = [np.array([x] if math.isfinite(x) else [], dtype=np.float64) for x in (p, v, e)]
            w.write(self._joint, int(t[k]), {
                "header": {"stamp": {"sec": sec, "nanosec": nsec}, "frame_id": CYLINDER}, "name": [JOINT_NAME],
                "position": fields[0], "velocity": fields[1], "effort": fields[2]})

    def _joint_template(self) -> tuple[bytes, int, tuple[int, int, int]]:
        """The joint state with every field present, serialized once by the generic path with
        sentinel values; where the stamp and the three values sit in it."""
        if self._joint_cdr is None:
            sec, nsec = 0x1A2B3C4D, 0x0E1F2A3B
            marks = (1.2345678901234567e-300, -2.3456789012345678e-301, 3.4567890123456789e-302)
            data = cdr.serialize(self._joint, JOINT_STATE, {
                "header": {"stamp": {"sec": sec, "nanosec": nsec}, "frame_id": CYLINDER}, "name": [JOINT_NAME],
                "position": np.array(marks[:1]), "velocity": np.array(marks[1:2]), "effort": np.array(marks[2:])})
            where = [data.find(_STAMP_PACK.pack(sec, nsec)), *(data.find(_JOINT_PACK.pack(m)) for m in marks)]
            if min(where) < 0:
                msg = "JointState template: a field was not found in its serialization"
                raise BagError(msg)
            self._joint_cdr = (data, where[0], (where[1], where[2], where[3]))
        return self._joint_cdr


