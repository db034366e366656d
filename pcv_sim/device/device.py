"""What every device is, whatever it composes (one valve; valves and a plant): model time and its
stamps, the queue of inputs by the step they act from and the step a received input acts from, one
watchdog per valve, and the fault state. No ROS.

`ValveDevice` (pcv_sim.device.valve, the emulator) and `Rig` (pcv_sim.rig.rig, valves on the
steering cylinder) are devices; a node adapts any device the same way (model time anchored to a
clock through `origin_ns`, inputs scheduled by `timing`, nothing published while `fault` is set,
`skip` when the loop fell behind or an external clock jumped).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from pcv_sim.device.inputs import InputQueue, InputTiming, Watchdog

__all__ = ["MODEL_FAILURES", "Device"]

#: What the model may raise when its state runs away (e.g. no coil current solves Eq. 2): a fault.
MODEL_FAILURES = (ArithmeticError, ValueError)


class Device:
    """The common part of the devices (see the module docstring); `steps` is the subclass's model
    step counter (model time = steps * dt)."""

    steps: int

    def __init__(self, dt: float, valve_names: Sequence[str], watchdog_steps: int) -> None:
        self.dt = dt
        self.dt_ns = round(dt * 1e9)
        self.origin_ns = 0                  # stamp of model time 0 (a node anchors it to its clock)
        self.timing = InputTiming(self.dt_ns)
        #: Inputs (what one is, is the device's) by the step they act from.
        self.queue: InputQueue[Any] = InputQueue()
        self.watchdogs = {name: Watchdog(watchdog_steps) for name in valve_names}
        #: Why the model stands still (it ran away): nothing is stepped or shown until a reset.
        self.fault: str | None = None
        self.fault_step: int | None = None

    @property
    def time(self) -> float:
        """Model time, s (an integer count of steps: it never drifts)."""
        return self.steps * self.dt

    def stamp_ns(self, step: int | None = None) -> int:
        """The stamp of model step `step` (default: the present one)."""
        return self.origin_ns + (self.steps if step is None else step) * self.dt_ns

    def next_due(self) -> int:
        """The first step at which a queued input or a watchdog deadline falls (`inputs.NEVER` if
        none): where a stretch of compiled steps must stop."""
        return min(self.queue.next_step, *(w.deadline for w in self.watchdogs.values()))

    def skip(self, n: int) -> None:
        """Let n steps of model time pass without computing them (the model state is held): a real-time
        loop that fell too far behind, an external clock that jumped."""
        self.steps += n

    def set_fault(self, reason: str) -> None:
        """Enter the fault state (the first reason stays until it is cleared)."""
        if self.fault is None:
            self.fault = reason
            self.fault_step = self.steps

    def clear_fault(self) -> str | None:
        """Leave the fault state; the reason it had, or None."""
        was, self.fault, self.fault_step = self.fault, None, None
        return was
