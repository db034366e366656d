"""Typed, validated parameters of the plants (the steering cylinder), in the valve YAML's style.

Each field carries its unit, where its value comes from and a plausible range; `section_from_mapping`
refuses unknown keys, wrong types and values outside the range with a message naming the key and
what is accepted (`ParameterError`). The ranges are wide (what any steering cylinder on a rig
could have), so they catch unit slips (mm for m, bar for Pa, L for m^3) rather than judge a design.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, TypeVar

from pcv_sim.errors import ParameterError
from pcv_sim.params import check_value as params_check_value
from pcv_sim.params import plausible_range

__all__ = ["CylinderParams", "check_value", "ranged", "section_from_mapping"]

T = TypeVar("T")


def ranged(unit: str, lo: float, hi: float, description: str, *, kind: str = "float") -> Any:
    """A field with its unit, its plausible range [lo, hi] and what it is, declared the way every
    parameter of the package is (`pcv_sim.params`), so one validator checks them all."""
    return field(metadata={"unit": unit, "source": description, "description": description,
                           "check": plausible_range(lo, hi), "kind": kind})


def check_value(path: str, f: dataclasses.Field, value: Any) -> Any:  # type: ignore[type-arg]
    """Convert and check one value of field `f` (`pcv_sim.params.check_value`); ParameterError
    naming `path`, the plausible range and what the parameter is if refused."""
    try:
        return params_check_value(path, f.metadata, value)
    except ParameterError as err:
        raise ParameterError(f"{err} ({f.metadata['description']})") from None


def section_from_mapping(cls: type[T], data: Any, path: str, *, defaults: bool = False) -> T:
    """Build the frozen dataclass `cls` from a mapping, refusing unknown keys (and, unless
    `defaults`, missing ones) naming `path.key`."""
    if not isinstance(data, Mapping):
        raise ParameterError(f"{path}: got {data!r}; accepted is a mapping of key: value")
    fields = {f.name: f for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    unknown = sorted(str(k) for k in data if k not in fields)
    if unknown:
        raise ParameterError(f"{path}: unknown key(s) {', '.join(f'{path}.{k}' for k in unknown)}; "
                             f"accepted: {', '.join(fields)}")
    if not defaults:
        missing = [k for k in fields if k not in data]
        if missing:
            raise ParameterError(f"{path}: missing key(s) {', '.join(f'{path}.{k}' for k in missing)}")
    values = {k: check_value(f"{path}.{k}", fields[k], v) for k, v in data.items()}
    try:
        return cls(**values)
    except ParameterError as err:
        raise ParameterError(f"{path}: {err}") from None


@dataclass(frozen=True)
class CylinderParams:
    """A double-acting steering cylinder (`pcv_sim.plant.cylinder`). x = 0 is mid-stroke (straight
    ahead), x > 0 extends: chamber a (the bore side) grows, chamber b (the rod side) shrinks."""

    area_a: float = ranged("m^2", 1e-5, 1e-1, "piston area on the chamber a side (bore)")
    area_b: float = ranged("m^2", 1e-5, 1e-1, "piston area on the chamber b side (annulus; = area_a for a double rod)")
    mass: float = ranged("kg", 0.01, 1e4, "moving mass reflected to the rod (piston, rod, linkage, wheels)")
    stroke_min: float = ranged("m", -1.0, 0.0, "end stop on the retract side (inelastic)")
    stroke_max: float = ranged("m", 0.0, 1.0, "end stop on the extend side (inelastic)")
    dead_volume_a: float = ranged("m^3", 1e-8, 1e-1, "oil in chamber a at full retraction (x = stroke_min)")
    dead_volume_b: float = ranged("m^3", 1e-8, 1e-1, "oil in chamber b at full extension (x = stroke_max)")
    hose_volume_a: float = ranged("m^3", 0.0, 1e-1, "oil in the line from valve a's load port to chamber a")
    hose_volume_b: float = ranged("m^3", 0.0, 1e-1, "oil in the line from valve b's load port to chamber b")
    load_stiffness: float = ranged("N/m", 0.0, 1e9, "steering load (tyre self-aligning) as a spring toward x = 0")
    load_damping: float = ranged("Ns/m", 0.0, 1e7, "steering load damping")
    viscous_friction: float = ranged("Ns/m", 0.0, 1e7, "cylinder seal viscous friction")
    coulomb_friction: float = ranged("N", 0.0, 1e6, "cylinder seal Coulomb friction (magnitude)")
    friction_velocity: float = ranged("m/s", 1e-6, 1.0, "velocity scale of the Coulomb smoothing tanh(v / v_s)")
    initial_position: float = ranged("m", -1.0, 1.0, "piston position at the start")

    def __post_init__(self) -> None:
        if not self.stroke_min < 0.0 < self.stroke_max:
            raise ParameterError(f"stroke_min={self.stroke_min} and stroke_max={self.stroke_max}: accepted is "
                                 "stroke_min < 0 < stroke_max (x = 0 is mid-stroke, straight ahead)")
        if not self.stroke_min <= self.initial_position <= self.stroke_max:
            raise ParameterError(f"initial_position={self.initial_position}: accepted is stroke_min <= "
                                 f"initial_position <= stroke_max ({self.stroke_min} .. {self.stroke_max} m)")

    def volume_a(self, x: float) -> float:
        """Chamber a plus its hose (m^3) at piston position x (m)."""
        return self.hose_volume_a + self.dead_volume_a + self.area_a * (x - self.stroke_min)

    def volume_b(self, x: float) -> float:
        """Chamber b plus its hose (m^3) at piston position x (m)."""
        return self.hose_volume_b + self.dead_volume_b + self.area_b * (self.stroke_max - x)
