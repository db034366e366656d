"""What the node and the rig's client share instead of an executor: blocking until a message comes
without using a core (`Waiter`; the messages are then taken by `pcv_sim.node.inputs.drain`), and
a start-up error's last chance to reach /rosout."""

from __future__ import annotations

import os
import time
from collections.abc import Iterable
from typing import Any

from rclpy.exceptions import InvalidHandle

__all__ = ["ROSOUT_LINGER", "ROSOUT_LINGER_ENV", "Waiter", "linger_for_rosout"]

ROSOUT_LINGER = 3.0                          # s a node that cannot start waits for a /rosout subscriber
ROSOUT_LINGER_ENV = "PCV_SIM_ROSOUT_LINGER"  # another budget (s): discovery on a loaded machine may take longer


class Waiter:
    """Blocks until one of `subscriptions` has a message (or `timeout` s pass), without the
    interpreter lock and without using a core: an rcl wait set made once, woken by the DDS
    listener. For the one topic a lockstep waits for; the others are then taken by `drain`."""

    def __init__(self, subscriptions: Iterable[Any], context: Any) -> None:
        from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy

        self._subs = list(subscriptions)
        self._ws = _rclpy.WaitSet(len(self._subs), 0, 0, 0, 0, 0, context.handle)

    def wait(self, timeout: float) -> None:
        ws = self._ws
        ws.clear_entities()
        try:
            for sub in self._subs:
                with sub.handle:
                    ws.add_subscription(sub.handle)
            ws.wait(max(0, int(timeout * 1e9)))
        except InvalidHandle:                # destroyed during shutdown
            time.sleep(timeout)


def linger_for_rosout(node: Any) -> None:
    """Give /rosout subscribers (rqt_console, a log aggregator) the chance to get a node's last
    message before it goes: up to ROSOUT_LINGER s (or $PCV_SIM_ROSOUT_LINGER) to discover one,
    then a tenth of that, 0.5 s at least, for delivery (the rosout writer keeps its last messages
    for late joiners while it exists)."""
    try:
        linger = float(os.environ.get(ROSOUT_LINGER_ENV, ROSOUT_LINGER))
    except ValueError:
        linger = ROSOUT_LINGER
    end = time.monotonic() + linger
    while time.monotonic() < end:
        if node.count_subscribers("/rosout") > 0:
            time.sleep(max(0.5, linger / 10.0))
            return
        time.sleep(0.02)
