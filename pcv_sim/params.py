"""Typed, validated valve parameters, loaded from `config/*.yaml`; the one parameter mechanism.

Every parameter set of the package (the valve YAML, the plants, the rig, the node settings) is a
frozen dataclass whose fields are declared with `parameter` (or its two shorthands: `setting` for
a node setting, `_param` for a valve YAML key): type (`kind`), unit, check (a plausible range,
a choice...), default and one line of doc, in one declaration. `check_value` converts and checks
a value from that declaration, `section_from_mapping` a whole section; the checks below
(`positive`, `fraction`, `plausible_range`, `one_of`, ...) are the ones every set uses.

One frozen dataclass per section of the valve YAML file. Each field carries its unit, its source and
the check that makes it physical; `load_params` refuses unknown keys, wrong types and
non-physical values with a message naming the key and what is accepted.

The same declarations serve the ROS node: its settings (`pcv_sim.device.settings.NodeSettings`)
are fields declared with `setting(default, unit, description, check, ...)`, and every value, a
valve YAML key, a `model.*` ROS parameter or a node setting, is converted and checked by
`check_value` from its field's metadata. The node names model keys `model.<section>.<key>`
(`prefix=` of `params_from_mapping`), so the messages name the parameter as the user wrote it.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ParamSpec, TypeVar

import yaml

from pcv_sim.errors import ParameterError, PcvSimError
from pcv_sim.keys import unknown_message
from pcv_sim.units import KINDS, quantity, si_kind

__all__ = [
    "DEFAULT_CONFIG",
    "CalibrationParams",
    "CircuitParams",
    "CommandParams",
    "DampingParams",
    "FitParams",
    "FluidParams",
    "OrificeParams",
    "SimulationParams",
    "SolenoidParams",
    "SpoolParams",
    "ValveParams",
    "WatchdogParams",
    "accepted_words",
    "any_value",
    "at_least",
    "between",
    "check_field",
    "check_mapping",
    "check_si",
    "check_value",
    "declarations",
    "default_params",
    "duty_fraction",
    "fraction",
    "int_range",
    "key_cells",
    "key_table",
    "load_params",
    "non_empty",
    "non_negative",
    "one_of",
    "parameter",
    "params_from_mapping",
    "params_to_mapping",
    "plausible_range",
    "positive",
    "read",
    "read_yaml",
    "refused_as",
    "replace_param",
    "section_from_mapping",
    "setting",
    "speed_factor",
    "watchdog_parameter",
    "yaml_load_unique",
]

T = TypeVar("T")
R = TypeVar("R")
P = ParamSpec("P")

DEFAULT_CONFIG = Path(__file__).resolve().parent.parent / "config" / "valve.yaml"


def _installed_default() -> Path:
    """The default YAML, from the source tree or an ament install (share/pcv_sim/config)."""
    if DEFAULT_CONFIG.is_file():
        return DEFAULT_CONFIG
    try:
        from ament_index_python.packages import get_package_share_directory

        return Path(get_package_share_directory("pcv_sim")) / "config" / "valve.yaml"
    except Exception:
        return DEFAULT_CONFIG


# --- checks: each returns None when fine, else the text "what is accepted" -------------------

Check = Callable[[Any], "str | None"]


def positive(v: float) -> str | None:
    return None if v > 0 else "a finite number > 0"


def non_negative(v: float) -> str | None:
    return None if v >= 0 else "a finite number >= 0"


positive.accepted = "> 0"           # type: ignore[attr-defined]  # for the tables of keys
non_negative.accepted = ">= 0"      # type: ignore[attr-defined]  # for the tables of keys


def any_value(_v: Any) -> str | None:
    """No check beyond the kind's (a finite number, a string, a bool...)."""
    return None


def fraction(v: float) -> str | None:
    return None if 0.0 <= v <= 1.0 else "a fraction 0..1"


def duty_fraction(v: float) -> str | None:
    return None if 0.0 <= v <= 1.0 else "a duty fraction 0..1"


fraction.lo = duty_fraction.lo = 0.0     # type: ignore[attr-defined]  # the range, for the tables of keys
fraction.hi = duty_fraction.hi = 1.0     # type: ignore[attr-defined]


def int_range(lo: int, hi: int, accepted: str | None = None) -> Check:
    """An integer lo..hi (inclusive); `accepted`: the message's words for it, if not 'an integer lo..hi'."""

    def check(v: int) -> str | None:
        return None if lo <= v <= hi else (accepted or f"an integer {lo}..{hi}")

    check.lo, check.hi = lo, hi  # type: ignore[attr-defined]  # the range, for the tables of keys
    return check


def between(lo: float, hi: float, what: str = "a value", *, above: bool = False) -> Check:
    """lo <= value <= hi (inclusive), in the message's words `what` ("a duration", "a position");
    `above`: lo < value <= hi (a factor that 0 would make a different fault)."""
    if above:

        def above_lo(v: float) -> str | None:
            return None if lo < v <= hi else f"{what} > {lo:g} and <= {hi:g}"

        above_lo.accepted = f"> {lo:g} and <= {hi:g}"  # type: ignore[attr-defined]  # for the tables of keys
        return above_lo

    def check(v: float) -> str | None:
        return None if lo <= v <= hi else f"{what} in {lo:g} .. {hi:g}"

    check.lo, check.hi = lo, hi  # type: ignore[attr-defined]  # the range, for the tables of keys
    return check


def at_least(lo: float, what: str = "a value", *, strict: bool = False) -> Check:
    """value >= lo (> lo when `strict`), in the message's words `what`."""

    def check(v: float) -> str | None:
        return None if (v > lo if strict else v >= lo) else f"{what} {'>' if strict else '>='} {lo:g}"

    check.accepted = f"{'>' if strict else '>='} {lo:g}"  # type: ignore[attr-defined]  # for the tables of keys
    return check


