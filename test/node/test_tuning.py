"""The loop's process tuning that runs without ROS: the garbage collector's timer."""

from __future__ import annotations

import gc

from pcv_sim.node.tuning import GcTimer


def test_the_gc_timer_counts_each_collection_and_its_time_while_entered() -> None:
    ticks = iter(range(0, 1000, 3))             # a clock that moves 3 s a reading
    gc.disable()                                # only the two collections below
    try:
        with GcTimer(lambda: float(next(ticks))) as timer:
            assert timer in gc.callbacks
            gc.collect(0)
            gc.collect(2)
    finally:
        gc.enable()
    assert timer not in gc.callbacks
    assert timer.collections == [1, 0, 1] and timer.total == 6.0       # two collections, one reading apart each
    gc.collect()
    assert timer.collections == [1, 0, 1]
