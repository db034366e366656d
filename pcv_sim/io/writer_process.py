"""A recorder's disk side in its own process, fed through a shared-memory ring.

Why a process. A writer *thread* shares the interpreter lock with the node's real-time loop: while
it serialises a batch (Python code between numpy calls) the loop waits for the lock when it
wakes, and on a busy machine the writer can be preempted by the kernel *while holding the lock*,
so the loop waits for a whole scheduler slice (several ms) although it has a core. A process has
its own interpreter: the node's side of recording is then the model loop appending a tuple per
item and, every ``batch_period``, one ``pickle.dumps`` of the batch (~25 µs for 200 items) copied
into shared memory. BENCHMARKS.md ("Recording") has the figures.

The pieces:

- :class:`Ring`: a byte ring in an anonymous shared memory file (``memfd``), one producer (the
  node's loop) and one consumer (the writer process). Records are a length and a pickled batch;
  the producer advances ``head`` after the bytes, the consumer ``tail`` after it has read them.
  Both counters are 8-byte aligned stores of one writer each.
- :class:`WriterProcess`: the node's handle. It starts ``python -m pcv_sim.io.writer_process``
  with the ring and a control pipe, sends it how to build the recorder's writing side
  (class and arguments; the child builds the same recorder class with ``writer="inline"``, so the
  bytes on disk are the same code's), and waits until the bag is open (or the reason it is not).
- :func:`main`: the writer process: it writes what the ring holds, one record at a time; its
  counters (items taken, messages, drops, error) live in the ring's header. It stops after the
  node's close request, and also when the control pipe reaches end of file (the node died, even
  by SIGKILL): it then writes what it had and finalizes the bag, which is complete up to the
  node's last batch. It ignores SIGINT, SIGTERM and SIGHUP and has its own process group: a
  Ctrl-C or a process group's SIGTERM reaches the node, which closes the bag after its last
  samples.

Scheduling: the writer takes only CPU that nothing else wants. It writes from a thread under
SCHED_IDLE (nice 19 where that is refused): a waking thread of normal priority, the node's loop,
preempts it at once, where a writer of normal priority made the loop wait for the rest of its
slice (BENCHMARKS.md, "Recording on a busy machine"). On a machine busy with other work it falls
behind and the ring holds the backlog. When the ring is more than HIGH_WATER full, and at close,
the process's main thread (normal priority) writes until the backlog is down to LOW_WATER (or
empty): a recording loses data only when the ring fills even so, and then the node counts every
message it could not hand over as dropped (its diagnostics go WARN, the close says how many).
The process stays in the node's session (Linux's autogroup scheduling then counts it in the
node's group, not as a group of its own).

A writer process that dies is seen by the node at its next batch or status (``failed`` with the
exit code): later items are counted as dropped, the loop never waits for it.
"""

from __future__ import annotations

import contextlib
import importlib
import mmap
import os
import pickle
import select
import signal
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Mapping
from typing import Any, Final

import numpy as np

from pcv_sim.errors import BagError

__all__ = ["Ring", "WriterProcess", "main"]

_HEADER: Final = 4096          # bytes before the data: counters, then the error text
_ERROR_AT: Final = 512
_LEN: Final = struct.Struct("<Q")
# Counter slots (int64) in the header.
_HEAD, _TAIL, _TAKEN, _MESSAGES, _DROPPED, _STATE, _ERROR_LEN = range(7)
STARTING: Final = 0
READY: Final = 1
FAILED: Final = 2              # could not open the bag, or writing failed (error text set)
CLOSED: Final = 3
#: s the node waits for the writer process to open the bag (imports of numpy, mcap, rosbags: ~0.5 s
#: on a quiet machine, several s on a busy one).
START_TIMEOUT: Final = 60.0
#: s without progress after which closing gives up on the writer process and kills it.
STALL_TIMEOUT: Final = 20.0
#: Fill of the ring (fraction) above which the writer writes at normal priority, down to LOW_WATER.
HIGH_WATER: Final = 0.5
LOW_WATER: Final = 0.25


