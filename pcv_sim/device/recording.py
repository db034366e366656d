"""A device's recorder (`DeviceRecorder`): the one recorder that writes a device's bag on its
layout (`pcv_sim.device.bag_layout.BagLayout`, re-exported here), live from the device's hooks
and offline from a run's arrays. The emulator and the rig are two configurations of it:

- records at model steps (`every`: the emulator, `record.rate_hz`): the recorder is the device's
  per-step hook (`recorder(t_ns, record_values())`, or `record_block` for a stretch at the full
  rate): inputs at the start and then on change as the model used them (the duty after the
  watchdog and the fall-rate limiter), stamped at the step they act from; the true outputs on the
  grid of every `every`-th step from the start;
- records with the samples (`every=None`: the rig): inputs as they act (`on_input`), each sample as
  published (measured: a sensor fault shows; a dropped value has no message), and each valve's
  load flow as its mean over the sample period (the change of its load volume / the period,
  stamped at the period's start: a replay feeds the valve the volume its chamber took);
- offline (`DeviceRecorder.rows`, `pcv_sim.rig.record.write_bag`): a run's arrays, a row per
  sample, with the layout's extra columns (the duty, the setpoint, the controller's flags).

Stamps: log time = model time, one clock for inputs and outputs; a FluidPressure's header stamp
equals its log time. Topics, types and QoS come from the registry; `DeviceRecorder` is a
`pcv_sim.io.recorder.QueuedBag` (the queue, the writer process, drops and finalisation).
"""

from __future__ import annotations

import math
import operator
import os
import struct
from collections.abc import Iterable, Mapping, Sequence
from typing import Any, Final

import numpy as np

from pcv_sim.device.bag_layout import RECORDABLE, BagLayout, Topic, check_signals
from pcv_sim.errors import BagError
from pcv_sim.io.bag import FLOAT64, cdr
from pcv_sim.io.recorder import WRITER_DEFAULTS, QueuedBag, WriterSettings, bag_name
from pcv_sim.io.topics import CYLINDER, EVENTS, FAULTS, JOINT_NAME, JOINT_STATE
from pcv_sim.units import NS_PER_S

__all__ = ["RECORDABLE", "BagLayout", "DeviceRecorder", "Topic", "check_signals"]

_IN: Final = 0       # queue item (_IN, input index, t_ns, value)
_ROW: Final = 1      # queue item (_ROW, t_ns, values of a row)
_TEXT: Final = 2     # queue item (_TEXT, topic, t_ns, text)
_BLOCK: Final = 4    # queue item (_BLOCK, t0_ns, dt_ns, rows): rows at t0, t0 + dt, ...
_ROWS: Final = 5     # queue item (_ROWS, t_ns array, rows)
_SLICE: Final = 1024     # rows per write_samples call (so that a backlog still ends chunks on time)
_STAMP_PACK: Final = struct.Struct("<iI")
_JOINT_PACK: Final = struct.Struct("<d")


