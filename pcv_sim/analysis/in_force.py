"""Which damping and which calibration a parameter set puts in force, named, for every output.

Damping of the simplified model (Sec. 4.3, reading R20): ``equivalent`` (B + A_cc^2/K_d, the
damper the chamber and restrictor act as, the default), ``paper`` (Table 1's tuned 223.6 Ns/m)
or a number. The full model has the chamber itself and B of Table 1.

Calibration kind (reading R21): the constants that close the static balance at the working
points. ``net_area``: ``calibration.net_area`` set, the spring preload f_0 as printed;
``force_offset``: the net area as printed (null), a constant force offset carried by f_0 (Eq.
14's only constant force: an offset F toward +x is f_0 - F); ``both``; ``as printed``.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any, Literal

from pcv_sim.params import ValveParams, replace_param

__all__ = [
    "DAMPING_CHOICES",
    "PAPER_DAMPING",
    "TABLE1_SPRING_PRELOAD",
    "InForce",
    "in_force",
    "with_damping",
]

#: Table 1's B for the simplified model, Ns/m (Sec. 4.3).
PAPER_DAMPING = 223.6
#: Table 1's spring preload f_0, N: a different value in the config is a force offset.
TABLE1_SPRING_PRELOAD = 2.0
DAMPING_CHOICES = ("equivalent", "paper")


@dataclass(frozen=True)
class InForce:
    """The damping and calibration a model runs with (SI)."""

    model: str
    damping_choice: str              # equivalent, paper, custom (simplified); chamber (full)
    damping_Ns_per_m: float          # B of the model
    calibration_kind: Literal["net_area", "force_offset", "both", "as printed"]
    net_area_m2: float               # in force
    force_offset_N: float            # toward +x: Table 1's f_0 minus the config's

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)

    def text(self) -> str:
        if self.model == "full":
            damp = f"damping: chamber + restrictor (full model), B = {self.damping_Ns_per_m:g} Ns/m"
        else:
            name = {"equivalent": "equivalent (B + A_cc^2/K_d, R20)", "paper": "paper (Table 1)"}.get(
                self.damping_choice, "custom")
            damp = f"damping: {name} {self.damping_Ns_per_m:.1f} Ns/m"
        cal = {"net_area": f"net area {self.net_area_m2:.4g} m^2",
               "force_offset": f"force offset {self.force_offset_N:+.3f} N (spring preload)",
               "both": f"net area {self.net_area_m2:.4g} m^2 and force offset {self.force_offset_N:+.3f} N",
               "as printed": f"none (as printed: net area {self.net_area_m2:.4g} m^2)"}[self.calibration_kind]
        return f"{damp}; calibration: {self.calibration_kind} ({cal})"


def in_force(params: ValveParams, model: str = "simplified") -> InForce:
    """Name the damping and calibration ``params`` put in force for ``model``."""
    b = params.spool.viscous_friction_simplified
    if model == "full":
        choice, damping = "chamber", params.spool.viscous_friction
    elif b == "equivalent":
        choice, damping = "equivalent", params.equivalent_damping
    else:
        choice = "paper" if math.isclose(float(b), PAPER_DAMPING) else "custom"
        damping = float(b)
    offset = TABLE1_SPRING_PRELOAD - params.spool.spring_preload
    has_area, has_offset = params.calibration.net_area is not None, not math.isclose(offset, 0.0, abs_tol=1e-12)
    kind: Any = ("both" if has_offset else "net_area") if has_area else ("force_offset" if has_offset else "as printed")
    return InForce(model, choice, damping, kind, params.net_area, offset)


def with_damping(params: ValveParams, choice: float | str | None) -> ValveParams:
    """``params`` with the simplified model's damping set by name or value (None: unchanged)."""
    if choice is None:
        return params
    value: float | str = PAPER_DAMPING if choice == "paper" else choice
    return replace_param(params, "spool.viscous_friction_simplified", value)
