"""Recording the emulated device into a bag, from inside the node, without ROS.

:class:`BagRecorder` is the device's recorder (the ``recorder(t_ns, signals)`` hook of
:class:`pcv_sim.device.valve.ValveDevice`, called at every model step) on top of
:class:`pcv_sim.io.bag.BagWriter`. It writes the device topics (:mod:`pcv_sim.io.topics`) with
the node's namespace, so a bag of the emulator in ``/left`` holds ``/left/pressure`` etc.
:class:`QueuedBag` is the one generic queued bag writer under it and under each device's own
layout (the rig's: ``pcv_sim.rig.bag.RigRecorder``): the queue, the writer thread or process, the
drop accounting and the finalisation described below.

What is written, and when (log time = model sample time, one clock for inputs and outputs):

- Outputs (``pressure``, ``current``, ``spool_position``) at every ``every``-th model step
  counted from the start (``every = 1``: the full 0.1 ms model rate). ``pressure`` is a
  FluidPressure whose header stamp equals its log time.
- Inputs (``duty_cycle``, ``load_flow``, ``supply_pressure``) at the start and then only when
  they change, as the model actually used them: the duty after the watchdog and the fall-rate
  limiter. The call for step t carries the state at t and the inputs in force from t on (the
  device's convention, `ValveDevice.run`), so a changed input is stamped t, the step at which
  it took effect. This needs a call at *every* model step, whatever the output rate: the
  recorder decimates the outputs itself.
- :meth:`BagRecorder.start` writes every selected signal at the first stamp (the device at
  rest): a replay starts the model at rest at the first duty command.
- The bag's metadata names the ROS distribution and, per topic, the QoS the node offers
  (:data:`ROLE_QOS`: outputs best effort keep last 5, inputs reliable keep last 10), so that
  ``ros2 bag play`` republishes each topic as the node does (docs/interface.md).

Timing. The model loop must not wait for the disk, nor for the interpreter lock. Where the disk
work runs is :class:`WriterSettings`' ``writer``:

- ``process`` (what the nodes use): a call appends a tuple to a list (~1 µs per step with all
  signals); every ``batch_period`` s (or 4096 items) the loop pickles the list into a
  shared-memory ring (~25 µs for 200 items) and a writer process (:mod:`pcv_sim.io.writer_process`)
  does the rest with this same class's writing side. The node's interpreter lock is then the
  loop's alone, and the writer runs under SCHED_IDLE: on a busy machine it waits for idle CPU and
  the ring (``max_queue_s`` of items) holds the backlog; past half of it the writer works at normal
  priority.
- ``thread``: the same queue taken by a writer thread every ``batch_period`` s, serialising the
  output samples as whole numpy arrays (``BagWriter.write_samples``, ~0.2 µs per message). Python
  threads share one interpreter lock: the loop waits whenever it wakes while the writer holds it,
  and on a busy machine the writer can be preempted *holding* it, which stalls the loop for a
  scheduler slice although the loop has a core (BENCHMARKS.md, "Recording", has what this
  costs next to the device's own per-step work).
- ``inline``: everything inside the call (every ~5-8 ms chunk flush landing on a model step).

Durability: a SIGKILL of the node or a power cut (chunks are fsync'ed) loses at most what was
not yet handed over (``batch_period``) plus what the BagWriter had not flushed
(``0.8 * flush_period_s`` at most, plus one flush), under one second with the defaults. With
``writer="process"`` a SIGKILL of the node alone loses only the batch in progress: the writer
process sees the node gone, writes what it had and finalizes the bag. ``close()`` (SIGINT/SIGTERM
in the node) finalizes the bag with everything recorded. Nothing is dropped silently: when the
writer cannot keep up (more than ``max_queue_s`` of data waiting) or writing failed (disk full, a
writer process that died), later messages are counted in :attr:`RecorderStatus.dropped` and the
failure is kept in :attr:`RecorderStatus.error`; the device keeps running either way.
"""

from __future__ import annotations

import collections
import contextlib
import dataclasses
import itertools
import math
import os
import pickle
import re
import threading
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final, Literal, Self

import numpy as np

