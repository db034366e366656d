"""Unit conversions, in one place. SI inside the model; the paper's curve fits take mm; bar,
L/min and percent only at the edges (CLI, reports, and values written with a unit in the
scenario, campaign, rig and valve files).

A value in a file is a bare number (SI, as always) or a string `"<number> <unit>"`: `100 bar`,
`5 mm`, `20 ms`, `-1 kN`, `12 L/min`. `quantity(raw, kind)` reads either; a bare number whose
size fits another unit of its kind far better than SI (a supply pressure of 100, a pressure limit
of 180, a position of 5) is refused with the likely meaning, since a wrong unit must not pass
silently. A number written with its unit is taken at its word (still range-checked by the caller).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Any

from pcv_sim.errors import ParameterError

__all__ = ["KINDS", "NS_PER_S", "Kind", "UnitError", "bar", "display", "fmt", "lpm", "quantity", "si_kind", "to_fit_mm",
           "unit_kind", "value_kind"]

MM_PER_M = 1.0e3        # the paper's fits (Eqs. 5-13, 21-25, 27, 31-32) take the position in mm
PA_PER_BAR = 1.0e5
M3S_PER_LPM = 1.0e-3 / 60.0
NS_PER_S = 1_000_000_000   # stamps and bag times are integer ns


def to_fit_mm(x_m: float) -> float:
    """Spool position in m -> the paper's fit coordinate in mm (the one conversion of x)."""
    return x_m * MM_PER_M


def bar(p_pa: float) -> float:
    return p_pa / PA_PER_BAR


def lpm(q_m3s: float) -> float:
    return q_m3s / M3S_PER_LPM


class UnitError(ParameterError):
    """A value with a unit that is not one of its kind, or a bare number whose size says it was
    meant in another unit."""


@dataclass(frozen=True)
class Kind:
    """A physical kind: its SI unit, the units accepted for it (unit -> SI per unit), the unit
    reports show it in, and the magnitudes a bare (SI) number may plausibly have (a nonzero bare
    number outside them is refused when another unit puts it inside; None: no such check)."""

    si: str
    units: dict[str, float]
    display: str
    plausible: tuple[float, float] | None = None
    hints: tuple[str, ...] = ()           # units to suggest, in order
    #: unit -> its zero in SI (degC: 273.15 K): added to an absolute value, not to a difference
    zeros: tuple[tuple[str, float], ...] = ()

    def zero(self, unit: str) -> float:
        return dict(self.zeros).get(unit, 0.0)

    def factor(self, unit: str) -> float:
        return self.units[unit]


#: The one table of units. Plausible magnitudes are for the rig's quantities (a valve's pressures
#: up to a few hundred bar, a steering stroke of +-0.1 m, flows of a few L/min).
KINDS: dict[str, Kind] = {
    "pressure": Kind("Pa", {"Pa": 1.0, "kPa": 1e3, "MPa": 1e6, "bar": PA_PER_BAR, "mbar": 100.0, "psi": 6894.757293168},
                     "bar", (1.0e3, 1.0e8), ("bar", "MPa")),
    "length": Kind("m", {"m": 1.0, "cm": 1e-2, "mm": 1e-3, "um": 1e-6, "µm": 1e-6}, "mm", (0.0, 1.0), ("mm", "cm")),
    "velocity": Kind("m/s", {"m/s": 1.0, "mm/s": 1e-3, "cm/s": 1e-2}, "mm/s", (0.0, 10.0), ("mm/s",)),
    "time": Kind("s", {"s": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6, "min": 60.0}, "ms"),
    "frequency": Kind("Hz", {"Hz": 1.0, "kHz": 1e3}, "Hz"),
    "force": Kind("N", {"N": 1.0, "kN": 1e3}, "N"),
    "flow": Kind("m^3/s", {"m^3/s": 1.0, "m3/s": 1.0, "L/min": M3S_PER_LPM, "l/min": M3S_PER_LPM},
                 "L/min", (0.0, 0.01), ("L/min",)),
    "current": Kind("A", {"A": 1.0, "mA": 1e-3}, "A", (0.0, 100.0), ("mA",)),
    "fraction": Kind("-", {"-": 1.0, "%": 0.01}, "%", (0.0, 1.0), ("%",)),
    "conductance": Kind("m^3/(s Pa)", {"m^3/(s Pa)": 1.0}, "m^3/(s Pa)"),
    "number": Kind("-", {"-": 1.0}, "-"),
    # Absolute temperatures (an ambient, an oil's); a bare number is K, and one that reads as degC
    # (a plausible temperature once 273.15 K is added) is refused with that meaning.
    "temperature": Kind("K", {"K": 1.0, "degC": 1.0}, "degC", (150.0, 700.0), ("degC",), (("degC", 273.15),)),
}

_VALUE = re.compile(r"^\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*(\S.*?)?\s*$")


def _unit_factor(kind: Kind, unit: str) -> float | None:
    if unit in kind.units:
        return kind.units[unit]
    # A rate (drift): `<unit>/s`, `<unit>/min`...
    if "/" in unit:
        num, _, den = unit.rpartition("/")
        if num in kind.units and den in KINDS["time"].units:
            return kind.units[num] / KINDS["time"].units[den]
    return None


