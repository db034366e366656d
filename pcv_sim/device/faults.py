"""Faults of a device: what each one is, the values it takes, and how it changes the physics or
the measurements. Each kind is declared here (`FaultKind`: what it acts on, one line of doc, and
the dataclass that declares its values with `pcv_sim.params.parameter`: unit, plausible range,
one line of doc); every check of a fault's values and every message about them comes from those
declarations (`parse_fault`; `parse_fault_command` for the `faults` topic's text), so a value
takes a unit ("80 bar", "2 %") wherever faults are given, a bare number being SI.
`fault_table` prints them for docs/files.md. A valve's parameters under its faults are computed
here (`valve_fault_parameters`); the faults are applied by the device
(`pcv_sim.device.device.Device`), the measurements by `pcv_sim.device.sensors.Sensors`.

How the physical ones act (on a valve, through its kernel parameter vector or its supply input;
clearing one restores the healthy value): coil_open leaves no drive voltage, so the flux
linkage decays through the coil resistance (time constant L/R), the current to 0, the pressure
falls; spool_sticking adds Coulomb friction F tanh(v / v_s). On the cylinder: cylinder_friction
is F tanh(v / v_s) against the motion with v_s at least F dt / m (a steeper slope at v = 0 than
the step can hold); under cylinder_jam the chambers keep their volumes, so the valves then hold
pressure against it. Sensor faults change what the controller and the recording see, never
the physics; noise is seeded, so a run repeats bit for bit.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import yaml

from pcv_sim.device.spec import signal_kind
from pcv_sim.errors import ParameterError, PcvSimError
from pcv_sim.io.topics import CYLINDER  # the plant's target name, the one target of CYLINDER_FAULTS
from pcv_sim.keys import closest, unknown_message
from pcv_sim.model import kernel
from pcv_sim.params import any_value, at_least, between, declarations, key_cells, parameter, read

__all__ = ["CYLINDER", "CYLINDER_FAULTS", "FAULT_KINDS", "SENSOR_FAULTS", "VALVE_FAULTS", "Fault", "FaultCommand",
           "FaultError", "FaultKind", "fault_kind", "fault_table", "fault_value_kind", "parse_fault",
           "parse_fault_command", "valve_fault_parameters"]


class FaultError(PcvSimError, ValueError):
    """A fault that does not exist, on a target that does not exist, or with values out of range."""


@dataclass(frozen=True)
class FaultKind:
    """One kind of fault: what it acts on (`on`: a valve, the cylinder or a measured signal), one
    line of doc, and the dataclass declaring its values (None: it takes none)."""

    on: str
    doc: str
    values: type | None = None


# --- the values of each kind, declared once (pcv_sim.params) --------------------------------------
# A sensor fault's values are in its signal's unit (kind "value": the signal's kind, by its name),
# as differences of it: a bias of 2 degC is 2 K, and a small one is no unit slip.


@dataclass(frozen=True, kw_only=True)
class SupplyDrop:
    pressure: float = parameter("Pa", "the supply pressure under the fault",
                                between(0.0, 400e5, "a supply pressure"), kind="pressure", role="supply pressure")


@dataclass(frozen=True, kw_only=True)
class CoilShort:
    resistance_factor: float = parameter("-", "the factor on the coil resistance",
                                         between(0.0, 1.0, "a factor", above=True), kind="fraction",
                                         role="resistance factor")


@dataclass(frozen=True, kw_only=True)
class SpoolSticking:
    friction: float = parameter("N", "the extra Coulomb friction on the spool, F tanh(v / v_s)",
                                between(0.0, 100.0, "a friction force", above=True), kind="force")


@dataclass(frozen=True, kw_only=True)
class Contamination:
    area_factor: float = parameter("-", "the factor on the metering edges' area",
                                   between(0.0, 1.0, "a factor", above=True), kind="fraction", role="area factor")


@dataclass(frozen=True, kw_only=True)
class InternalLeakage:
    conductance: float = parameter("m^3/(s Pa)", "its laminar conductance: q = conductance (p - p_t)",
                                   between(0.0, 1e-9, "a conductance", above=True), kind="conductance")


@dataclass(frozen=True, kw_only=True)
class CylinderFriction:
    friction: float = parameter("N", "the seals' Coulomb friction instead of the configured one",
                                between(0.0, 1e5, "a friction force"), kind="force")


@dataclass(frozen=True, kw_only=True)
class Bias:
    value: float = parameter("the signal's unit", "the offset", any_value, kind="value", difference=True)


@dataclass(frozen=True, kw_only=True)
class Drift:
    rate: float = parameter("the signal's unit/s", "the offset's growth per second", any_value,
                            kind="value", rate=True)


@dataclass(frozen=True, kw_only=True)
class Noise:
    std: float = parameter("the signal's unit", "its standard deviation",
                           at_least(0.0, "a standard deviation", strict=True), kind="value", difference=True)


@dataclass(frozen=True, kw_only=True)
class Delay:
    delay: float = parameter("s", "how late (rounded up to whole control periods)",
                             between(0.0, 10.0, "a delay", above=True), kind="time")


#: What a fault acts on (`FaultKind.on`): a valve, the cylinder (`CYLINDER`) or a measured signal.
VALVE, SIGNAL = "valve", "signal"

VALVE_FAULTS: dict[str, FaultKind] = {
    "supply_drop": FaultKind(VALVE, "the supply pressure falls", SupplyDrop),
    "supply_loss": FaultKind(VALVE, "the supply pressure falls to 0 (tank): the pump is gone"),
    "coil_open": FaultKind(VALVE, "coil open circuit: no drive voltage, the current decays to 0"),
    "coil_short": FaultKind(VALVE, "a partial short of the coil", CoilShort),
    "spool_sticking": FaultKind(VALVE, "the spool sticks", SpoolSticking),
    "spool_stuck": FaultKind(VALVE, "the spool is held where it is"),
    "contamination": FaultKind(VALVE, "contaminated metering edges", Contamination),
    "internal_leakage": FaultKind(VALVE, "a leak from the load port to tank", InternalLeakage),
}
CYLINDER_FAULTS: dict[str, FaultKind] = {
    "cylinder_friction": FaultKind(CYLINDER, "worn or dry seals, a binding linkage", CylinderFriction),
    "cylinder_jam": FaultKind(CYLINDER, "a seized linkage, a blocked wheel: the piston is held where it is"),
}
SENSOR_FAULTS: dict[str, FaultKind] = {
    "bias": FaultKind(SIGNAL, "an offset on the measurement", Bias),
    "drift": FaultKind(SIGNAL, "an offset growing from the fault's start", Drift),
    "freeze": FaultKind(SIGNAL, "the value at the fault's start, held"),
    "noise": FaultKind(SIGNAL, "Gaussian noise on the measurement (seeded: a run repeats bit for bit)", Noise),
    "dropout": FaultKind(SIGNAL, "no sample at all (the controller's measurement lacks the key; the bag has no "
                                 "message)"),
    "delay": FaultKind(SIGNAL, "the measurement shown late", Delay),
}
#: Every kind by its name.
FAULT_KINDS: dict[str, FaultKind] = {**VALVE_FAULTS, **CYLINDER_FAULTS, **SENSOR_FAULTS}


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


def fault_kind(kind: Any, target: Any, *, valves: tuple[str, ...], signals: tuple[str, ...],
               where: str = "fault") -> FaultKind:
    """The declaration of `kind`, checked to act on `target`; FaultError naming `where` and what
    is accepted otherwise (a clear needs no more)."""
    spec = FAULT_KINDS.get(kind) if isinstance(kind, str) else None
    if spec is None:
        near = closest(kind, FAULT_KINDS)
        raise FaultError(f"{where}: kind {kind!r}; accepted are {', '.join(VALVE_FAULTS)} (on a valve), "
                         f"{', '.join(CYLINDER_FAULTS)} (on the {CYLINDER}) and "
                         f"{', '.join(SENSOR_FAULTS)} (on a measured signal)"
                         + (f" (did you mean {near!r}?)" if near else ""))
    targets = valves if spec.on == VALVE else (CYLINDER,) if spec.on == CYLINDER else signals
    if target not in targets:
        raise FaultError(f"{where}: target {target!r} for {kind}; accepted are {', '.join(targets)}")
    return spec


def parse_fault(kind: Any, target: Any, values: Mapping[str, Any] | None, *, valves: tuple[str, ...],
                signals: tuple[str, ...], where: str = "fault", path: str | None = None) -> Fault:
    """A validated Fault, its values in SI (a bare number, or a value with a unit: "80 bar"; a
    sensor fault's in its signal's unit); FaultError naming `where` (the kind and target) or
    `path` (the values: `path.name`; default `where: kind`) and what is accepted otherwise."""
    spec = fault_kind(kind, target, valves=valves, signals=signals, where=where)
    prefix = f"{where}: {kind}" if path is None else path
    given = dict(values or {})
    if spec.values is None:
        if given:
            raise FaultError(f"{prefix}: takes no values (got {', '.join(map(str, given))})")
        return Fault(kind, str(target), {})
    of = signal_kind(str(target)) if spec.on == SIGNAL else None
    unknown = unknown_message(prefix, given, declarations(spec.values))
    if unknown:
        raise FaultError(unknown)
    try:
        out = {name: float(read(spec.values, given, name, prefix, of=of)) for name in declarations(spec.values)}
    except ParameterError as err:
        raise FaultError(str(err)) from None
    return Fault(kind, str(target), out)


def fault_value_kind(kind: str, name: str, target: str) -> tuple[str, bool, bool]:
    """The units kind (`pcv_sim.units.KINDS`) of the value `name` of a fault `kind` on `target` (a
    sensor fault's: its signal's), whether it is that kind per second (a drift's rate) and whether
    it is a difference of it (a bias: no unit's zero applies)."""
    cls = FAULT_KINDS[kind].values
    meta = declarations(cls)[name].metadata if cls is not None else {"kind": "number"}
    rate = bool(meta.get("rate"))
    return (signal_kind(target) if meta["kind"] == "value" else meta["kind"]), rate, \
        rate or bool(meta.get("difference"))


def fault_table() -> str:
    """Every fault kind and its values as a Markdown table (fault, on, value, unit, accepted,
    meaning): docs/files.md's table of faults is this, and a test holds it equal."""
    on = {VALVE: "a valve", CYLINDER: f"the {CYLINDER}", SIGNAL: "a measured signal"}
    rows = ["| fault | on | value | unit | accepted | meaning |", "|---|---|---|---|---|---|"]
    for name, spec in FAULT_KINDS.items():
        cells = key_cells(spec.values) if spec.values is not None else [("", "", "", "", "")]
        for key, unit, accepted, _default, doc in cells:
            value = f"`{key}`" if key else ""
            meaning = spec.doc.replace("|", "\\|") + (f"; `{key}`: {doc}" if key else "")
            rows.append(f"| `{name}` | {on[spec.on]} | {value} | {unit} | {accepted} | {meaning} |")
    return "\n".join(rows)


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
        {fault: supply_drop, valve: right, pressure: 80 bar}         # with its values (SI or a unit)
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
        fault_kind(kind, target, valves=valves, signals=signals, where="clear")    # its values: not needed
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
