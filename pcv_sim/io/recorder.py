"""The one generic queued bag writer, without ROS: what every recorder shares.

:class:`QueuedBag` is a recorder's machinery on top of :class:`pcv_sim.io.bag.BagWriter`: the
bag directory (never overwritten), the queue the model loop appends to, the writer thread or
process, the drop accounting, the status and the finalisation described below. What a device's
bag holds (its topics, types, stamps, and the rows of a record) is its layout, beside the device:
:mod:`pcv_sim.device.recording` (`BagLayout`, `DeviceRecorder`), for live recording and offline
writing alike. A subclass says how many messages a queued item makes (`_count`) and writes a
batch of items (`_write_batch`).

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
import math
import os
import pickle
import re
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final, Literal, Self

from pcv_sim.errors import BagError
from pcv_sim.io.bag import BagWriter, Qos
from pcv_sim.io.writer_process import STALL_TIMEOUT, WriterProcess

__all__ = [
    "SWITCH_INTERVAL",
    "WRITER_DEFAULTS",
    "QueuedBag",
    "RecorderStatus",
    "Writer",
    "WriterSettings",
    "bag_name",
]

#: Where a recorder's disk work runs (see `WriterSettings.writer`).
Writer = Literal["process", "thread", "inline"]
#: Interpreter switch interval (s) a node sets while a threaded recorder runs: the longest a
#: woken model loop waits for the writer thread to hand over the interpreter lock.
SWITCH_INTERVAL: Final = 1e-3

_SHIP_ITEMS: Final = 4096   # items per batch to the writer process at most (besides batch_period)
#: A bag directory's name: anything but a path (the nodes' record.name is stricter, its own check).
_NAME_OK: Final = re.compile(r"^[^/\x00]+$")


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
        stall_timeout: s the loop and the close wait for a writer that takes nothing (a writer
            process that is alive but stuck): then waiting ends, the messages not handed over are
            counted as dropped and the failure said; a writer making progress is waited for.
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
    stall_timeout: float = STALL_TIMEOUT
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
        if not (math.isfinite(self.stall_timeout) and self.stall_timeout > 0.0):
            msg = f"stall_timeout {self.stall_timeout!r} s: accepted is a number > 0"
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
            msg = (f"bag name {name!r}: accepted is a plain directory name, without '/' and other than "
                   f"'.' and '..' (the directory is given separately)")
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
        self.stall_timeout = writing.stall_timeout
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
                capacity=max_items * item_bytes, batch_period=batch_period, stall_timeout=writing.stall_timeout)
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
        taken, since = proc.taken, time.monotonic()
        while not proc.put(payload, len(local), count):
            if not (wait or self.when_full == "wait") or proc.failure():
                self._dropped += count
                return
            if proc.taken != taken:
                taken, since = proc.taken, time.monotonic()
            elif time.monotonic() - since > self.stall_timeout:      # alive, but it takes nothing
                proc.ring.set_error(f"the bag writer process took nothing for {self.stall_timeout:g} s")
                self._error = proc.failure()
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
        return self._status(self._writer.files, self._writer.message_count, len(self._queue), self._dropped)

    def _process_status(self) -> RecorderStatus:
        proc = self._proc
        assert proc is not None
        if not self._error:
            self._error = proc.failure()
        if self._local and (self._error or time.monotonic() >= self._ship_due) and not self._closed:
            self._ship()                         # the loop may be idle (a fault): the batch still goes
        # A writer that failed loses what it had not written: handed over, neither written nor dropped there.
        lost = max(0, proc.shipped_messages - proc.messages - proc.dropped) if self._error else 0
        queued = 0 if self._error else len(self._local) + proc.shipped - proc.taken
        return self._status(sorted(self.path.glob("*.mcap")), proc.messages, queued,
                            self._dropped + proc.dropped + lost)

    def _status(self, files: list[Path], messages: int, queued: int, dropped: int) -> RecorderStatus:
        """The status with the bag's files (their size on disk now) and these counts."""
        size = 0
        for f in files:
            with contextlib.suppress(OSError):
                size += f.stat().st_size
        state: Literal["recording", "failed", "closed"] = (
            "failed" if self._error else "closed" if self._closed else "recording")
        return RecorderStatus(state, self.path, len(files), messages, size, queued, dropped, self._error)

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
            self._thread.join(self.stall_timeout)
            if self._thread.is_alive():       # stuck in a write: the BagWriter stays the thread's, not finalized
                self._fail(BagError(f"the bag writer thread did not finish within {self.stall_timeout:g} s"))
                self._closed = True
                return self.status()
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


def _normal_scheduling() -> None:
    """The writer thread never runs under SCHED_FIFO, even if its creator later does."""
    with contextlib.suppress(OSError, AttributeError):
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))