from pcv_sim.errors import BagError
from pcv_sim.io.bag import COMMAND_QOS, FLOAT64, SENSOR_DATA_QOS, BagWriter, Qos
from pcv_sim.io.topics import (
    CURRENT,
    DUTY_CYCLE,
    FAULTS,
    INPUT_ROLES,
    LOAD_FLOW,
    OPTION_INTERFACE,
    OUTPUT_ROLES,
    PRESSURE,
    ROLE_ALIASES,
    ROLE_TYPES,
    ROLES,
    SPOOL_POSITION,
    SUPPLY_PRESSURE,
    bag_topic,
    role_of,
)
from pcv_sim.io.writer_process import WriterProcess

__all__ = [
    "RECORDABLE",
    "ROLE_QOS",
    "STRING",
    "SWITCH_INTERVAL",
    "WRITER_DEFAULTS",
    "BagRecorder",
    "QueuedBag",
    "RecorderStatus",
    "Writer",
    "WriterSettings",
    "bag_name",
    "check_signals",
]

#: The QoS the emulator offers per role (docs/interface.md): written into the bag as each
#: topic's ``offered_qos_profiles`` so that ``ros2 bag play`` republishes it the same way.
ROLE_QOS: Final[Mapping[str, Qos]] = {
    **{r: SENSOR_DATA_QOS for r in OUTPUT_ROLES},
    **{r: COMMAND_QOS for r in INPUT_ROLES},
}

#: Where a recorder's disk work runs (see `WriterSettings.writer`).
Writer = Literal["process", "thread", "inline"]
#: Signals a recorder can write, by role (the device's topic names).
RECORDABLE: Final = ROLES
#: Interpreter switch interval (s) a node sets while a threaded recorder runs: the longest a
#: woken model loop waits for the writer thread to hand over the interpreter lock.
SWITCH_INTERVAL: Final = 1e-3

# Device signal (pcv_sim.device.valve.SIGNALS) each role is recorded from.
_SOURCE: Final = {
    DUTY_CYCLE: "duty",             # effective: after watchdog and fall-rate limiter
    LOAD_FLOW: "load_flow",
    SUPPLY_PRESSURE: "supply_pressure",
    PRESSURE: "pressure",
    CURRENT: "current",
    SPOOL_POSITION: "spool_position",
}
_IN: Final = 0     # queue item (_IN, role index, t_ns, value)
_OUT: Final = 1    # queue item (_OUT, t_ns, pressure, current, spool_position)
_BLOCK: Final = 4  # queue item (_BLOCK, t0_ns, dt_ns, rows of pressure, current, spool_position)
_TEXT: Final = 2   # queue item (_TEXT, topic, t_ns, text)
#: The type of the text topics (fault commands, events).
STRING: Final = "std_msgs/msg/String"
_SLICE: Final = 1024   # output samples per write_samples call (~130 kB with all three outputs)
_SHIP_ITEMS: Final = 4096   # items per batch to the writer process at most (besides batch_period)
_NAME_OK: Final = re.compile(r"^[A-Za-z0-9_.\-]+$")


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


def bag_name(namespace: str = "/", when: float | None = None, *, prefix: str = "emulator") -> str:
    """A timestamped bag name, ``<prefix>[_<namespace>]_YYYYmmdd-HHMMSS`` (local time)."""
    ns = "_".join(p for p in namespace.strip("/").split("/") if p)
    stamp = time.strftime("%Y%m%d-%H%M%S", time.localtime(time.time() if when is None else when))
    return f"{prefix}_{ns}_{stamp}" if ns else f"{prefix}_{stamp}"


@dataclass(frozen=True)
class RecorderStatus:
    """What the recorder has done so far (diagnostics)."""

    state: Literal["recording", "failed", "closed"]
    path: Path
    files: int            # MCAP files so far (split)
    messages: int         # handed to the bag writer
    bytes: int            # on disk now (flushed chunks)
    queued: int           # samples waiting for the writer thread
    dropped: int          # messages not written: queue full or writing failed
    error: str            # why writing failed ('' if it did not)