class Ring:
    """A shared-memory byte ring of `capacity` bytes (a multiple of 8) plus a header."""

    def __init__(self, fd: int, capacity: int) -> None:
        self.fd = fd
        self.capacity = capacity
        self._map = mmap.mmap(fd, _HEADER + capacity)
        self.counters = np.frombuffer(self._map, dtype=np.int64, count=8)
        self._data = memoryview(self._map)[_HEADER:]

    @classmethod
    def create(cls, capacity: int) -> Ring:
        capacity = max(1 << 16, (capacity + 7) // 8 * 8)
        fd = os.memfd_create("pcv_sim_bag_ring", 0)       # inherited by the writer process (pass_fds)
        os.ftruncate(fd, _HEADER + capacity)
        return cls(fd, capacity)

    def free(self) -> int:
        c = self.counters
        return self.capacity - int(c[_HEAD] - c[_TAIL])

    def put(self, payload: bytes) -> bool:
        """Append one record (producer); False when it does not fit now."""
        size = _LEN.size + (len(payload) + 7) // 8 * 8
        if size > self.free():
            return False
        head = int(self.counters[_HEAD])
        self._write(head, _LEN.pack(len(payload)))
        self._write(head + _LEN.size, payload)
        self.counters[_HEAD] = head + size
        return True

    def used(self) -> int:
        """Bytes written and not yet taken."""
        c = self.counters
        return int(c[_HEAD] - c[_TAIL])

    def take_one(self) -> bytes | None:
        """The oldest record (consumer); None when there is none."""
        c = self.counters
        tail = int(c[_TAIL])
        if tail >= int(c[_HEAD]):
            return None
        (n,) = _LEN.unpack(self._read(tail, _LEN.size))
        out = self._read(tail + _LEN.size, n)
        c[_TAIL] = tail + _LEN.size + (n + 7) // 8 * 8
        return out

    def _write(self, at: int, data: bytes) -> None:
        k, n = at % self.capacity, len(data)
        first = min(n, self.capacity - k)
        self._data[k:k + first] = data[:first]
        if first < n:
            self._data[:n - first] = data[first:]

    def _read(self, at: int, n: int) -> bytes:
        k = at % self.capacity
        first = min(n, self.capacity - k)
        if first == n:
            return bytes(self._data[k:k + n])
        return bytes(self._data[k:]) + bytes(self._data[:n - first])

    @property
    def error(self) -> str:
        n = int(self.counters[_ERROR_LEN])
        return bytes(self._map[_ERROR_AT:_ERROR_AT + n]).decode("utf-8", "replace")

    def set_error(self, text: str) -> None:
        if self.counters[_ERROR_LEN]:
            return
        data = text.encode("utf-8")[:_HEADER - _ERROR_AT]
        self._map[_ERROR_AT:_ERROR_AT + len(data)] = data
        self.counters[_ERROR_LEN] = len(data)

    def close(self) -> None:
        self.counters = np.zeros(8, dtype=np.int64)      # views into the map must go before it closes
        self._data.release()
        with contextlib.suppress(BufferError):
            self._map.close()
        with contextlib.suppress(OSError):
            os.close(self.fd)


class WriterProcess:
    """The node's side: start the writer process, hand it batches, read its state, close it.

    Args:
        build: (module, class name, keyword arguments) of the recorder whose writing side the
            process runs (constructed there with ``writer="inline"``).
        capacity: Ring size in bytes: the backlog the writer may have before batches are refused.
        batch_period: s between the writer's turns.
        stall_timeout: s without progress after which closing gives up on the writer and kills it.
    """

    def __init__(self, build: tuple[str, str, Mapping[str, Any]], *, capacity: int, batch_period: float,
                 stall_timeout: float = STALL_TIMEOUT) -> None:
        self.stall_timeout = stall_timeout
        self.ring = Ring.create(capacity)
        self.shipped = 0                     # items handed over
        self.shipped_messages = 0            # the messages they make
        read_end, self._control = os.pipe()
        try:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "pcv_sim.io.writer_process", str(self.ring.fd), str(read_end),
                 str(self.ring.capacity), repr(batch_period)],
                pass_fds=(self.ring.fd, read_end), stdin=subprocess.DEVNULL, close_fds=True,
                process_group=0)      # not a session of its own: that would be a scheduling group of its own
        except OSError as exc:
            os.close(self._control)
            self.ring.close()
            msg = f"cannot start the bag writer process: {exc}"
            raise BagError(msg) from exc
        finally:
            os.close(read_end)
        spec = pickle.dumps(build, 5)
        with contextlib.suppress(OSError):       # it died already: reported below
            os.write(self._control, _LEN.pack(len(spec)) + spec)
        os.set_blocking(self._control, False)    # the loop never waits for the writer
        end = time.monotonic() + START_TIMEOUT
        while self.state == STARTING and self.proc.poll() is None and time.monotonic() < end:
            time.sleep(0.005)
        if self.state != READY:
            why = self.ring.error or (f"it exited with code {self.proc.returncode}" if self.proc.poll() is not None
                                      else f"it did not open the bag within {START_TIMEOUT:g} s")
            self.kill()
            msg = f"the bag writer process could not start: {why}"
            raise BagError(msg)

    @property
    def state(self) -> int:
        return int(self.ring.counters[_STATE])

    @property
    def taken(self) -> int:
        return int(self.ring.counters[_TAKEN])

    @property
    def messages(self) -> int:
        return int(self.ring.counters[_MESSAGES])

    @property
    def dropped(self) -> int:
        return int(self.ring.counters[_DROPPED])

    def failure(self) -> str:
        """Why the writer cannot take more ('' while it can)."""
        if self.ring.error:
            return self.ring.error
        code = self.proc.poll()
        if code is not None and self.state != CLOSED:
            return f"the bag writer process exited unexpectedly (exit code {code})"
        return ""

    def put(self, payload: bytes, items: int, messages: int) -> bool:
        """One batch of `items` items making `messages` messages; False if the ring has no room now."""
        if not self.ring.put(payload):
            return False
        self.shipped += items
        self.shipped_messages += messages
        return True

    def close(self, on_wait: Callable[[], None] | None = None) -> None:
        """Ask the writer to write what it has and finalize the bag; wait for it while it makes
        progress (at most `stall_timeout` s without), then kill it."""
        with contextlib.suppress(OSError):
            os.write(self._control, b"c")
        last, since = (-1, -1), time.monotonic()
        while self.proc.poll() is None:
            progress = (self.taken, int(self.ring.counters[_TAIL]))
            if progress != last:
                last, since = progress, time.monotonic()
            elif time.monotonic() - since > self.stall_timeout:
                self.ring.set_error(f"the bag writer process made no progress for {self.stall_timeout:g} s and was "
                                    f"killed")
                self.kill()
                break
            if on_wait is not None:
                on_wait()
            time.sleep(0.01)
        with contextlib.suppress(OSError):
            os.close(self._control)

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()
        with contextlib.suppress(OSError):
            os.close(self._control)


