"""Steady flow forces with a stroke-dependent jet angle (Sec. 4.2, Eqs. 30-32).

Sign convention (reading R14): each orifice's steady flow force tends to close that orifice,
in both flow directions. The pump-side force pushes toward -x, the tank-side force toward +x;
Eq. 14 subtracts the net F_f = F_pump - F_tank.
"""

from __future__ import annotations

import math

from pcv_sim.jit import jit

__all__ = ["flow_force", "jet_cosine"]


@jit(inline=True)
def jet_cosine(s_mm: float, fit: tuple[tuple[float, ...], ...], cap: float) -> float:
    """Eqs. 31-32 (readings R8, R9): cos(delta) = min(cap, sum a exp(-((s - b)/c)^2)).

    s is x (pump side, Eq. 31) or |x| (tank side, Eq. 32) in mm. The cap keeps the fit below the
    0.7 it was fitted under; it is a minimum, not a maximum, or cos(delta) would exceed 1.
    """
    total = 0.0
    for k in range(len(fit)):
        z = (s_mm - fit[k][1]) / fit[k][2]
        total += fit[k][0] * math.exp(-z * z)
    return total if total < cap else cap


@jit(inline=True)
def flow_force(cq: float, area: float, dp: float, cos_delta: float) -> float:
    """Eq. 30: F_f = 2 C_q A |dp| cos(delta) (N), the steady jet force of one orifice (>= 0)."""
    return 2.0 * cq * area * abs(dp) * cos_delta
