"""Faults of a device: what each one is, the values it takes, and how it changes the physics or
the measurements. Validated here (`parse_fault`, `parse_fault_command` for the `faults` topic's
text), a valve's parameters under its faults computed here (`valve_fault_parameters`); applied
by the devices (`pcv_sim.device.valve.ValveDevice`: one valve; `pcv_sim.rig.rig.Rig`: valves and
the cylinder), the measurements by `pcv_sim.device.sensors.Sensors`.

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
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import yaml

from pcv_sim.errors import PcvSimError
from pcv_sim.model import kernel

__all__ = ["CYLINDER", "CYLINDER_FAULTS", "SENSOR_FAULTS", "VALVE_FAULTS", "Fault", "FaultCommand", "FaultError",
           "parse_fault", "parse_fault_command", "valve_fault_parameters"]


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


# --- fault commands ------------------------------------------------------------------------------


@dataclass(frozen=True)
class FaultCommand:
    """`fault` to inject, or (`target`, `kind`) to clear."""

    clear: bool
    kind: str
    target: str
    fault: Fault | None
    text: str = ""              # the command as given (a bag's `faults` topic records it)


_TARGET_KEYS = ("valve", "signal", "target")


def parse_fault_command(text: str, *, valves: tuple[str, ...], signals: tuple[str, ...]) -> FaultCommand:
    """A validated fault command from one line of YAML; FaultError saying what is accepted.

        {fault: coil_open, valve: left}                              # a physical fault on a valve
        {fault: supply_drop, valve: right, pressure: 8.0e+6}         # with its values (SI)
        {fault: bias, signal: left.pressure, value: 1.0e+5}          # a sensor fault on a signal
        {clear: coil_open, valve: left}

    A device of one valve (the emulator) takes a valve fault without its target too:
    `{fault: coil_open}`."""
    v0 = valves[0] if valves else "left"
    example = (f"accepted is a YAML mapping such as {{fault: coil_open, valve: {v0}}} or "
               f"{{clear: coil_open, valve: {v0}}}")
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError:
        raise FaultError(f"fault command {text!r} is not YAML; {example}") from None
    if not isinstance(data, Mapping):
        raise FaultError(f"fault command {text!r}: {example}")
    actions = [k for k in ("fault", "clear") if k in data]
    if len(actions) != 1:
        raise FaultError(f"fault command {text!r}: needs exactly one of 'fault' or 'clear'; {example}")
    action = actions[0]
    targets = [k for k in _TARGET_KEYS if k in data]
    if not targets and len(valves) == 1 and data[action] not in SENSOR_FAULTS:
        data = {**data, "valve": valves[0]}        # the one valve
        targets = ["valve"]
    if len(targets) != 1:
        raise FaultError(f"fault command {text!r}: needs exactly one of 'valve' (a physical fault: "
                         f"{', '.join(valves)}) or 'signal' (a sensor fault: {', '.join(signals)})")
    kind, target = data[action], data[targets[0]]
    values = {k: v for k, v in data.items() if k not in (action, targets[0])}
    if action == "clear":
        if values:
            raise FaultError(f"fault command {text!r}: clear takes no values ({', '.join(map(str, values))})")
        # Validated as a fault with no values would be: the kind and target must exist.
        try:
            parse_fault(kind, target, None, valves=valves, signals=signals, where="clear")
        except FaultError as err:
            if "needs" not in str(err):            # a kind that takes values: those are not needed to clear it
                raise
        return FaultCommand(True, str(kind), str(target), None, text)
    fault = parse_fault(kind, target, values, valves=valves, signals=signals, where="fault")
    return FaultCommand(False, fault.kind, fault.target, fault, text)


def valve_fault_parameters(healthy: np.ndarray, supply: float, faults: Iterable[Fault]) -> tuple[np.ndarray, float, bool]:
    """A valve's kernel parameter vector and supply pressure (Pa) under its physical `faults`, from
    the healthy ones (not modified); and whether its spool is stuck (the caller then stops the
    spool: no velocity, so the continuity's A v term stops with it)."""
    p = healthy.copy()
    stuck = False
    for f in faults:
        kind = f.kind
        if kind == "supply_drop":
            supply = f.values["pressure"]
        elif kind == "supply_loss":
            supply = 0.0
        elif kind == "coil_open":
            p[kernel.VOLTAGE_FACTOR] = 0.0
        elif kind == "coil_short":
            p[kernel.R_COIL] *= f.values["resistance_factor"]
        elif kind == "spool_sticking":
            friction = f.values["friction"]
            p[kernel.SPOOL_FRICTION] = friction
            # The friction's slope at v = 0 (F / v_s) kept at most the spool's own damping:
            # a steeper one is a stiffer spool than the 0.1 ms Heun step can hold.
            p[kernel.SPOOL_FRICTION_V] = max(1e-3, friction / p[kernel.DAMPING])
        elif kind == "spool_stuck":
            p[kernel.STUCK] = 1.0
            stuck = True
        elif kind == "contamination":
            p[kernel.AREA_FACTOR] = f.values["area_factor"]
        elif kind == "internal_leakage":
            p[kernel.LEAK] = f.values["conductance"]
    return p, supply, stuck
