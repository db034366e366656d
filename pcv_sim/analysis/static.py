"""Static characteristic (the paper's Fig. 10): pressure-flow curves from the valve's rest states.

The rest states themselves (Eq. 14 at rest with continuity Eq. 15) are in
`pcv_sim.model.statics`; their names are re-exported here for the analysis commands.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pcv_sim.model.statics import (
    EquilibriumError,
    StaticPoint,
    balance_pressure,
    equilibrium_at_flow,
    static_point,
    stop_point,
    zero_flow_equilibrium,
)
from pcv_sim.model.valve import ValveModel
from pcv_sim.params import ValveParams

__all__ = [
    "EquilibriumError",
    "PressureFlowCurve",
    "StaticPoint",
    "balance_pressure",
    "equilibrium_at_flow",
    "pressure_flow_curve",
    "static_point",
    "stop_point",
    "zero_flow_equilibrium",
]


@dataclass(frozen=True)
class PressureFlowCurve:
    """A static pressure-flow curve at one duty, ordered by spool position."""

    duty: float
    spool_position: np.ndarray   # m
    pressure: np.ndarray         # Pa
    load_flow: np.ndarray        # m^3/s


def pressure_flow_curve(
    params: ValveParams | ValveModel, duty: float, points: int = 100, supply_pressure: float | None = None
) -> PressureFlowCurve:
    """The static pressure-flow curve at duty D over the stroke (Fig. 10 a and b).

    Spool positions where no free equilibrium exists (at low duty and large opening the
    solenoid cannot hold the spool at any pressure) are left out.
    """
    model = params if isinstance(params, ValveModel) else ValveModel(params)
    xs, ps, qs = [], [], []
    for x in np.linspace(model.x_min, model.x_max, points):
        try:
            pt = static_point(model, duty, float(x), supply_pressure)
        except EquilibriumError:
            continue
        xs.append(pt.spool_position)
        ps.append(pt.pressure)
        qs.append(pt.load_flow)
    return PressureFlowCurve(duty, np.array(xs), np.array(ps), np.array(qs))
