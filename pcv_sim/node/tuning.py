"""Process tuning for a node's loop: what makes its wakes land on time on a shared Linux machine
(1 ns timer slack, the start-up heap out of the garbage collector's reach, SCHED_FIFO on request)."""

from __future__ import annotations

import contextlib
import ctypes
import gc
import os
from typing import Any

__all__ = ["freeze_heap", "set_realtime_priority", "tighten_timer_slack"]


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