def non_empty(v: Any) -> str | None:
    """A list or mapping with at least one entry (a string with at least one character)."""
    return None if len(v) else ("a non-empty string" if isinstance(v, str) else "at least one entry")


def speed_factor(name: str, v: Any) -> float:
    """Converter of a real-time factor: a number >= 0, where 0 and inf both mean as fast as possible."""
    if isinstance(v, bool) or not isinstance(v, (int, float)) or math.isnan(v) or v < 0.0:
        raise ParameterError(f"{name}: got {v!r}; accepted is a number >= 0 (0 or inf: as fast as possible)")
    return float(v)


# The valve sections' names for the same checks.
_positive, _non_negative, _any_finite = positive, non_negative, any_value


def _fraction(v: float) -> str | None:
    return None if 0.0 <= v <= 1.0 else "a fraction in 0..1"


def _range(lo: float, hi: float) -> Check:
    """A plausible physical range for a valve of this class (a small solenoid proportional valve on
    a mobile hydraulic circuit), wide around the paper's values: beyond it the model means
    nothing (e.g. a 1e-12 m^3 load volume makes it diverge), so it is refused, not run."""

    def check(v: float) -> str | None:
        return None if lo <= v <= hi else f"a plausible value {lo:g} .. {hi:g}"

    check.lo, check.hi = lo, hi  # type: ignore[attr-defined]  # the range, for default fit bounds
    return check


#: The plausible-range check by its public name (every parameter set's ranges).
plausible_range = _range


def one_of(*choices: str) -> Check:
    def check(v: str) -> str | None:
        return None if v in choices else "one of " + ", ".join(repr(c) for c in choices)

    check.accepted = " \\| ".join(choices)  # type: ignore[attr-defined]  # for the tables of keys
    return check


_one_of = one_of


def parameter(unit: str, doc: str, check: Check = any_value, *, kind: str = "float", default: Any = dataclasses.MISSING,
              source: str = "", name: str | None = None, read_only: bool = False,
              convert: Callable[[str, Any], Any] | None = None, item: Any = None, section: type | None = None,
              role: str = "", difference: bool = False, rate: bool = False) -> Any:
    """One parameter, declared once: its unit, one line of doc, its check (a plausible range, a
    choice...), its type (`kind`) and its default (none: required). `source`: where the value
    comes from (the paper's table or section); `name`: the parameter's name if not the field's
    (`record.enabled`, `from`); `read_only`: a node setting that cannot change while the node runs;
    `convert`: a converter `(name, value) -> value` raising ParameterError, for values no kind
    describes.

    Kinds: float, int, str, bool, float_or_null, float_or_equivalent, vectorN, matrix4x4,
    matrixNx3; a kind of `pcv_sim.units.KINDS` (time, pressure, length, fraction...): a bare SI
    number or a value with a unit ("20 ms"), read by `units.quantity` (`role` words its hint for
    a bare number of the wrong size; `difference`: an amplitude, to which degC's zero does not
    apply); value: the same with the kind the loader names (`of=` of
    `check_value`: a profile's quantity, an assertion's signal's; `rate`: that kind per second, a
    drift's "0.5 bar/s"); list and mapping (each entry
    checked as `item`, a declaration, when given); section: a mapping of the keys declared by the
    dataclass `section`; any: taken as written (the loader checks it)."""
    return field(default=default, metadata={"unit": unit, "source": source or doc, "description": doc,
                                            "check": check, "kind": kind, "name": name, "read_only": read_only,
                                            "convert": convert, "role": role, "section": section,
                                            "difference": difference, "rate": rate,
                                            "item": item.metadata if isinstance(item, dataclasses.Field) else item})


def _param(unit: str, source: str, check: Check = _any_finite, kind: str = "float", default: Any = dataclasses.MISSING) -> Any:
    """A valve YAML key (`parameter` with the paper's source as its doc). Required, unless it has a
    `default` (keys added after files were written: an older YAML without them still loads)."""
    return parameter(unit, "", check, kind=kind, default=default, source=source)


def setting(default: Any, unit: str, description: str, check: Check = _any_finite, kind: str = "float", *,
            name: str | None = None, read_only: bool = False,
            convert: Callable[[str, Any], Any] | None = None) -> Any:
    """A node setting: `parameter` with its default first (every setting has one)."""
    return parameter(unit, description, check, kind=kind, default=default, name=name, read_only=read_only,
                     convert=convert)


@dataclass(frozen=True)
class WatchdogParams:
    """The duty watchdog every device has (the emulator's valve, each valve of a rig), declared once:
    a node's settings and the rig YAML's `rig:` take these fields (`watchdog_parameter`)."""

    watchdog_timeout: float = parameter(
        "s", "model time without a valid duty command (after the first) -> safe_duty; 0 = off. 2 s is above the "
        "1 s period of `ros2 topic pub`'s default rate", between(0.0, 60.0, "a duration"), default=2.0)
    safe_duty: float = parameter("-", "duty fraction when the watchdog fires, and before the first command of a "
                                 "valve without an initial duty (the emulator's)", duty_fraction, default=0.0)


def watchdog_parameter(key: str) -> Any:
    """A field declared as `WatchdogParams`' `key`: the same type, unit, range, default and doc."""
    f = {g.name: g for g in dataclasses.fields(WatchdogParams)}[key]
    return field(default=f.default, metadata=f.metadata)