@dataclass(frozen=True)
class WriterSettings:
    """How a recorder writes its bag, whatever it records (every recorder takes one; the writer
    process gets it too): where the disk work runs, how often it takes the queue, how the bag is
    flushed and split, what a full queue does. Checked when made (BagError saying what is accepted).

    Attributes:
        split_size_bytes: Start a new MCAP file when one reaches this size; None = never.
        writer: Where the disk work runs: ``process`` (a writer process fed through shared
            memory, :mod:`pcv_sim.io.writer_process`: what the nodes use), ``thread`` (a writer
            thread, default) or ``inline`` (inside each call).
        batch_period: s between the writer's turns.
        flush_period_s: The BagWriter's flush period (durability bound, wall clock).
        chunk_size: Uncompressed MCAP chunk size that forces a flush earlier.
        fsync: ``os.fsync`` at every flush, so flushed chunks also survive a power cut (done by
            the writer; inline it lands on a model step).
        when_full: What a call does when the queue is full: ``drop`` (real time: count the
            messages as dropped) or ``wait`` for the writer (simulated time, where the model may
            run far faster than the writer: a complete bag).
        ros_distro: The ROS 2 distribution for the bag's metadata; None detects it
            (``ROS_DISTRO``, else the installed rclpy: :func:`pcv_sim.io.bag.detect_ros_distro`).
    """

    split_size_bytes: int | None = None
    writer: Writer = "thread"
    batch_period: float = 0.02
    flush_period_s: float = 0.9
    chunk_size: int = 1 << 20
    fsync: bool = True
    when_full: Literal["drop", "wait"] = "drop"
    ros_distro: str | None = None

    def __post_init__(self) -> None:
        if self.writer not in ("process", "thread", "inline"):
            msg = f"writer {self.writer!r}: accepted are 'process', 'thread' and 'inline'"
            raise BagError(msg)
        if not (math.isfinite(self.batch_period) and 0.0 < self.batch_period <= 0.1):
            msg = f"batch_period {self.batch_period!r} s: accepted is 0 < batch_period <= 0.1"
            raise BagError(msg)
        if self.when_full not in ("drop", "wait"):
            msg = f"when_full {self.when_full!r}: accepted are 'drop' and 'wait'"
            raise BagError(msg)


#: A recorder's writing unless told otherwise.
WRITER_DEFAULTS: Final = WriterSettings()


