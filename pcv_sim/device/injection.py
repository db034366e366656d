"""Injected faults on a device (what a fault is and its commands: `pcv_sim.device.faults`): a
physical fault changes a valve's (or the plant's) parameters and supply, a sensor fault what
`measure` makes of a sample (`pcv_sim.device.sensors`); set and cleared at a step. No ROS.
"""

from __future__ import annotations

from pcv_sim.device.composition import Composition
from pcv_sim.device.faults import (
    CYLINDER,
    Fault,
    FaultCommand,
    FaultError,
    valve_fault_parameters,
)
from pcv_sim.io.topics import SUPPLY_PRESSURE

__all__ = ["FaultInjection"]


class FaultInjection(Composition):
    """Injecting and clearing faults on a device (see the module docstring)."""

    def _fault_command(self, command: FaultCommand) -> None:
        if command.clear:
            self.clear(command.target, command.kind)
        else:
            assert command.fault is not None     # a command that is not a clear carries its fault
            self.inject(command.fault)

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
        if fault.on_cylinder:
            return None if self.has_cylinder and fault.target == CYLINDER else (
                f"is {CYLINDER}" if self.has_cylinder else f"are none: this device has no {CYLINDER}")
        if fault.target in self.valve_names:
            return None
        return f"is the valve {self.valve_names[0]}" if len(self.valve_names) == 1 else \
            f"are the valves {', '.join(self.valve_names)}"

    def _apply_physical_faults(self, fault: Fault) -> None:
        """Re-apply every active physical fault on `fault`'s target (after one was set or cleared)."""
        if fault.on_cylinder:
            self._apply_plant_faults()
        else:
            self._apply_valve_faults(fault.target)

    def _apply_valve_faults(self, valve: str) -> None:
        """The valve's parameters and supply: healthy, then every active physical fault on it."""
        k = self.valve_names.index(valve)
        p, supply, stuck = valve_fault_parameters(
            self._healthy[k], self._supply[k],
            (f for (target, _), f in self.faults.items() if target == valve and not f.sensor))
        if stuck:
            self.sim.x[self._state_off[k] + 2] = 0.0
        self.sim.set_parameters(k, p)
        self.sim.u[self._supply_i[k]] = supply
        if self.on_input is not None:
            self.on_input(self.sim.steps, f"{self._prefix[valve]}{SUPPLY_PRESSURE}", supply)

    def _apply_plant_faults(self) -> None:
        """The plant's parameters: healthy, then every active fault on it (a device with a plant)."""
        raise FaultError("this device has no plant")