# --- sections ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class SolenoidParams:
    """Eqs. 1-13: the flux-linkage solenoid and its force map."""

    restoring_f1: tuple[float, ...] = _param("A/Wb^3 per mm^k", "T1 p_f11..p_f16", kind="vector6")
    restoring_f2: tuple[float, ...] = _param("A/Wb^2 per mm^k", "T1 p_f21..p_f26", kind="vector6")
    restoring_f3: tuple[float, ...] = _param("A/Wb per mm^k", "T1 p_f31..p_f33", kind="vector3")
    dissipating: tuple[float, ...] = _param("A/V^k", "T1 p_d1..p_d4", kind="vector4")
    force: tuple[tuple[float, ...], ...] = _param("N/A^k per mm^j", "T1 p_fs11..p_fs44", kind="matrix4x4")
    core_offset_mm: float = _param("mm", "R2", _range(0.0, 10.0))
    coil_resistance: float = _param("ohm", "R16", _range(0.5, 200.0))
    supply_voltage: float = _param("V", "Sec. 3.1", _range(1.0, 60.0))
    pwm: str = _param("-", "R15", _one_of("averaged", "switched"), kind="str")
    pwm_frequency: float = _param("Hz", "Sec. 3", _range(10.0, 1e5))

    @property
    def coil_thermal(self) -> bool:
        """True when the coil heats (R33): a coil temperature state, R(T)."""
        return self.coil_temperature == "lumped"
    # Coil heating (not in the paper, whose coil was pre-heated: docs/model.md R33). fixed: the coil
    # keeps `coil_resistance` (the paper's bench). lumped: a coil temperature state, R(T) =
    # R_ref (1 + alpha (T - T_ref)) with R_ref = coil_resistance at coil_reference_temperature_c.
    coil_temperature: str = _param("-", "R33", _one_of("fixed", "lumped"), kind="str", default="fixed")
    coil_reference_temperature_c: float = _param("degC", "R33", _range(-60.0, 250.0), default=20.0)
    coil_temperature_coefficient: float = _param("1/K", "R33, IEC 60028 copper", _range(0.0, 1e-2),
                                                 default=3.93e-3)
    coil_thermal_resistance: float = _param("K/W", "R33, assumption", _range(0.05, 50.0), default=2.5)
    coil_heat_capacity: float = _param("J/K", "R33, assumption", _range(1.0, 1e5), default=200.0)
    ambient_temperature_c: float = _param("degC", "R33: the ambient input's default", _range(-60.0, 150.0),
                                          default=40.0)


@dataclass(frozen=True)
class SpoolParams:
    """Eq. 14: the moving parts."""

    mass: float = _param("kg", "T1 m", _range(1e-3, 1.0))
    pressure_area: float = _param("m^2", "T1 A_c", _range(1e-7, 1e-2))
    chamber_area: float = _param("m^2", "T1 A_cc", _range(0.0, 1e-2))
    spring_stiffness: float = _param("N/m", "T1 K", _range(0.0, 1e6))
    spring_preload: float = _param("N", "T1 f_0", _range(-1e3, 1e3))
    viscous_friction: float = _param("Ns/m", "T1 B", _range(0.0, 1e5))
    viscous_friction_simplified: float | str = _param("Ns/m", "Sec. 4.3, R20", _range(1e-3, 1e5), kind="float_or_equivalent")
    stroke_min_mm: float = _param("mm", "Sec. 4.2", _range(-10.0, 10.0))
    stroke_max_mm: float = _param("mm", "Sec. 4.2", _range(-10.0, 10.0))
    # Core-spool separation (Sec. 3.2 names it, the model leaves it out: docs/model.md R35).
    # attached: core and spool one body of `mass`. separate: the magnet core a body of core_mass on its own side
    # of a unilateral contact, with core_damping of the moving parts' damping on it.
    core: str = _param("-", "R35", _one_of("attached", "separate"), kind="str", default="attached")
    core_mass: float = _param("kg", "R35, assumption", _range(1e-4, 1.0), default=0.024)
    core_damping: float = _param("Ns/m", "R35, assumption", _range(0.0, 1e5), default=2.0)
    core_stroke_min_mm: float = _param("mm", "R35, R2", _range(-10.0, 10.0), default=-0.7)

    @property
    def core_separation(self) -> bool:
        """True when the magnet core is its own body (R35)."""
        return self.core == "separate"


@dataclass(frozen=True)
class OrificeParams:
    """Eq. 17 and Sec. 2: the metering holes and gaps."""

    hole_radius: float = _param("m", "Sec. 2, R4", _range(1e-5, 1e-2))
    hole_count: int = _param("-", "Sec. 2", _range(1, 100), kind="int")
    gap_height: float = _param("m", "T1 h_gap", _range(1e-7, 1e-3))
    tank_pilot_hole_radius: float = _param("m", "Sec. 2, R10", _range(1e-5, 1e-2))
    tank_hole_offset: float = _param("m", "Sec. 2, R10", _range(0.0, 1e-2))
    blend_steepness_per_mm: float = _param("1/mm", "Eq. 27, R7", _range(1.0, 1e6))


@dataclass(frozen=True)
class FitParams:
    """Eqs. 21-25, 31-32: the paper's curve fits (x in mm)."""

    gap_geometry: tuple[float, ...] = _param("-", "Eq. 21", kind="vector4")
    hole_geometry: tuple[tuple[float, ...], ...] = _param("-", "Eq. 22", kind="matrixNx3")
    hole_exponent: tuple[float, ...] = _param("-", "Eq. 23", kind="vector3")
    tank_geometry: tuple[tuple[float, ...], ...] = _param("-", "Eq. 24, R8", kind="matrixNx3")
    tank_exponent: tuple[float, ...] = _param("-", "Eq. 25", kind="vector3")
    pump_jet: tuple[tuple[float, ...], ...] = _param("-", "Eq. 31, R8", kind="matrixNx3")
    pump_jet_cap: float = _param("-", "Eq. 31, R9", _fraction)
    tank_jet: tuple[tuple[float, ...], ...] = _param("-", "Eq. 32, R8", kind="matrixNx3")
    tank_jet_cap: float = _param("-", "Eq. 32, R9", _fraction)


@dataclass(frozen=True)
class DampingParams:
    """Eqs. 28-29: restrictor and damping chamber."""

    restrictor_conductance: float = _param("m^5/(N s)", "T1 K_d", _range(1e-15, 1e-6))
    chamber_volume: float = _param("m^3", "T1 V_c", _range(1e-12, 1e-4))