def quantity(raw: Any, kind: str, where: str, *, rate: bool = False, role: str = "", difference: bool = False
             ) -> float:
    """`raw` (a bare SI number, or "<number> <unit>") as a float in SI; UnitError naming `where`
    and the accepted units otherwise. `rate`: the kind per second (a drift: `bar/s`). `role`
    words the plausibility hint (e.g. "supply pressure"). `difference`: a difference of the kind
    (an amplitude), to which a unit's zero (degC's) does not apply."""
    k = KINDS[kind]
    si = k.si + ("/s" if rate else "")
    accepted = ", ".join(f"{u}/s" if rate else u for u in k.units)
    if isinstance(raw, bool) or raw is None:
        raise UnitError(f"{where}: got {raw!r}; accepted is a number ({si}) or a value with a unit ({accepted})")
    if isinstance(raw, (int, float)):
        v = float(raw)
        if not math.isfinite(v):
            raise UnitError(f"{where}: got {raw!r}; accepted is a finite number ({si})")
        if k.plausible is not None and not rate and not difference and v != 0.0:
            lo, hi = k.plausible
            if not lo <= abs(v) <= hi:
                for hint in k.hints:
                    if lo <= abs(v * k.units[hint] + k.zero(hint)) <= hi:
                        side = "below" if abs(v) < lo else "above"
                        what = role or f"plausible {kind}"
                        si_v = f"{v:g} {k.si}" if k.si != "-" else f"{v:g} (a fraction)"
                        raise UnitError(f"{where}: {raw!r} is {si_v}, {side} any {what}; did you mean "
                                        f"{raw!r} {hint}? Write the unit: '{raw} {hint}' (a bare number is SI, {k.si})")
        return v
    if not isinstance(raw, str):
        raise UnitError(f"{where}: got {raw!r}; accepted is a number ({si}) or a value with a unit ({accepted})")
    m = _VALUE.match(raw)
    if m is None:
        raise UnitError(f"{where}: got {raw!r}; accepted is '<number> <unit>' with a unit of {accepted}")
    number, unit = float(m.group(1)), m.group(2)
    if unit is None:
        return quantity(number, kind, where, rate=rate, role=role, difference=difference)
    f = _unit_factor(k, unit) if rate else k.units.get(unit)
    if rate and unit in k.units:
        f = None                             # a rate needs its "per time"
    if f is None:
        other = [name for name, kk in KINDS.items() if _unit_factor(kk, unit) is not None or unit in kk.units]
        also = f" ({unit} is a unit of {', '.join(other)})" if other else ""
        raise UnitError(f"{where}: unit {unit!r} in {raw!r}{also}; accepted for a {kind}{' rate' if rate else ''} "
                        f"are {accepted}")
    return number * f + (0.0 if rate or difference else k.zero(unit))


def unit_kind(unit: str) -> str | None:
    """The kind a unit is of (`mm` -> length, `bar` -> pressure); None for none. ('-' is a
    fraction's and a plain number's: fraction.)"""
    return next((name for name, k in KINDS.items() if unit in k.units), None)


def value_kind(raw: Any) -> str | None:
    """The kind of a value as written: the kind its unit names ("20 mm" -> length), None for a
    bare number or a string with no unit of any kind."""
    if isinstance(raw, str):
        m = _VALUE.match(raw)
        if m is not None and m.group(2) is not None:
            return unit_kind(m.group(2))
    return None


def fmt(value: float | None, kind: str, *, digits: int = 4, difference: bool = False) -> str:
    """`value` (SI) in the kind's engineering unit: '125.3 bar', '0.48 mm', '35 ms', '12 %'.
    `difference`: a difference of the kind (a bias, a rate), to which a unit's zero does not apply."""
    if value is None or math.isnan(value):
        return "n/a"
    if math.isinf(value):
        return ("+" if value > 0 else "-") + "inf"
    unit, f = display(kind)
    v = value * f - (0.0 if difference else KINDS[kind].zero(unit))
    return f"{v:.{digits}g} {unit}" if unit != "-" else f"{v:.{digits}g}"


def si_kind(unit: str) -> str | None:
    """The kind whose SI unit is `unit` (a declared parameter's), None for none (or '-')."""
    if unit in ("", "-"):
        return None
    return next((name for name, k in KINDS.items() if k.si == unit), None)


def display(kind: str) -> tuple[str, float]:
    """The unit reports show `kind` in and the factor SI -> that unit."""
    k = KINDS[kind]
    return k.display, 1.0 / k.units[k.display] if k.display in k.units else 1.0


KELVIN_AT_0C = 273.15   # temperatures are kelvin inside; the YAML and reports give degC (keys *_c)


def kelvin(celsius: float) -> float:
    """degC (the YAML's *_c keys, scenario profiles) -> K (inside the model)."""
    return celsius + KELVIN_AT_0C


CST_PER_M2S = 1.0e6     # kinematic viscosity: 1 cSt = 1 mm^2/s (oil grades, Walther's relation)
