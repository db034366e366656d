"""Process tuning for a node's loop: what makes its wakes land on time on a shared Linux machine
(1 ns timer slack, the start-up heap out of the garbage collector's reach, SCHED_FIFO on request)."""

from __future__ import annotations

import contextlib
import ctypes
import gc
import os
import time
from collections.abc import Callable
from types import TracebackType
from typing import Any

__all__ = ["GcTimer", "freeze_heap", "set_realtime_priority", "tighten_timer_slack"]


def tighten_timer_slack() -> None:
    """Ask Linux for 1 ns timer slack (default 50 us): wakes land ~50 us closer to the grid."""
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL(None, use_errno=True).prctl(29, 1, 0, 0, 0)   # PR_SET_TIMERSLACK


def freeze_heap() -> None:
    """Move everything allocated so far (rclpy, numpy, scipy, the model: ~50 000 objects) out of
    the garbage collector's reach. A full collection over them takes ~17 ms here, which would
    make a wake-up that many ms late; the loop itself only makes short-lived objects."""
    gc.collect()
    gc.freeze()


def set_realtime_priority(priority: int, logger: Any) -> None:
    """The calling thread under SCHED_FIFO at `priority`; refused (no rtprio limit): said, and the loop
    runs with normal scheduling."""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except (OSError, AttributeError) as err:
        logger.warning(f"realtime_priority {priority}: SCHED_FIFO refused ({err}); running with "
                       "normal scheduling (grant an rtprio limit or run as root)")
    else:
        logger.info(f"loop thread under SCHED_FIFO, priority {priority}")


class GcTimer:
    """The wall time the garbage collector took (`gc.callbacks`, while entered as a context): a
    loop reads `total` before and after a wake to see a collection's share of it."""

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        self.clock = clock
        self.total = 0.0                # s, every collection since entered
        self.collections = [0, 0, 0]    # per generation
        self._t0 = 0.0

    def __call__(self, phase: str, info: dict[str, Any]) -> None:
        if phase == "start":
            self._t0 = self.clock()
        else:
            self.total += self.clock() - self._t0
            self.collections[info["generation"]] += 1

    def __enter__(self) -> GcTimer:
        gc.callbacks.append(self)
        return self

    def __exit__(self, kind: type[BaseException] | None, err: BaseException | None, tb: TracebackType | None) -> None:
        if self in gc.callbacks:
            gc.callbacks.remove(self)