@dataclass(frozen=True)
class FluidParams:
    density: float = _param("kg/m^3", "T1 rho", _range(500.0, 2000.0))
    bulk_modulus: float = _param("Pa", "T1 beta", _range(1e8, 5e9))
    kinematic_viscosity: float = _param("m^2/s", "T1 nu", _range(1e-7, 1e-2))
    # Not in the paper (its valve never sees it): the gauge pressure at which the oil cavitates
    # (gas release), the floor of the load pressure (reading R32). Optional, for older files.
    cavitation_pressure: float = _param("Pa", "R32", _range(-1.0e5, -1.0e4), default=-0.9e5)
    # Oil temperature (not in the paper, whose oil was at 37-42 degC: docs/model.md R34). fixed: the
    # values above. input: the oil temperature an input; density, bulk modulus and kinematic_viscosity
    # hold at reference_temperature_c, the viscosity follows Walther (ASTM D341) through them and
    # the second point; laminar conductances and viscous damping scale with the dynamic viscosity.
    temperature: str = _param("-", "R34", _one_of("fixed", "input"), kind="str", default="fixed")
    reference_temperature_c: float = _param("degC", "R34, the paper's 40 degC", _range(-40.0, 150.0),
                                            default=40.0)
    second_viscosity: float = _param("m^2/s", "R34, ISO VG 46 VI ~100", _range(1e-7, 1e-2), default=6.8e-6)
    second_viscosity_temperature_c: float = _param("degC", "R34", _range(-40.0, 150.0), default=100.0)
    thermal_expansion: float = _param("1/K", "R34, mineral oil", _range(0.0, 2e-3), default=7.0e-4)
    bulk_modulus_temperature_coefficient: float = _param("1/K", "R34, mineral oil", _range(0.0, 2e-2),
                                                         default=4.0e-3)
    oil_temperature_c: float = _param("degC", "R34: the oil input's default", _range(-40.0, 150.0),
                                      default=40.0)

    @property
    def oil_temperature_model(self) -> bool:
        """True when the oil temperature is an input (R34)."""
        return self.temperature == "input"


@dataclass(frozen=True)
class CircuitParams:
    load_volume: float = _param("m^3", "T1 V", _range(1e-6, 1.0))
    supply_pressure: float = _param("Pa", "Sec. 3.2", _range(1e5, 400e5))
    tank_pressure: float = _param("Pa", "R19", _range(0.0, 10e5))


@dataclass(frozen=True)
class CalibrationParams:
    net_area: float | None = _param("m^2", "R21, fitted by pcv_sim.analysis.calibrate", _positive, kind="float_or_null")


def _duty_range(v: tuple[float, ...]) -> str | None:
    lo, hi = v
    return None if 0.0 <= lo < hi <= 1.0 else "[min, max] with 0 <= min < max <= 1 (duty fractions)"


@dataclass(frozen=True)
class CommandParams:
    duty_range: tuple[float, ...] = _param("-", "PWM duty, Sec. 3", _duty_range, kind="vector2")
    duty_fall_rate_limit: float | None = _param("1/s", "Sec. 3.2", _range(1e-3, 1e6), kind="float_or_null")


@dataclass(frozen=True)
class SimulationParams:
    time_step: float = _param("s", "Sec. 3", _range(1e-7, 1e-3))
    integrator: str = _param("-", "docs/model.md", _one_of("auto", "euler", "rk2", "rk4", "erk2"), kind="str")
    model: str = _param("-", "Sec. 4.2 / 4.3", _one_of("simplified", "full"), kind="str")

    @property
    def method(self) -> str:
        """The integrator in effect: 'auto' is Heun (rk2) for the simplified model and the
        exponential Heun (erk2) for the full one, whose chamber pole no explicit method survives."""
        if self.integrator != "auto":
            return self.integrator
        return "erk2" if self.model == "full" else "rk2"


_SECTIONS: dict[str, type] = {
    "solenoid": SolenoidParams,
    "spool": SpoolParams,
    "orifice": OrificeParams,
    "fits": FitParams,
    "damping": DampingParams,
    "fluid": FluidParams,
    "circuit": CircuitParams,
    "calibration": CalibrationParams,
    "command": CommandParams,
    "simulation": SimulationParams,
}