# --- the writer process ----------------------------------------------------------------------------


def _read_spec(fd: int) -> tuple[str, str, dict[str, Any]]:
    data = b""
    while len(data) < _LEN.size or len(data) < _LEN.size + _LEN.unpack(data[:_LEN.size])[0]:
        chunk = os.read(fd, 1 << 16)
        if not chunk:
            msg = "the node closed the control pipe before sending the recorder"
            raise BagError(msg)
        data += chunk
    n = _LEN.unpack(data[:_LEN.size])[0]
    module, name, kwargs = pickle.loads(data[_LEN.size:_LEN.size + n])
    return module, name, dict(kwargs)


def main(argv: list[str]) -> int:
    """``python -m pcv_sim.io.writer_process RING_FD CONTROL_FD CAPACITY BATCH_PERIOD``."""
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):    # the node decides when the bag ends
        signal.signal(sig, signal.SIG_IGN)
    with contextlib.suppress(OSError, AttributeError):
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))   # never SCHED_FIFO, even if the node is
    ring_fd, control, capacity, batch_period = int(argv[0]), int(argv[1]), int(argv[2]), float(argv[3])
    ring = Ring(ring_fd, capacity)
    c = ring.counters
    try:
        module, name, kwargs = _read_spec(control)
        rec = getattr(importlib.import_module(module), name)(**kwargs)      # its WriterSettings: inline
    except Exception as exc:      # whatever stops the bag from opening is what the node reports
        ring.set_error(str(exc) if isinstance(exc, BagError) else f"{type(exc).__name__}: {exc}")
        c[_STATE] = FAILED
        return 1
    turns = _Turns(ring, rec)
    c[_STATE] = READY
    background = threading.Thread(target=turns.background, args=(batch_period,), name="bag writer (idle)", daemon=True)
    background.start()
    done = False
    while not done:
        ready, _, _ = select.select([control], [], [], batch_period)
        if ready:
            data = os.read(control, 4096)
            done = not data or b"c" in data          # end of file: the node is gone; "c": close
        if done or ring.used() > HIGH_WATER * ring.capacity:
            turns.take_over(until=0 if done else LOW_WATER * ring.capacity)
    st = rec.close()
    c[_MESSAGES], c[_DROPPED] = st.messages, st.dropped
    if st.error:
        ring.set_error(st.error)
        c[_STATE] = FAILED
        return 1
    c[_STATE] = CLOSED
    return 0