class DeviceRecorder(QueuedBag):
    """The recorder of any device, on its `BagLayout` (see the module docstring).

    Args:
        directory: Where the bag directory is created (made if missing).
        layout: What goes where (`BagLayout.of(device, ...)`).
        name: Bag directory name; None = a timestamped one (`pcv_sim.io.recorder.bag_name`). An
            existing bag is never overwritten.
        dt_ns: Model step in ns (recording at model steps).
        namespace: The node's namespace, for the default name (the layout has the topics').
        max_queue_s: Longest backlog (in model time) the queue holds before it is full (at model
            steps); with the samples the queue holds `max_items` items.
        offered_qos: Write each topic's QoS into the bag's metadata (what ``ros2 bag play`` offers).
        writing: How the bag is written (:class:`pcv_sim.io.recorder.WriterSettings`).
    """

    def __init__(
        self,
        directory: str | os.PathLike[str],
        layout: BagLayout,
        *,
        name: str | None = None,
        dt_ns: int = 100_000,
        namespace: str = "/",
        max_queue_s: float = 10.0,
        max_items: int = 100_000,
        offered_qos: bool = True,
        writing: WriterSettings = WRITER_DEFAULTS,
    ) -> None:
        if isinstance(dt_ns, bool) or not isinstance(dt_ns, int) or dt_ns < 1:
            msg = f"dt_ns {dt_ns!r}: accepted is an integer >= 1 (model step in ns)"
            raise BagError(msg)
        if not (math.isfinite(max_queue_s) and max_queue_s > 0.0):
            msg = f"max_queue_s {max_queue_s!r} s: accepted is a finite number > 0"
            raise BagError(msg)
        if name is None:
            name = bag_name(namespace, prefix=layout.prefix)
        self.layout = layout
        self.dt_ns = dt_ns
        self.every = layout.every
        self.inputs = layout.of_kind("input")
        self._input_index = {t.source: k for k, t in enumerate(self.inputs)}
        self._input_index.update({t.name: k for k, t in enumerate(self.inputs)})
        self._flow_inputs = tuple(self._input_index[name] for name in layout.flows)
        self._step_inputs = tuple((k, str(t.source)) for k, t in enumerate(self.inputs))
        columns = layout.of_kind("column")
        #: (frame_id, [(topic, index in a row)]) written together by `write_samples`
        groups: dict[str, list[tuple[str, int]]] = {}
        for c in columns:
            assert isinstance(c.source, tuple)
            groups.setdefault(c.frame_id, []).append((c.topic, c.source[0]))
        self._groups = list(groups.items())
        joint = layout.of_kind("joint")
        self._joint = (joint[0].topic, tuple(map(int, joint[0].source))) if joint else None
        self._per_row = len(columns) + len(joint)
        texts = {t.name: t.topic for t in layout.of_kind("text")}
        self.faults_topic = texts.get(FAULTS)
        self.events_topic = texts.get(EVENTS)
        self.topics = {t.topic: t.type for t in layout.topics}
        self._last: list[float] = [math.nan] * len(self.inputs)
        self._origin: int | None = None
        self.started = False
        self._volumes: tuple[int, list[float]] | None = None    # (t_ns, load volumes) at the last sample
        self._joint_cdr: tuple[bytes, int, tuple[int, int, int]] | None = None
        self._logged = 0
        self._row_of = operator.itemgetter(*layout.row) if len(layout.row) > 1 else (
            lambda values: (values[layout.row[0]],))
        if layout.every is not None:
            every_ns = layout.every * dt_ns
            self._every_ns = every_ns
            # Queue bound in items: rows at their rate plus one input change per step.
            max_items = max(1000, int(max_queue_s * 1e9 / every_ns) + int(max_queue_s * 1e9 / dt_ns))
        super().__init__(
            directory, name, topics=self.topics,
            qos={t.topic: t.qos for t in layout.topics} if offered_qos else {},
            # Pickled bytes per item: a row of the emulator's three outputs ~48, else ~9 per value.
            max_items=max_items, writing=writing, item_bytes=48 if layout.every is not None else 9 * len(layout.row) + 48,
            build={"layout": layout, "dt_ns": dt_ns, "namespace": namespace, "max_queue_s": max_queue_s,
                   "max_items": max_items, "offered_qos": offered_qos})

    # --- a node's side (`pcv_sim.node.device_node`: attach, begin, shown, reset) -----------------

    def attach(self, device: Any) -> None:
        """On the device's hooks: at model steps its per-step recorder (inputs stamped exactly, rows
        on the grid, stretches as `record_block`); with the samples its inputs as they act
        (`on_input`); its fault commands as they act."""
        if self.every is not None:
            device.record_every = 1
            device.recorder = self
        else:
            device.on_input = lambda step, name, value: self.input(device.stamp_ns(step), name, value)
            self._logged = 0
        device.on_fault_command = lambda step, text: self.fault_command(device.stamp_ns(step), text)

    def begin(self, device: Any) -> str:
        """Anchor the recording at the device's present model time (at rest); what goes where (the log)."""
        if self.every is not None:
            self.start(device.stamp_ns(), device.record_values())
            names = [t.name for t in self.layout.topics if t.kind in ("input", "column")]
            return (f"{', '.join(names)} to {self.path} (outputs every {self.every * self.dt_ns * 1e-6:g} ms of "
                    "model time, inputs on change)")
        self.start(device.stamp_ns(), device.input_values())
        return (f"to {self.path}: every valve under its namespace, the cylinder, faults and events (outputs every "
                "control period, inputs on change)")

    def shown(self, device: Any, sample: Any, measured: Sequence[float]) -> None:
        """A published sample (recording with the samples): as measured, the load volumes then, and
        the device's new log entries."""
        if self.every is not None:
            return                      # recorded through the device's per-step hook
        self.sample(device.stamp_ns(sample.step), measured, device.load_volumes())
        if self.events_topic is None:
            return
        log = device.log
        while self._logged < len(log):
            t, text = log[self._logged]
            self._logged += 1
            self.text(self.events_topic, device.stamp_ns(round(t / device.dt)), text)

    def reset(self, device: Any) -> None:
        """The device went back to rest: no mean flow across the jump of its load volumes."""
        self._volumes = None

    # --- the model loop's side ----------------------------------------------------------------

    def start(self, t_ns: int, values: Mapping[str, float]) -> None:
        """Write every recorded input in force at ``t_ns`` (`values` by the inputs' source names); at
        model steps also the row there, which anchors the output grid."""
        self.started = True
        self._origin = t_ns
        put = self._put
        for k, key in self._step_inputs:
            if key in values:
                v = values[key]
                self._last[k] = v
                put((_IN, k, t_ns, v))
        if self.every is not None and self._per_row:
            put((_ROW, t_ns, self._row_of(values)))

    def __call__(self, t_ns: int, values: Mapping[str, float]) -> None:
        """The device at step ``t_ns`` (its per-step hook): inputs on change (stamped t), rows on the grid."""
        if self._origin is None:
            self.start(t_ns, values)
            return
        last = self._last
        for k, key in self._step_inputs:
            v = values[key]
            if v != last[k]:
                last[k] = v
                self._put((_IN, k, t_ns, v))
        if self._per_row and (t_ns - self._origin) % self._every_ns == 0:
            self._put((_ROW, t_ns, self._row_of(values)))

    def record_block(self, t0_ns: int, dt_ns: int, rows: np.ndarray) -> None:
        """Steps t0_ns, t0_ns + dt_ns, ... with their outputs (rows in the order of the device's
        signals) and the inputs of the last call unchanged: the device's stretch of steps in one
        call; the rows on the grid are written as `__call__` would."""
        if not self._per_row or not len(rows):
            return
        if self._origin is None:                  # no start(): the grid starts here
            self._origin = t0_ns
            self.started = True
        every = self._every_ns // dt_ns if self._every_ns % dt_ns == 0 else 0
        if every == 1:
            self._put((_BLOCK, t0_ns, dt_ns, rows))
        elif every > 1:                           # the rows on the output grid: every `every`-th
            j = -((t0_ns - self._origin) // dt_ns) % every
            if j < len(rows):
                self._put((_BLOCK, t0_ns + j * dt_ns, every * dt_ns, rows[j::every]))
        else:                                     # a grid that is not a whole number of steps
            t = t0_ns + dt_ns * np.arange(len(rows), dtype=np.int64)
            for k in np.flatnonzero((t - self._origin) % self._every_ns == 0):
                self._put((_ROW, int(t[k]), tuple(rows[k].tolist())))

    def input(self, t_ns: int, name: str, value: float) -> None:
        """An input (by its name, ``<valve>.duty_cycle``, ``cylinder.external_force`` ...) acting
        from ``t_ns``; written when it changed. An input the layout does not record is left."""
        if not self.started:
            return
        k = self._input_index.get(name)
        if k is None or self._last[k] == value:
            return
        self._last[k] = value
        self._put((_IN, k, t_ns, value))

    def sample(self, t_ns: int, measured: Sequence[float], load_volumes: Iterable[float] = ()) -> None:
        """The sample published at ``t_ns`` (measured, in the order of the layout's row; NaN: no
        message), and the valves' load volumes then (m^3, in the order of the layout's `flows`):
        the mean load flow of the period since the last sample is written (on change), stamped at
        its start."""
        if not self.started:
            return
        if self._flow_inputs:
            volumes = [float(v) for v in load_volumes]
            last = self._volumes
            if last is not None and t_ns > last[0]:
                t0, before = last
                for k, a, b in zip(self._flow_inputs, before, volumes):
                    value = (b - a) * 1e9 / (t_ns - t0)
                    if self._last[k] != value:
                        self._last[k] = value
                        self._put((_IN, k, t0, value))
            self._volumes = (t_ns, volumes)
        self._put((_ROW, t_ns, tuple(measured)))

    def rows(self, t_ns: np.ndarray, rows: np.ndarray) -> None:
        """Rows at the times ``t_ns`` (offline: a run's samples, values in the order of the layout's row)."""
        self.started = True
        self._put((_ROWS, np.asarray(t_ns, dtype=np.int64), np.asarray(rows, dtype=np.float64)))

    def fault_command(self, t_ns: int, text: str) -> None:
        """A fault command that acted at ``t_ns`` (the command as given), when the layout has ``faults``."""
        if self.started and self.faults_topic is not None:
            self._put((_TEXT, self.faults_topic, t_ns, text))

    def text(self, topic: str, t_ns: int, text: str) -> None:
        """A std_msgs/String on one of the layout's text topics."""
        if self.started:
            self._put((_TEXT, topic, t_ns, text))

    # --- the writer's side ------------------------------------------------------------------

    def _count(self, item: tuple[Any, ...]) -> int:
        kind = item[0]
        if kind == _ROW:
            return self._per_row
        if kind in (_BLOCK, _ROWS):
            return len(item[-1]) * self._per_row
        return 1

    def _write_batch(self, items: list[tuple[Any, ...]]) -> None:
        """Inputs and texts message by message; the rows per topic as arrays
        (``BagWriter.write_samples``, ~0.1 µs per message), the joint states from a template."""
        times: list[np.ndarray] = []
        blocks: list[np.ndarray] = []
        singles: list[tuple[Any, ...]] = []

        def take_singles() -> None:
            if singles:
                times.append(np.array([r[1] for r in singles], dtype=np.int64))
                blocks.append(np.array([r[2] for r in singles], dtype=np.float64).reshape(len(singles), -1))
                singles.clear()

        for item in items:                        # the rows in the order they came (time order)
            kind = item[0]
            if kind == _ROW:
                singles.append(item)
            elif kind == _BLOCK:
                take_singles()
                _, t0, dt, rows = item
                times.append(t0 + dt * np.arange(len(rows), dtype=np.int64))
                blocks.append(rows)
            elif kind == _ROWS:
                take_singles()
                times.append(item[1])
                blocks.append(item[2])
            else:
                self._guarded(self._write_message, item, 1)
        take_singles()
        if not blocks:
            return
        t, y = (times[0], blocks[0]) if len(blocks) == 1 else (np.concatenate(times), np.concatenate(blocks))
        for k in range(0, len(t), _SLICE):
            part = slice(k, k + _SLICE)
            self._guarded(self._write_rows, (t[part], y[part]), len(t[part]) * self._per_row)

    def _write_message(self, item: tuple[Any, ...]) -> None:
        """An input or a text."""
        w = self._bag
        if item[0] == _TEXT:
            _, topic, t, text = item
            w.write(topic, int(t), {"data": text})
            return
        _, k, t, v = item
        entry = self.inputs[int(k)]
        if entry.type == FLOAT64:
            w.write_float64(entry.topic, int(t), v)
        else:
            w.write_fluid_pressure(entry.topic, int(t), v, 0.0, entry.frame_id)

    def _write_rows(self, rows: tuple[np.ndarray, np.ndarray]) -> None:
        t, y = rows
        w = self._bag
        if np.isfinite(y).all():                 # the usual case: one bulk call per frame_id
            for frame, cols in self._groups:
                w.write_samples(t, {topic: y[:, j] for topic, j in cols}, frame_id=frame)
        else:
            for frame, cols in self._groups:
                for topic, j in cols:
                    v = y[:, j]
                    ok = np.isfinite(v)          # a dropped sample: no message (never a NaN measurement)
                    if np.any(ok):
                        w.write_samples(t[ok], {topic: v[ok]}, frame_id=frame)
        if self._joint is not None:
            self._write_joints(t, y)

    def _write_joints(self, t: np.ndarray, y: np.ndarray) -> None:
        w = self._bag
        assert self._joint is not None
        topic, (jp, jv, je) = self._joint
        template, at_stamp, at_values = self._joint_template()
        pack = _JOINT_PACK.pack_into
        for k in range(len(t)):
            sec, nsec = divmod(int(t[k]), NS_PER_S)
            p, v, e = y[k, jp], y[k, jv], y[k, je]
            if math.isfinite(p) and math.isfinite(v) and math.isfinite(e):
                buf = bytearray(template)          # the template filled in: ~1 µs instead of ~50 µs
                _STAMP_PACK.pack_into(buf, at_stamp, sec, nsec)
                for at, value in zip(at_values, (p, v, e)):
                    pack(buf, at, value)
                w.write_serialized(topic, int(t[k]), bytes(buf))
                continue
            # A dropped signal is left out of the message (JointState allows empty arrays per field).
            fields = [np.array([x] if math.isfinite(x) else [], dtype=np.float64) for x in (p, v, e)]
            w.write(topic, int(t[k]), {
                "header": {"stamp": {"sec": sec, "nanosec": nsec}, "frame_id": CYLINDER}, "name": [JOINT_NAME],
                "position": fields[0], "velocity": fields[1], "effort": fields[2]})

    def _joint_template(self) -> tuple[bytes, int, tuple[int, int, int]]:
        """The joint state with every field present, serialized once by the generic path with
        sentinel values; where the stamp and the three values sit in it."""
        if self._joint_cdr is None:
            assert self._joint is not None
            sec, nsec = 0x1A2B3C4D, 0x0E1F2A3B
            marks = (1.2345678901234567e-300, -2.3456789012345678e-301, 3.4567890123456789e-302)
            data = cdr.serialize(self._joint[0], JOINT_STATE, {
                "header": {"stamp": {"sec": sec, "nanosec": nsec}, "frame_id": CYLINDER}, "name": [JOINT_NAME],
                "position": np.array(marks[:1]), "velocity": np.array(marks[1:2]), "effort": np.array(marks[2:])})
            where = [data.find(_STAMP_PACK.pack(sec, nsec)), *(data.find(_JOINT_PACK.pack(m)) for m in marks)]
            if min(where) < 0:
                msg = "JointState template: a field was not found in its serialization"
                raise BagError(msg)
            self._joint_cdr = (data, where[0], (where[1], where[2], where[3]))
        return self._joint_cdr
