"""What every device is, whatever it composes (one valve; valves and a plant): model time and its
stamps, the queue of inputs by the step they act from and the step a received input acts from, one
watchdog per valve, the fault state, and the injected faults (`pcv_sim.device.faults`: physical
ones through the subclass's parameters, sensor faults through its `sensors`). No ROS.

`ValveDevice` (pcv_sim.device.valve, the emulator) and `Rig` (pcv_sim.rig.rig, valves on the
steering cylinder) are devices; a node adapts any device the same way (model time anchored to a
clock through `origin_ns`, inputs scheduled by `timing`, nothing published while `fault` is set,
`skip` when the loop fell behind or an external clock jumped).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from pcv_sim.device.faults import Fault, FaultError
from pcv_sim.device.inputs import InputQueue, InputTiming, Watchdog
from pcv_sim.device.sensors import Sensors

__all__ = ["MODEL_FAILURES", "Device"]

#: What the model may raise when its state runs away (e.g. no coil current solves Eq. 2): a fault.
MODEL_FAILURES = (ArithmeticError, ValueError)


class Device:
    """The common part of the devices (see the module docstring); `steps` is the subclass's model
    step counter (model time = steps * dt)."""

    steps: int
    #: The device's parameters (its YAML: a valve's, a rig's), set by the subclass.
    params: Any
    #: Active faults by (target, kind), and the sensors the sensor faults act on (set by the subclass).
    faults: dict[tuple[str, str], Fault]
    sensors: Sensors

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

    # --- injected faults ---------------------------------------------------------------------

    def inject(self, fault: Fault) -> None:
        """Start `fault` at the present step (a second fault of the same kind on the same target
        replaces the first); FaultError for a target this device does not have."""
        if fault.sensor:
            if fault.target not in self.sensors.signals:
                raise FaultError(f"sensor fault on {fault.target!r}: accepted are {', '.join(self.sensors.signals)}")
            self.sensors.add(fault, self.time)
        elif (accepted := self._fault_targets(fault)) is not None:
            raise FaultError(f"{fault.kind} on {fault.target!r}: accepted {accepted}")
        self.faults[fault.key] = fault
        if not fault.sensor:
            self._apply_physical_faults(fault)
        self._note(f"fault {fault.kind} on {fault.target} {dict(fault.values) or ''}".rstrip())

    def clear(self, target: str, kind: str) -> None:
        """End a fault: the target is back to normal from the present step on."""
        fault = self.faults.pop((target, kind), None)
        if fault is None:
            active = ", ".join(f"{k}@{t}" for t, k in self.faults) or "none"
            raise FaultError(f"no active fault {kind} on {target}; active: {active}")
        if fault.sensor:
            self.sensors.clear(target, kind)
        else:
            self._apply_physical_faults(fault)
        self._note(f"cleared {kind} on {target}")

    def _fault_targets(self, fault: Fault) -> str | None:
        """What a physical fault's target may be, when `fault`'s is not one (None: it is)."""
        raise NotImplementedError

    def _apply_physical_faults(self, fault: Fault) -> None:
        """Re-apply every active physical fault on `fault`'s target (after one was set or cleared)."""
        raise NotImplementedError

    def _note(self, text: str) -> None:
        """A fault set or cleared, for the device's log (none here)."""