class QueuedBag:
    """What every recorder here shares: the bag directory (never overwritten), the BagWriter, the
    queue the model loop appends to, the writer thread, drop accounting, status and close.
    Subclasses say how many messages an item makes (`_count`) and write a batch (`_write_batch`)."""

    def __init__(
        self,
        directory: str | os.PathLike[str],
        name: str,
        *,
        topics: Mapping[str, str],
        qos: Mapping[str, Qos],
        max_items: int,
        writing: WriterSettings,
        build: Mapping[str, Any],
        item_bytes: int,
    ) -> None:
        writer, batch_period = writing.writer, writing.batch_period
        if not isinstance(name, str) or not _NAME_OK.match(name) or name in (".", ".."):
            msg = (f"bag name {name!r}: accepted is a plain directory name of letters, digits, "
                   f"'_', '-', '.' (the directory is given separately)")
            raise BagError(msg)
        self.path = Path(directory) / name
        if self.path.exists():
            msg = (f"bag {str(self.path)!r} exists already; the recorder never overwrites a bag: "
                   f"choose another name (or the default timestamped one) or move it away")
            raise BagError(msg)
        try:
            Path(directory).mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            msg = f"cannot create the recording directory {str(directory)!r}: {exc.strerror}"
            raise BagError(msg) from exc
        self._max_items = max_items
        self._queue: collections.deque[tuple[Any, ...]] = collections.deque()
        self._dropped = 0
        self._error = ""
        self._closed = False
        self._lock = threading.Lock()          # writer side only: drain vs close
        self.writer = writer
        self.threaded = writer == "thread"
        self.when_full = writing.when_full
        self.batch_period = batch_period
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._proc: WriterProcess | None = None
        self._final: RecorderStatus | None = None
        if writer == "process":
            self._local: list[tuple[Any, ...]] = []
            self._ship_due = time.monotonic() + batch_period
            self._proc = WriterProcess(
                (type(self).__module__, type(self).__qualname__,
                 {**build, "directory": directory, "name": name,
                  "writing": dataclasses.replace(writing, writer="inline")}),
                capacity=max_items * item_bytes, batch_period=batch_period)
            self._writer: BagWriter | None = None
            return
        self._writer = BagWriter(
            self.path,
            topics=topics,
            qos=qos,
            ros_distro=writing.ros_distro,
            flush_period_s=writing.flush_period_s,
            split_size_bytes=writing.split_size_bytes,
            chunk_size=writing.chunk_size,
            fsync=writing.fsync,
        )
        if writer == "thread":
            self._thread = threading.Thread(target=self._run, name=f"{type(self).__name__}:{name}", daemon=True)
            self._thread.start()

    # --- the model loop's side ----------------------------------------------------------------

    def _put(self, item: tuple[Any, ...]) -> None:
        if self._proc is not None:
            local = self._local
            local.append(item)
            if len(local) >= _SHIP_ITEMS or time.monotonic() >= self._ship_due:
                self._ship()
            return
        if self.threaded:
            q = self._queue
            if len(q) >= self._max_items and self.when_full == "wait":
                while len(q) >= self._max_items and self._thread is not None and self._thread.is_alive():
                    time.sleep(self.batch_period / 4)
            if len(q) < self._max_items and not self._error and not self._closed:
                q.append(item)
            else:
                self._dropped += self._count(item)
        elif self._error or self._closed:
            self._dropped += self._count(item)
        else:
            with self._lock:
                self._write_batch([item])

    def _ship(self, wait: bool = False) -> None:
        """The items gathered since the last batch into the writer process's ring (one pickle)."""
        proc = self._proc
        assert proc is not None
        local, self._local = self._local, []
        self._ship_due = time.monotonic() + self.batch_period
        if not local:
            return
        if not self._error:
            self._error = proc.failure()
        if self._error or self._closed:
            self._dropped += sum(map(self._count, local))
            return
        payload = pickle.dumps(local, pickle.HIGHEST_PROTOCOL)
        count = sum(map(self._count, local))
        while not proc.put(payload, len(local), count):
            if not (wait or self.when_full == "wait") or proc.failure():
                self._dropped += count
                return
            time.sleep(self.batch_period / 4)

    # --- the writer's side ------------------------------------------------------------------

    def _count(self, item: tuple[Any, ...]) -> int:
        """Messages `item` makes."""
        raise NotImplementedError

    def _guarded(self, write: Callable[[Any], None], what: Any, messages: int) -> None:
        """`write(what)` unless writing failed already; its `messages` counted as dropped when it
        cannot be written (the first failure is kept: `_fail`)."""
        if self._error:
            self._dropped += messages
            return
        try:
            write(what)
        except (BagError, OSError) as exc:
            self._fail(exc)
            self._dropped += messages

    def write_items(self, items: list[tuple[Any, ...]]) -> None:
        """Write items the loop side queued (the writer process's call)."""
        with self._lock:
            self._write_batch(items)

    def _write_batch(self, items: list[tuple[Any, ...]]) -> None:
        """Write `items` (under the lock); a failure goes to `_fail`, what it lost to `_dropped`."""
        raise NotImplementedError

    def _drain(self) -> None:
        """Write what is queued (writer thread, or close)."""
        q = self._queue
        with self._lock:
            items = [q.popleft() for _ in range(len(q))]
            if items:
                self._write_batch(items)

    @property
    def _bag(self) -> BagWriter:
        """The BagWriter (writer side; with writer="process" it lives in the writer process)."""
        if self._writer is None:
            msg = f"bag {str(self.path)!r} is written by its writer process, not here"
            raise BagError(msg)
        return self._writer

    def _fail(self, exc: BaseException) -> None:
        if not self._error:
            self._error = f"{type(exc).__name__}: {exc}"

    def _run(self) -> None:
        _normal_scheduling()
        while not self._stop.wait(self.batch_period):
            self._drain()

    # --- status and shutdown ------------------------------------------------------------------

    @property
    def error(self) -> str:
        return self._error

    def status(self) -> RecorderStatus:
        if self._final is not None:
            return self._final
        if self._proc is not None:
            return self._process_status()
        assert self._writer is not None
        files = self._writer.files
        size = 0
        for f in files:
            with contextlib.suppress(OSError):
                size += f.stat().st_size
        state: Literal["recording", "failed", "closed"] = (
            "failed" if self._error else "closed" if self._closed else "recording")
        return RecorderStatus(state, self.path, len(files), self._writer.message_count, size,
                              len(self._queue), self._dropped, self._error)

    def _process_status(self) -> RecorderStatus:
        proc = self._proc
        assert proc is not None
        if not self._error:
            self._error = proc.failure()
        if self._local and (self._error or time.monotonic() >= self._ship_due) and not self._closed:
            self._ship()                         # the loop may be idle (a fault): the batch still goes
        # A writer that failed loses what it had not written: handed over, neither written nor dropped there.
        lost = max(0, proc.shipped_messages - proc.messages - proc.dropped) if self._error else 0
        files = sorted(self.path.glob("*.mcap"))
        size = 0
        for f in files:
            with contextlib.suppress(OSError):
                size += f.stat().st_size
        state: Literal["recording", "failed", "closed"] = (
            "failed" if self._error else "closed" if self._closed else "recording")
        queued = 0 if self._error else len(self._local) + proc.shipped - proc.taken
        return RecorderStatus(state, self.path, len(files), proc.messages, size, queued,
                              self._dropped + proc.dropped + lost, self._error)

    def close(self) -> RecorderStatus:
        """Write what is queued and finalize the bag (summary, footer, metadata.yaml). Idempotent."""
        if self._proc is not None:
            if not self._closed:
                self._ship(wait=True)
                self._closed = True
                self._proc.close()
                self._error = self._error or self._proc.failure()
                self._final = self._process_status()
                self._proc.ring.close()
            assert self._final is not None
            return self._final
        if self._thread is not None:
            self._stop.set()
            self._thread.join()
            self._thread = None
        if not self._closed:
            self._drain()
            self._closed = True
            try:
                assert self._writer is not None
                self._writer.close()
            except (BagError, OSError) as exc:
                self._fail(exc)
        return self.status()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class BagRecorder(QueuedBag):
    """The device recorder writing a rosbag2/MCAP bag (see the module docstring).

    Args:
        directory: Where the bag directory is created (made if missing).
        name: Bag directory name; ``None`` = :func:`bag_name` (timestamped). An existing bag
            is never overwritten.
        signals: Roles to record (:func:`check_signals`); default all six.
        options: The valve options' signals to record too (:data:`pcv_sim.io.topics.OPTION_INTERFACE`
            names, std_msgs/Float64 in SI): inputs on change, outputs at each call on the output grid
            (with `record_block`, the device calls at least once per published sample).
        every: Record the outputs at every ``every``-th model step (1 = every 0.1 ms step).
        dt_ns: Model step in ns.
        namespace: The node's namespace, for the topic names (:func:`bag_topic`).
        frame_id: ``header.frame_id`` of the FluidPressure messages.
        max_queue_s: Longest backlog (in model time) the queue holds before it is full.
        faults: Record the fault commands too (``faults``, std_msgs/String, at the step each acted:
            :meth:`fault_command`), as the rig's bag does; a device with its fault topic on.
        writing: How the bag is written (:class:`WriterSettings`).
    """

    def __init__(
        self,
        directory: str | os.PathLike[str],
        *,
        name: str | None = None,
        signals: Iterable[str] = RECORDABLE,
        options: Iterable[str] = (),
        every: int = 1,
        dt_ns: int = 100_000,
        namespace: str = "/",
        frame_id: str = "",
        max_queue_s: float = 10.0,
        faults: bool = False,
        writing: WriterSettings = WRITER_DEFAULTS,
    ) -> None:
        if isinstance(every, bool) or not isinstance(every, int) or every < 1:
            msg = f"every {every!r}: accepted is an integer >= 1 (model steps between output samples)"
            raise BagError(msg)
        if isinstance(dt_ns, bool) or not isinstance(dt_ns, int) or dt_ns < 1:
            msg = f"dt_ns {dt_ns!r}: accepted is an integer >= 1 (model step in ns)"
            raise BagError(msg)
        if not (math.isfinite(max_queue_s) and max_queue_s > 0.0):
            msg = f"max_queue_s {max_queue_s!r} s: accepted is a finite number > 0"
            raise BagError(msg)
        if name is None:
            name = bag_name(namespace)
        self.signals = check_signals(signals)
        directions = {e.name: e.direction for e in OPTION_INTERFACE}
        self.options = tuple(options)
        unknown = [o for o in self.options if o not in directions]
        if unknown:
            msg = f"record option signal(s) {', '.join(map(repr, unknown))}: accepted are {', '.join(directions)}"
            raise BagError(msg)
        self.every = every
        self.dt_ns = dt_ns
        self.frame_id = frame_id
        self.topics = {role: bag_topic(role, namespace) for role in self.signals}
        n_in = len(INPUT_ROLES)
        # Option inputs go as inputs (on change), indexed after INPUT_ROLES; option outputs on the grid.
        self._inputs = tuple((k, r, _SOURCE[r]) for k, r in enumerate(INPUT_ROLES) if r in self.signals) + tuple(
            (n_in + j, o, o) for j, o in enumerate(self.options) if directions[o] == "in")
        self._option_outputs = tuple((n_in + j, o) for j, o in enumerate(self.options) if directions[o] == "out")
        self._input_topics = tuple(bag_topic(r, namespace) for r in (*INPUT_ROLES, *self.options))
        option_topics = {bag_topic(o, namespace): o for o in self.options}
        self._outputs = any(r in self.signals for r in OUTPUT_ROLES)
        self._p_topic = self.topics.get(PRESSURE)
        self._i_topic = self.topics.get(CURRENT)
        self._x_topic = self.topics.get(SPOOL_POSITION)
        self._last = [math.nan] * (n_in + len(self.options))
        self._origin: int | None = None
        self._every_ns = every * dt_ns
        self._per_output = sum(r in self.signals for r in OUTPUT_ROLES)
        self.faults_topic = bag_topic(FAULTS, namespace) if faults else None
        texts = {self.faults_topic: STRING} if self.faults_topic else {}
        # Queue bound in items: outputs at their rate plus one input change per step.
        max_items = max(1000, int(max_queue_s * 1e9 / self._every_ns) + int(max_queue_s * 1e9 / dt_ns))
        super().__init__(
            directory, name,
            topics={**{self.topics[r]: ROLE_TYPES[r] for r in self.signals}, **dict.fromkeys(option_topics, FLOAT64),
                    **texts},
            qos={**{self.topics[r]: ROLE_QOS[r] for r in self.signals},
                 **{t: SENSOR_DATA_QOS if directions[o] == "out" else COMMAND_QOS for t, o in option_topics.items()},
                 **dict.fromkeys(texts, COMMAND_QOS)},
            max_items=max_items, writing=writing, item_bytes=48,
            build={"signals": self.signals, "options": self.options, "every": every, "dt_ns": dt_ns, "namespace": namespace,
                   "frame_id": frame_id, "max_queue_s": max_queue_s, "faults": faults})

    # --- a node's side (`pcv_sim.node.device_node`: every device's recorder offers these) ------

    def attach(self, device: Any) -> None:
        """On a `ValveDevice`'s hooks: called at every model step (inputs stamped exactly, outputs
        decimated here; stretches as `record_block`), and with each fault command that acted."""
        device.record_every = 1
        device.recorder = self
        device.on_fault_command = lambda step, text: self.fault_command(device.stamp_ns(step), text)

    def begin(self, device: Any) -> str:
        """Anchor the recording at the device's present model time (at rest); what goes where (the log)."""
        self.start(device.stamp_ns(), device.record_values())
        return (f"{', '.join((*self.signals, *self.options))} to {self.path} (outputs every "
                f"{self.every * self.dt_ns * 1e-6:g} ms of model time, inputs on change)")

    def shown(self, device: Any, sample: Any, measured: Any) -> None:
        """A published sample: recorded through the device's hook already."""

    def reset(self, device: Any) -> None:
        """The device went back to rest: the hook records its inputs as they change."""

    # --- the model loop's side ----------------------------------------------------------------

    def start(self, t_ns: int, signals: Mapping[str, float]) -> None:
        """Anchor the output grid at ``t_ns`` and write every selected signal there (at rest)."""
        self._origin = t_ns
        put = self._put
        for k, _role, key in self._inputs:
            v = signals[key]
            self._last[k] = v
            put((_IN, k, t_ns, v))
        if self._outputs:
            put((_OUT, t_ns, signals["pressure"], signals["current"], signals["spool_position"]))
        for k, key in self._option_outputs:
            put((_IN, k, t_ns, signals[key]))

    def __call__(self, t_ns: int, signals: Mapping[str, float]) -> None:
        """The device at step ``t_ns``: inputs on change (stamped t), outputs on the grid."""
        if self._origin is None:
            self.start(t_ns, signals)
            return
        last = self._last
        for k, _role, key in self._inputs:
            v = signals[key]
            if v != last[k]:
                last[k] = v
                self._put((_IN, k, t_ns, v))
        if (t_ns - self._origin) % self._every_ns == 0:
            if self._outputs:
                self._put((_OUT, t_ns, signals["pressure"], signals["current"], signals["spool_position"]))
            for k, key in self._option_outputs:
                self._put((_IN, k, t_ns, signals[key]))

    def record_block(self, t0_ns: int, dt_ns: int, rows: np.ndarray) -> None:
        """Steps t0_ns, t0_ns + dt_ns, ... with their outputs (rows: pressure, current,
        spool_position) and the inputs of the last call unchanged: the device's stretch of steps
        in one call (`ValveDevice` uses it when the recorder is called at every step); the
        outputs on the grid are written as `__call__` would."""
        if not self._outputs or not len(rows):
            return
        if self._origin is None:                  # no start(): the grid starts here
            self._origin = t0_ns
        every = self._every_ns // dt_ns if self._every_ns % dt_ns == 0 else 0
        if every == 1:
            self._put((_BLOCK, t0_ns, dt_ns, rows))
        elif every > 1:                           # the rows on the output grid: every `every`-th
            j = -((t0_ns - self._origin) // dt_ns) % every
            if j < len(rows):
                self._put((_BLOCK, t0_ns + j * dt_ns, every * dt_ns, rows[j::every]))
        else:                                     # a grid that is not a whole number of steps
            t = t0_ns + dt_ns * np.arange(len(rows), dtype=np.int64)
            on = (t - self._origin) % self._every_ns == 0
            for k in np.flatnonzero(on):
                self._put((_OUT, int(t[k]), float(rows[k, 0]), float(rows[k, 1]), float(rows[k, 2])))

    def fault_command(self, t_ns: int, text: str) -> None:
        """A fault command that acted at ``t_ns`` (the command as given), with ``faults`` on."""
        if self._origin is not None and self.faults_topic is not None:
            self._put((_TEXT, self.faults_topic, t_ns, text))

    # --- the writer's side ------------------------------------------------------------------

    def _count(self, item: tuple[Any, ...]) -> int:
        if item[0] == _BLOCK:
            return len(item[3]) * self._per_output
        return 1 if item[0] == _IN else self._per_output

    def _write(self, item: tuple[Any, ...]) -> None:
        w = self._bag
        if item[0] == _OUT:
            _, t, p, i, x = item
            t = int(t)
            if self._p_topic is not None:
                w.write_fluid_pressure(self._p_topic, t, p, 0.0, self.frame_id)
            if self._i_topic is not None:
                w.write_float64(self._i_topic, t, i)
            if self._x_topic is not None:
                w.write_float64(self._x_topic, t, x)
        elif item[0] == _TEXT:
            _, topic, t, text = item
            w.write(topic, int(t), {"data": text})
        else:
            _, k, t, v = item
            k, t = int(k), int(t)
            if k < len(INPUT_ROLES) and INPUT_ROLES[k] == SUPPLY_PRESSURE:
                w.write_fluid_pressure(self._input_topics[k], t, v, 0.0, self.frame_id)
            else:
                w.write_float64(self._input_topics[k], t, v)

    def _write_batch(self, items: list[tuple[Any, ...]]) -> None:
        """Inputs message by message, the output samples as whole arrays
        (``BagWriter.write_samples``, ~0.1 µs per message), so the writer holds the interpreter
        lock for a small fraction of the time."""
        outputs = []
        for item in items:
            if item[0] == _OUT:
                outputs.append(item)
            elif item[0] == _BLOCK:
                _, t0, dt, rows = item
                outputs.extend(zip(itertools.repeat(_OUT), range(t0, t0 + dt * len(rows), dt), *rows.T.tolist()))
            else:
                self._guarded(self._write, item, 1)
        if not outputs:
            return
        if self._error:
            self._dropped += len(outputs) * self._per_output
            return
        for k in range(0, len(outputs), _SLICE):   # slices, so that a backlog still ends chunks on time
            part = outputs[k:k + _SLICE]
            if self._error:
                self._dropped += len(part) * self._per_output
                continue
            _, t, p, i, x = zip(*part)
            columns = {topic: values for topic, values in ((self._p_topic, p), (self._i_topic, i),
                                                           (self._x_topic, x)) if topic is not None}
            try:
                self._bag.write_samples(np.array(t, dtype=np.int64), columns, frame_id=self.frame_id)
            except (BagError, OSError) as exc:
                self._fail(exc)
                self._dropped += len(part) * self._per_output


def _normal_scheduling() -> None:
    """The writer thread never runs under SCHED_FIFO, even if its creator later does."""
    with contextlib.suppress(OSError, AttributeError):
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))