@dataclass(frozen=True)
class ValveParams:
    """All parameters of the valve model, validated. Build with `load_params` or `default_params`."""

    solenoid: SolenoidParams
    spool: SpoolParams
    orifice: OrificeParams
    fits: FitParams
    damping: DampingParams
    fluid: FluidParams
    circuit: CircuitParams
    calibration: CalibrationParams
    command: CommandParams
    simulation: SimulationParams

    def __post_init__(self) -> None:
        s = self.spool
        if not s.stroke_min_mm < 0.0 < s.stroke_max_mm:
            raise ParameterError(
                f"spool.stroke_min_mm={s.stroke_min_mm} and spool.stroke_max_mm={s.stroke_max_mm}: "
                "accepted is stroke_min_mm < 0 < stroke_max_mm (0 is the closed centre)"
            )
        if s.chamber_area >= s.pressure_area:
            raise ParameterError(
                f"spool.chamber_area={s.chamber_area} >= spool.pressure_area={s.pressure_area}: the net "
                "area A_c - A_cc that holds the load pressure must be > 0"
            )
        cal = self.calibration.net_area
        if cal is not None and not 0.0 < cal < s.pressure_area:
            raise ParameterError(
                f"calibration.net_area={cal}: accepted is null (as printed) or 0 < net_area < "
                f"spool.pressure_area={s.pressure_area} m^2"
            )
        if self.circuit.tank_pressure >= self.circuit.supply_pressure:
            raise ParameterError("circuit.tank_pressure must be below circuit.supply_pressure")
        core_min = s.stroke_min_mm + self.solenoid.core_offset_mm
        if core_min < 0.0:
            raise ParameterError(
                f"spool.stroke_min_mm + solenoid.core_offset_mm = {core_min} mm: the core position "
                "must stay >= 0 mm (the core's end position) over the stroke"
            )
        if s.core_separation and not s.core_mass < s.mass:
            raise ParameterError(
                f"spool.core_mass={s.core_mass} >= spool.mass={s.mass}: the core is part of the moving parts; "
                "accepted is 0 < core_mass < mass (the spool's own mass is the rest)")
        if s.core_separation and s.core_damping > min(s.viscous_friction, self.simplified_damping):
            raise ParameterError(
                f"spool.core_damping={s.core_damping} Ns/m: the core's share of the moving parts' damping; "
                f"accepted is 0 .. spool.viscous_friction={s.viscous_friction} Ns/m")
        if s.core_separation and not s.core_stroke_min_mm <= s.stroke_min_mm:
            raise ParameterError(
                f"spool.core_stroke_min_mm={s.core_stroke_min_mm}: the core's stop lies at or beyond the "
                f"spool's, accepted is core_stroke_min_mm <= stroke_min_mm={s.stroke_min_mm}")
        if s.core_separation and s.core_stroke_min_mm + self.solenoid.core_offset_mm < 0.0:
            raise ParameterError(
                f"spool.core_stroke_min_mm + solenoid.core_offset_mm = "
                f"{s.core_stroke_min_mm + self.solenoid.core_offset_mm} mm: the core position must stay >= 0 mm")
        fl = self.fluid
        if fl.oil_temperature_model and not (fl.second_viscosity_temperature_c != fl.reference_temperature_c
                                             and (fl.second_viscosity - fl.kinematic_viscosity)
                                             * (fl.second_viscosity_temperature_c - fl.reference_temperature_c) < 0):
            raise ParameterError(
                "fluid.second_viscosity at fluid.second_viscosity_temperature_c: accepted is a second point of "
                "the viscosity-temperature line at another temperature, the viscosity lower where it is warmer "
                f"(got {fl.second_viscosity} m^2/s at {fl.second_viscosity_temperature_c} degC against "
                f"{fl.kinematic_viscosity} m^2/s at {fl.reference_temperature_c} degC)")
        sim = self.simulation
        if sim.model == "full" and sim.method in ("euler", "rk2", "rk4"):
            raise ParameterError(
                f"simulation.integrator={sim.integrator!r} with simulation.model='full': the damping chamber's "
                "pole (~-2.6e8 1/s) makes every explicit method diverge at any usable step; accepted are "
                "'erk2' (exponential Heun) or 'auto'")
        dt = self.simulation.time_step
        if dt > 1e-3:
            raise ParameterError(f"simulation.time_step={dt}: accepted is 0 < time_step <= 1e-3 s")

    @property
    def net_area(self) -> float:
        """A_c - A_cc, m^2: the area the load pressure acts on at rest (R11), as calibrated (R21)."""
        cal = self.calibration.net_area
        return self.spool.pressure_area - self.spool.chamber_area if cal is None else cal

    @property
    def chamber_area(self) -> float:
        """A_cc in effect, m^2: the calibration adjusts the chamber side, A_c stays as printed (R21)."""
        return self.spool.pressure_area - self.net_area

    @property
    def equivalent_damping(self) -> float:
        """B + A_cc^2 / K_d, Ns/m: the damper the chamber and restrictor act as (R20)."""
        return self.spool.viscous_friction + self.chamber_area**2 / self.damping.restrictor_conductance

    @property
    def simplified_damping(self) -> float:
        """B of the simplified model (Sec. 4.3), Ns/m."""
        b = self.spool.viscous_friction_simplified
        return self.equivalent_damping if b == "equivalent" else float(b)


# --- conversion and validation ----------------------------------------------------------------


