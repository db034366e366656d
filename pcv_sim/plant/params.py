"""Typed, validated parameters of the plants (the steering cylinder), declared with
`pcv_sim.params.parameter` as every parameter set is.

Each field carries its unit, what it is and a plausible range; `pcv_sim.params.section_from_mapping`
refuses unknown keys, wrong types and values outside the range with a message naming the key and
what is accepted (`ParameterError`). The ranges are wide (what any steering cylinder on a rig
could have), so they catch unit slips (mm for m, bar for Pa, L for m^3) rather than judge a design.
"""

from __future__ import annotations

from dataclasses import dataclass

from pcv_sim.errors import ParameterError
from pcv_sim.params import parameter, plausible_range

__all__ = ["CylinderParams"]


@dataclass(frozen=True)
class CylinderParams:
    """A double-acting steering cylinder (`pcv_sim.plant.cylinder`). x = 0 is mid-stroke (straight
    ahead), x > 0 extends: chamber a (the bore side) grows, chamber b (the rod side) shrinks."""

    area_a: float = parameter("m^2", "piston area on the chamber a side (bore)", plausible_range(1e-5, 1e-1))
    area_b: float = parameter("m^2", "piston area on the chamber b side (annulus; = area_a for a double rod)",
                              plausible_range(1e-5, 1e-1))
    mass: float = parameter("kg", "moving mass reflected to the rod (piston, rod, linkage, wheels)", plausible_range(0.01, 1e4))
    stroke_min: float = parameter("m", "end stop on the retract side (inelastic)", plausible_range(-1.0, 0.0))
    stroke_max: float = parameter("m", "end stop on the extend side (inelastic)", plausible_range(0.0, 1.0))
    dead_volume_a: float = parameter("m^3", "oil in chamber a at full retraction (x = stroke_min)", plausible_range(1e-8, 1e-1))
    dead_volume_b: float = parameter("m^3", "oil in chamber b at full extension (x = stroke_max)", plausible_range(1e-8, 1e-1))
    hose_volume_a: float = parameter("m^3", "oil in the line from valve a's load port to chamber a", plausible_range(0.0, 1e-1))
    hose_volume_b: float = parameter("m^3", "oil in the line from valve b's load port to chamber b", plausible_range(0.0, 1e-1))
    load_stiffness: float = parameter("N/m", "steering load (tyre self-aligning) as a spring toward x = 0",
                                      plausible_range(0.0, 1e9))
    load_damping: float = parameter("Ns/m", "steering load damping", plausible_range(0.0, 1e7))
    viscous_friction: float = parameter("Ns/m", "cylinder seal viscous friction", plausible_range(0.0, 1e7))
    coulomb_friction: float = parameter("N", "cylinder seal Coulomb friction (magnitude)", plausible_range(0.0, 1e6))
    friction_velocity: float = parameter("m/s", "velocity scale of the Coulomb smoothing tanh(v / v_s)",
                                         plausible_range(1e-6, 1.0))
    initial_position: float = parameter("m", "piston position at the start", plausible_range(-1.0, 1.0))

    def __post_init__(self) -> None:
        if not self.stroke_min < 0.0 < self.stroke_max:
            raise ParameterError(f"stroke_min={self.stroke_min} and stroke_max={self.stroke_max}: accepted is "
                                 "stroke_min < 0 < stroke_max (x = 0 is mid-stroke, straight ahead)")
        if not self.stroke_min <= self.initial_position <= self.stroke_max:
            raise ParameterError(f"initial_position={self.initial_position}: accepted is stroke_min <= "
                                 f"initial_position <= stroke_max ({self.stroke_min} .. {self.stroke_max} m)")