class _Turns:
    """Who writes: the background thread under SCHED_IDLE, or the main thread at normal priority
    when the ring is filling up (a machine busy for longer than the ring holds) and at close (the
    node waits for the bag). An unprivileged process cannot raise a thread's priority again, hence
    two threads. A turn is one record (one batch of the node's, ~1-2 ms of writing); the main
    thread waits for the background thread's record in progress and for the interpreter lock it
    may hold. Where the process may (root, CAP_SYS_NICE, RLIMIT_NICE) it raises the background
    thread to normal priority for that wait; otherwise, on a saturated machine, the wait takes
    seconds (the idle thread gets a slice every ~1 s or less): HIGH_WATER leaves half the ring for
    that."""

    def __init__(self, ring: Ring, rec: Any) -> None:
        self.ring, self.rec = ring, rec
        self.work = threading.Lock()
        self.go = threading.Event()       # the background thread may write
        self.go.set()
        self.tid = 0                      # the background thread's (Linux), once it runs

    def turn(self) -> bool:
        """Write the oldest record in the ring (False: there was none)."""
        payload = self.ring.take_one()
        if payload is None:
            return False
        items = pickle.loads(payload)
        self.rec.write_items(items)
        c = self.ring.counters
        c[_TAKEN] += len(items)
        st = self.rec.status()
        c[_MESSAGES], c[_DROPPED] = st.messages, st.dropped
        if st.error:
            self.ring.set_error(st.error)
            c[_STATE] = FAILED
        return True

    def background(self, batch_period: float) -> None:
        self.tid = threading.get_native_id()
        _lowest_priority()
        while True:
            self.go.wait()                # no timeout: parked without the interpreter lock while the main thread writes
            with self.work:
                wrote = self.go.is_set() and self.turn()
            if not wrote:
                time.sleep(batch_period)

    def take_over(self, until: float) -> None:
        """Write at normal priority until at most `until` bytes are waiting in the ring."""
        self.go.clear()
        # The background thread may hold `work` (a record in progress, or only looking at `go`) and,
        # under SCHED_IDLE on a busy machine, not run again for seconds: measured at close beside
        # four CPU burners, 1.5-42 s, a third of the bags killed unfinished after STALL_TIMEOUT.
        # Raised to normal priority it hands `work` over at once; where that is refused (unprivileged,
        # RLIMIT_NICE 0) it is waited for as before.
        raised = _set_policy(self.tid, os.SCHED_OTHER) if self.tid else False
        with self.work:                   # the background thread's record in progress, if any
            while self.ring.used() > until and self.turn():
                pass
        if until > 0:
            if raised:
                _set_policy(self.tid, os.SCHED_IDLE)
            self.go.set()


def _set_policy(tid: int, policy: int) -> bool:
    """Another thread's scheduling policy (priority 0); False where it is refused."""
    try:
        os.sched_setscheduler(tid, policy, os.sched_param(0))
    except (OSError, AttributeError):
        return False
    return True


def _lowest_priority() -> None:
    """This thread to SCHED_IDLE, else (refused) to nice 19."""
    try:
        os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))
    except (OSError, AttributeError):
        with contextlib.suppress(OSError):
            os.setpriority(os.PRIO_PROCESS, 0, 19)       # this thread's (Linux: per thread)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
