"""Faults of the rig: what each one is, the values it takes, and how it changes the physics or
the measurements. Validated here (`parse_fault`), applied by `pcv_sim.rig.rig.Rig`.

Physical faults (on a valve, through its kernel parameter vector or its supply input; clearing
one restores the healthy value):

    supply_drop        supply pressure -> `pressure` (Pa, 0 .. the configured supply)
    supply_loss        supply pressure -> 0 (tank): the pump is gone
    coil_open          coil open circuit: no drive voltage, the flux linkage decays through the
                       coil resistance (time constant L/R), the current to 0, the pressure falls
    coil_short         partial short: the coil resistance times `resistance_factor` (0 < f < 1)
    spool_sticking     extra Coulomb friction `friction` (N) on the spool, F tanh(v / v_s)
    spool_stuck        the spool is held where it is
    contamination      metering edges' area times `area_factor` (0 < f <= 1)
    internal_leakage   a laminar leak load -> tank, q = `conductance` (p - p_t) (m^3/(s Pa))

Cylinder faults (target `cylinder`: the steering linkage):

    cylinder_friction  the seals' Coulomb friction is `friction` (N) instead of the configured one
                       (worn or dry seals, a binding linkage): F tanh(v / v_s) against the motion,
                       v_s at least F dt / m (a steeper slope at v = 0 than the step can hold)
    cylinder_jam       the piston is held where it is (a seized linkage, a blocked wheel); the
                       chambers keep their volumes, so the valves then hold pressure against it

Sensor faults (on one measured signal, `valve.pressure`, `cylinder.position`...: what the
controller and the recording see; the physics is untouched):

    bias      + `value` (the signal's SI unit)
    drift     + `rate` (unit/s) times the time since the fault started
    freeze    the value at the fault's start, held
    noise     + Gaussian noise of standard deviation `std` (seeded: a run repeats bit for bit)
    dropout   no sample at all (the controller's measurement lacks the key; the bag has no message)
    delay     the value of `delay` s before (a whole number of control periods, rounded up)
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from pcv_sim.errors import PcvSimError

__all__ = ["CYLINDER", "CYLINDER_FAULTS", "SENSOR_FAULTS", "VALVE_FAULTS", "Fault", "FaultError", "parse_fault"]


class FaultError(PcvSimError, ValueError):
    """A fault that does not exist, on a target that does not exist, or with values out of range."""


#: kind -> {value name: (lo, hi, unit)}; lo exclusive when marked by a tuple's 4th element True.
VALVE_FAULTS: dict[str, dict[str, tuple[float, float, str, bool]]] = {
    "supply_drop": {"pressure": (0.0, 400e5, "Pa", False)},
    "supply_loss": {},
    "coil_open": {},
    "coil_short": {"resistance_factor": (0.0, 1.0, "-", True)},
    "spool_sticking": {"friction": (0.0, 100.0, "N", True)},
    "spool_stuck": {},
    "contamination": {"area_factor": (0.0, 1.0, "-", True)},
    "internal_leakage": {"conductance": (0.0, 1e-9, "m^3/(s Pa)", True)},
}
#: The plant's target name, the one target of CYLINDER_FAULTS.
CYLINDER = "cylinder"
CYLINDER_FAULTS: dict[str, dict[str, tuple[float, float, str, bool]]] = {
    "cylinder_friction": {"friction": (0.0, 1e5, "N", False)},
    "cylinder_jam": {},
}
SENSOR_FAULTS: dict[str, dict[str, tuple[float, float, str, bool]]] = {
    "bias": {"value": (-math.inf, math.inf, "SI unit of the signal", False)},
    "drift": {"rate": (-math.inf, math.inf, "SI unit of the signal per s", False)},
    "freeze": {},
    "noise": {"std": (0.0, math.inf, "SI unit of the signal", True)},
    "dropout": {},
    "delay": {"delay": (0.0, 10.0, "s", True)},
}


@dataclass(frozen=True)
class Fault:
    """One fault: `target` is a valve name (physical faults) or a signal `system.output` (sensor
    faults); `values` its numbers (SI)."""

    kind: str
    target: str
    values: Mapping[str, float] = field(default_factory=dict)

    @property
    def sensor(self) -> bool:
        return self.kind in SENSOR_FAULTS

    @property
    def on_cylinder(self) -> bool:
        return self.kind in CYLINDER_FAULTS

    @property
    def key(self) -> tuple[str, str]:
        return (self.target, self.kind)


def parse_fault(kind: Any, target: Any, values: Mapping[str, Any] | None, *, valves: tuple[str, ...],
                signals: tuple[str, ...], where: str = "fault") -> Fault:
    """A validated Fault; FaultError naming `where` and what is accepted otherwise."""
    table = (VALVE_FAULTS if kind in VALVE_FAULTS else CYLINDER_FAULTS if kind in CYLINDER_FAULTS
             else SENSOR_FAULTS if kind in SENSOR_FAULTS else None)
    if table is None:
        raise FaultError(f"{where}: kind {kind!r}; accepted are {', '.join(VALVE_FAULTS)} (on a valve), "
                         f"{', '.join(CYLINDER_FAULTS)} (on the {CYLINDER}) and "
                         f"{', '.join(SENSOR_FAULTS)} (on a measured signal)")
    targets = valves if table is VALVE_FAULTS else (CYLINDER,) if table is CYLINDER_FAULTS else signals
    if target not in targets:
        raise FaultError(f"{where}: target {target!r} for {kind}; accepted are {', '.join(targets)}")
    spec = table[kind]
    values = dict(values or {})
    unknown = sorted(set(values) - set(spec))
    if unknown:
        raise FaultError(f"{where}: {kind} takes no {', '.join(unknown)}; accepted: {', '.join(spec) or 'no values'}")
    out: dict[str, float] = {}
    for name, (lo, hi, unit, open_lo) in spec.items():
        if name not in values:
            raise FaultError(f"{where}: {kind} needs {name} ({unit})")
        v = values[name]
        ok = not isinstance(v, bool) and isinstance(v, (int, float)) and math.isfinite(v)
        ok = ok and (lo < v if open_lo else lo <= v) and v <= hi
        if not ok:
            rng = f"{'>' if open_lo else '>='} {lo:g}" + (f" and <= {hi:g}" if math.isfinite(hi) else "")
            raise FaultError(f"{where}: {kind}.{name} = {v!r}; accepted is a finite number {rng} ({unit})")
        out[name] = float(v)
    return Fault(str(kind), str(target), out)