def _number(path: str, value: Any, accepted: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        hint = ""
        if isinstance(value, str):
            try:
                float(value)
                hint = " (YAML reads 1e9 as text: write 1.0e+9)"
            except ValueError:
                pass
        raise ParameterError(f"{path}: got {value!r} ({type(value).__name__}); accepted is {accepted}{hint}")
    v = float(value)
    if not math.isfinite(v):
        raise ParameterError(f"{path}: got {value!r}; accepted is a finite number")
    return v


def _vector(path: str, value: Any, length: int | None) -> tuple[float, ...]:
    want = f"a list of {length} numbers" if length else "a list of numbers"
    if not isinstance(value, (list, tuple)) or (length is not None and len(value) != length):
        raise ParameterError(f"{path}: got {value!r}; accepted is {want}")
    return tuple(_number(f"{path}[{k}]", v, "a finite number") for k, v in enumerate(value))


def _matrix(path: str, value: Any, rows: int | None, cols: int) -> tuple[tuple[float, ...], ...]:
    shape = f"{rows}x{cols}" if rows else f"Nx{cols}"
    if not isinstance(value, (list, tuple)) or (rows is not None and len(value) != rows) or not value:
        raise ParameterError(f"{path}: got {value!r}; accepted is a {shape} list of lists of numbers")
    return tuple(_vector(f"{path}[{k}]", row, cols) for k, row in enumerate(value))


def validate_section_value(section: str, key: str, value: Any, *, prefix: str = "") -> Any:
    """Convert and check one parameter; raise ParameterError naming `<prefix>section.key` if it is refused."""
    cls = _SECTIONS.get(section)
    if cls is None:
        raise ParameterError(f"unknown section {section!r}; accepted are: {', '.join(_SECTIONS)}")
    fields = declarations(cls)
    if key not in fields:
        raise ParameterError(f"unknown parameter {prefix}{section}.{key}; accepted in {section}: {', '.join(fields)}")
    return check_value(f"{prefix}{section}.{key}", fields[key].metadata, value)


#: A number followed by a unit ("200 bar", "0.1 ms"); a bare number in quotes ("1e9") is not one.
_WITH_UNIT = re.compile(r"^\s*[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?\s*[^\d\s.+eE-]")


def check_value(path: str, meta: Mapping[str, Any], value: Any, *, check: Check | None = None,
                of: str | None = None) -> Any:
    """Convert and check one value of a declared parameter (its field's metadata: kind, unit, check,
    convert); ParameterError naming `path`, what was wrong and what is accepted. `check`: the
    check in force instead of the declared one (a range the rest of the file narrows: a scenario's
    duration at least the rig's control period); `of`: the units kind of a `value` parameter."""
    kind, unit = meta["kind"], meta["unit"]
    check = check or meta["check"]
    if kind == "value":
        kind = of or "number"
        unit = KINDS[kind].si + ("/s" if meta.get("rate") else "")
    in_unit = f" in {unit}" if unit not in ("", "-") else ""
    if meta.get("convert") is not None:
        return meta["convert"](path, value)
    if isinstance(value, str) and kind.startswith("float") and si_kind(unit) is not None \
            and _WITH_UNIT.match(value):
        value = quantity(value, str(si_kind(unit)), path)       # "200 bar": a value with its unit, to SI
    if kind == "float":
        out: Any = _number(path, value, f"a number{in_unit}")
    elif kind in KINDS:
        out = quantity(value, kind, path, role=meta.get("role") or "", difference=meta.get("difference", False),
                       rate=meta.get("rate", False))
    elif kind in ("list", "mapping"):
        return _entries(path, meta, value)
    elif kind == "section":
        return section_from_mapping(meta["section"], value, path, defaults=True)
    elif kind == "any":
        out = value
    elif kind == "int":
        if isinstance(value, bool) or not isinstance(value, int):
            raise ParameterError(f"{path}: got {value!r}; accepted is an integer")
        out = value
    elif kind == "str":
        if not isinstance(value, str):
            raise ParameterError(f"{path}: got {value!r}; accepted is {check('') or 'a string'}")
        out = value
    elif kind == "bool":
        if not isinstance(value, bool):
            raise ParameterError(f"{path}: got {value!r}; accepted is true or false")
        out = value
    elif kind == "float_or_null":
        if value is None:
            return None
        out = _number(path, value, f"null (off) or a number{in_unit}")
    elif kind == "float_or_equivalent":
        if value == "equivalent":
            return value
        out = _number(path, value, f"'equivalent' or a number{in_unit}")
    elif kind.startswith("vector"):
        out = _vector(path, value, int(kind[6:]))
    elif kind == "matrix4x4":
        return _matrix(path, value, 4, 4)
    elif kind == "matrixNx3":
        return _matrix(path, value, None, 3)
    else:  # pragma: no cover - a field declared with an unknown kind is a programming error
        raise AssertionError(kind)
    problem = check(out)
    if problem is not None:
        raise ParameterError(f"{path}: got {value!r}; accepted is {problem}{f' ({unit})' if in_unit else ''}")
    return out


def check_si(path: str, meta: Mapping[str, Any], value: float, *, check: Check | None = None,
             of: str | None = None) -> float:
    """An SI value the loader worked out from what the file holds (the reach of a profile: offset
    +- amplitude, a table's values) against the declared check (or `check`), named `path`."""
    problem = (check or meta["check"])(value)
    if problem is not None:
        unit = KINDS[of].si if meta["kind"] == "value" and of else meta["unit"]
        shown = f" {unit}" if unit not in ("", "-") else ""
        raise ParameterError(f"{path}: {value:g}{shown}; accepted is {problem}{f' ({unit})' if shown else ''}")
    return value


def _entries(path: str, meta: Mapping[str, Any], value: Any) -> Any:
    """A list (kind list) or a mapping (kind mapping) with each entry checked as `meta["item"]`."""
    item, what = meta.get("item"), _accepted(meta)
    if meta["kind"] == "list":
        if not isinstance(value, list):
            raise ParameterError(f"{path}: got {value!r}; accepted is {what}")
        out: Any = value if item is None else [check_value(f"{path}[{k}]", item, v) for k, v in enumerate(value)]
    else:
        if not isinstance(value, Mapping):
            raise ParameterError(f"{path}: got {value!r}; accepted is {what}")
        out = value if item is None else {k: check_value(f"{path}.{k}", item, v) for k, v in value.items()}
    problem = meta["check"](out)
    if problem is not None:
        raise ParameterError(f"{path}: got {value!r}; accepted is {what}, {problem}")
    return out


@functools.cache
def declarations(cls: type) -> dict[str, dataclasses.Field[Any]]:
    """The declared keys of `cls` (a dataclass declared with `parameter`), as a file names them."""
    return {f.metadata.get("name") or f.name: f for f in dataclasses.fields(cls)}


def _required(f: dataclasses.Field[Any]) -> bool:
    return f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING


def check_mapping(cls: type, data: Any, where: str, prefix: str | None = None, *,
                  also: tuple[str, ...] = ()) -> Mapping[str, Any]:
    """`data` as a mapping of the keys `cls` declares (and `also`, keys the caller reads itself);
    ParameterError naming `where` when it is none, for an unknown key (with the key it was likely
    meant as) or a missing required one (`prefix.key`; prefix defaults to `where`)."""
    keys = (*declarations(cls), *also)
    if not isinstance(data, Mapping):
        raise ParameterError(f"{where}: got {data!r}; accepted is a mapping with {', '.join(keys)}")
    msg = unknown_message(where, data, keys)
    if msg:
        raise ParameterError(msg)
    for key, f in declarations(cls).items():
        if key not in data and _required(f):
            raise ParameterError(f"{_join(where if prefix is None else prefix, key)}: missing; accepted is "
                                 f"{_accepted(f.metadata)}")
    return data


def _join(prefix: str, key: str) -> str:
    return f"{prefix}.{key}" if prefix else key


def _accepted(meta: Mapping[str, Any]) -> str:
    """A declaration in words: its doc and unit ("the run's length (s)"); a list's or mapping's
    doc says what of ("a list of segments {t, ...}")."""
    unit, doc = meta["unit"], meta["description"]
    if meta["kind"] in ("list", "mapping"):
        doc = f"a {meta['kind']} {doc}"
    return f"{doc}{f' ({unit})' if unit not in ('', '-') else ''}"


def read(cls: type, data: Mapping[str, Any], key: str, prefix: str = "", *, check: Check | None = None,
         of: str | None = None) -> Any:
    """The value of the declared key `key` of `cls` in `data` (checked: `check_value`; its
    default when absent), named `prefix.key` in a refusal."""
    f = declarations(cls)[key]
    if key not in data or (data[key] is None and f.default is None):     # YAML's `key:` (null): not given
        if _required(f):
            raise ParameterError(f"{_join(prefix, key)}: missing; accepted is {_accepted(f.metadata)}")
        return f.default if f.default_factory is dataclasses.MISSING else f.default_factory()
    return check_value(_join(prefix, key), f.metadata, data[key], check=check, of=of)


def accepted_words(meta: Mapping[str, Any]) -> str:
    """What a declaration accepts, in a table's cell or a parameter's description ("0 .. 1",
    ">= 0", "product | zip", "true, false"; '' when its check has no words for it)."""
    return _range_words(meta["check"]) or _KIND_WORDS.get(meta["kind"], "")


def _range_words(check: Check) -> str:
    """What a check accepts, in a table's cell ("0 .. 1", ">= 0", "product | zip"; '' for none)."""
    lo, hi = getattr(check, "lo", None), getattr(check, "hi", None)
    if isinstance(lo, int) and isinstance(hi, int):          # an integer range, to its last digit
        return f"{lo} .. {hi}"
    if lo is not None and hi is not None:
        return f"{lo:g} .. {hi:g}"
    return str(getattr(check, "accepted", ""))


_KIND_WORDS = {"str": "a string", "bool": "true, false", "int": "an integer", "list": "a list", "mapping": "a mapping",
               "section": "a mapping"}


def refused_as(error: type[PcvSimError]) -> Callable[[Callable[P, R]], Callable[P, R]]:
    """A decorator: a refusal by these declarations in the decorated loader is raised as `error`,
    the file's own class (ScenarioError, ProfileError...), with its text."""

    def wrap(fn: Callable[P, R]) -> Callable[P, R]:
        @functools.wraps(fn)
        def loader(*args: P.args, **kwargs: P.kwargs) -> R:
            try:
                return fn(*args, **kwargs)
            except error:
                raise
            except ParameterError as err:
                raise error(str(err)) from None

        return loader

    return wrap


def key_table(cls: type) -> str:
    """The keys `cls` declares as a Markdown table (key, unit, accepted, default, meaning): the
    tables of the docs are these, and a test holds them equal."""
    rows = ["| key | unit | accepted | default | meaning |", "|---|---|---|---|---|"]
    rows += [f"| `{key}` | {unit} | {accepted} | {default} | {doc} |" for key, unit, accepted, default, doc in key_cells(cls)]
    return "\n".join(rows)


def key_cells(cls: type) -> list[tuple[str, str, str, str, str]]:
    """The cells of `key_table`'s rows, one per declared key: key, unit, accepted, default, meaning."""
    cells = []
    for key, f in declarations(cls).items():
        meta = f.metadata
        # a value in the unit of what it belongs to: the declaration's words for that, if it has them
        unit = ("the quantity's" if meta["unit"] in ("", "-") else meta["unit"]) if meta["kind"] == "value" \
            else meta["unit"]
        if _required(f):
            default = "required"
        elif f.default_factory is not dataclasses.MISSING or f.default is None:
            default = "none"
        else:
            default = f"`{str(f.default).lower() if isinstance(f.default, bool) else f.default or repr(f.default)}`"
        doc = _accepted({**meta, "unit": "-"}).replace("|", "\\|")
        accepted = accepted_words(meta)
        cells.append((key, unit, accepted, default, doc))
    return cells


def check_field(path: str, f: dataclasses.Field[Any], value: Any) -> Any:
    """`check_value` for a declared field; a refusal also says what the parameter is (its doc)."""
    try:
        return check_value(path, f.metadata, value)
    except ParameterError as err:
        doc = f.metadata.get("description")
        raise ParameterError(f"{err} ({doc})" if doc else str(err)) from None


def section_from_mapping(cls: type[T], data: Any, path: str, *, defaults: bool = False) -> T:
    """Build the frozen dataclass `cls` (fields declared with `parameter`) from a mapping, refusing
    unknown keys and missing ones (with `defaults`, only those without a default), naming `path.key`."""
    if not isinstance(data, Mapping):
        raise ParameterError(f"{path}: got {data!r}; accepted is a mapping of key: value")
    fields = declarations(cls)  # type: ignore[arg-type]  # a dataclass type (hashable)
    unknown = unknown_message(path, data, fields)
    if unknown:
        raise ParameterError(unknown)
    missing = [k for k, f in fields.items() if k not in data
               and not (defaults and (f.default is not dataclasses.MISSING or f.default_factory is not dataclasses.MISSING))]
    if missing:
        raise ParameterError(f"{path}: missing key(s) {', '.join(f'{path}.{k}' for k in missing)}")
    values = {fields[k].name: check_field(f"{path}.{k}", fields[k], v) for k, v in data.items()}
    try:
        return cls(**values)
    except ParameterError as err:
        raise ParameterError(f"{path}: {err}") from None


def params_from_mapping(data: Any, *, origin: str | None = "parameters", prefix: str = "") -> ValveParams:
    """Build ValveParams from a nested mapping (as loaded from YAML), refusing anything unknown.

    Messages start with `origin: ` (None: no origin) and name keys `<prefix>section.key`."""

    def where(err: ParameterError) -> ParameterError:
        return ParameterError(f"{origin}: {err}" if origin else str(err))

    if not isinstance(data, Mapping):
        raise ParameterError(f"{origin}: the top level must be a mapping of sections ({', '.join(_SECTIONS)})")
    unknown = sorted(set(data) - set(_SECTIONS))
    if unknown:
        raise ParameterError(f"{origin}: unknown section(s) {unknown}; accepted are: {', '.join(_SECTIONS)}")
    missing = [s for s in _SECTIONS if s not in data]
    if missing:
        raise ParameterError(f"{origin}: missing section(s) {missing}")
    sections: dict[str, Any] = {}
    for name, cls in _SECTIONS.items():
        raw = data[name]
        if not isinstance(raw, Mapping):
            raise ParameterError(f"{origin}: section {name!r} must be a mapping of key: value")
        try:
            values = {str(k): validate_section_value(name, str(k), v, prefix=prefix) for k, v in raw.items()}
        except ParameterError as err:  # unknown keys first: a misspelt key is not reported as missing
            raise where(err) from None
        absent = [f.name for f in dataclasses.fields(cls) if f.name not in raw and f.default is dataclasses.MISSING]
        if absent:
            raise where(ParameterError(f"missing parameter(s) {', '.join(f'{prefix}{name}.{k}' for k in absent)}"))
        sections[name] = cls(**values)
    try:
        return ValveParams(**sections)
    except ParameterError as err:
        raise where(err) from None


def params_to_mapping(params: ValveParams) -> dict[str, dict[str, Any]]:
    """The nested plain-Python form of `params` (lists, not tuples), e.g. for YAML or JSON output."""

    def plain(v: Any) -> Any:
        return [plain(x) for x in v] if isinstance(v, tuple) else v

    return {
        name: {f.name: plain(getattr(getattr(params, name), f.name)) for f in dataclasses.fields(cls)}
        for name, cls in _SECTIONS.items()
    }


def _construct_unique_mapping(self: yaml.constructor.SafeConstructor, node: yaml.MappingNode,
                              deep: bool = False) -> dict[Any, Any]:
    """SafeConstructor's mapping, refusing a key given twice in it (plain YAML keeps the last silently)."""
    seen: dict[Any, int] = {}
    for key_node, _ in node.value:
        key = self.construct_object(key_node, deep=True)
        line = key_node.start_mark.line + 1
        if key in seen:
            raise ParameterError(f"duplicate key {key!r} at line {line} (first at line {seen[key]}); "
                                 "accepted is each key once per mapping (YAML would keep the last silently)")
        seen[key] = line
    return yaml.constructor.SafeConstructor.construct_mapping(self, node, deep=deep)


class _UniqueKeyLoader(yaml.SafeLoader):
    """SafeLoader that refuses a key given twice in one mapping."""

    construct_mapping = _construct_unique_mapping      # type: ignore[assignment]


class _UniqueKeyCLoader(yaml.CSafeLoader):
    """The same on libyaml's parser (in pyyaml's wheels): several times faster than pyyaml's own on
    a campaign's files, its scenario, rig and valves, which it reads before any variant runs."""

    construct_mapping = _construct_unique_mapping      # type: ignore[assignment]


def _load(text: str, unique: bool) -> Any:
    """The YAML document `text`, parsed by libyaml; a document it refuses parsed again by pyyaml's
    own parser, whose error (its words, line and column) the messages quote."""
    try:
        return yaml.load(text, Loader=_UniqueKeyCLoader if unique else yaml.CSafeLoader)
    except yaml.YAMLError:
        return yaml.load(text, Loader=_UniqueKeyLoader if unique else yaml.SafeLoader)


def yaml_load_unique(text: str, origin: str) -> Any:
    """yaml.safe_load that refuses duplicate keys; ParameterError naming `origin`, the key and line."""
    try:
        return _load(text, True)
    except ParameterError as err:
        raise ParameterError(f"{origin}: {err}") from None
    except yaml.YAMLError as err:
        raise ParameterError(f"{origin}: not valid YAML: {err}") from err


def read_yaml(path: str | Path, what: str, error: type[PcvSimError] = ParameterError, *, unique: bool = False) -> Any:
    """The YAML file `path` (a `what`: "scenario", "rig file"...) as data; `error` naming the file
    when it cannot be read or is not valid YAML (`unique`: nor holds a key twice in a mapping)."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as err:
        raise error(f"cannot read {what} {p}: {err.strerror}") from None
    if unique:
        try:
            return yaml_load_unique(text, str(p))
        except ParameterError as err:
            raise (err if error is ParameterError else error(str(err))) from None
    try:
        return _load(text, False)
    except yaml.YAMLError as err:
        raise error(f"{p}: not valid YAML: {err}") from None


def load_params(path: str | Path | None = None) -> ValveParams:
    """Load and validate a valve YAML file (default: config/valve.yaml)."""
    p = Path(path) if path is not None else _installed_default()
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as err:
        raise ParameterError(f"cannot read parameter file {p}: {err.strerror}") from err
    return params_from_mapping(yaml_load_unique(text, str(p)), origin=str(p))


_DEFAULT: ValveParams | None = None


def default_params() -> ValveParams:
    """The shipped configuration (cached: ValveParams is immutable)."""
    global _DEFAULT
    if _DEFAULT is None:
        _DEFAULT = load_params()
    return _DEFAULT


def replace_param(params: ValveParams, dotted: str, value: Any) -> ValveParams:
    """A copy of `params` with `section.key` set to `value`, validated like the YAML file."""
    section, _, key = dotted.partition(".")
    checked = validate_section_value(section, key, value)
    new_section = dataclasses.replace(getattr(params, section), **{key: checked})
    try:
        return dataclasses.replace(params, **{section: new_section})
    except ParameterError as err:
        raise ParameterError(f"{dotted}={value!r}: {err}") from None
