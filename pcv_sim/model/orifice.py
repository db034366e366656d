"""Orifice flow from laminar to turbulent (Sec. 4.2, Eqs. 16-27).

Sign convention: a flow is positive in the direction of its pressure drop dp = p_upstream -
p_downstream (Pa); flows in m^3/s, areas in m^2. The pump-side orifice meters pump -> load
(opens for x > 0), the tank-side orifice meters load -> tank (opens for x < 0). The paper's fits
take the spool position in mm (`x_mm`); geometry takes metres.

The discharge coefficient depends on dp through |dp|^gamma; at dp = 0 every flow here is exactly
0 and the laminar gap law is linear in dp, so no regularisation of sqrt(|dp|) is needed except
in the hole law, which is continuous (|dp|^(gamma + 1/2) with gamma >= 0).
"""

from __future__ import annotations

import math

from pcv_sim.jit import jit

__all__ = [
    "blend",
    "gap_discharge_coefficient",
    "gap_geometry_factor",
    "hole_discharge_coefficient",
    "hole_geometry_factor",
    "orifice_flow",
    "pump_area",
    "pump_discharge_coefficient",
    "segment_area",
    "tank_area",
    "tank_discharge_coefficient",
    "tank_geometry_factor",
    "transition_exponent",
]


@jit(inline=True)
def segment_area(opening: float, radius: float) -> float:
    """Eq. 17, one hole: the area of a round hole of `radius` uncovered by `opening` (both m).

    A circular segment: 1/2 r^2 (theta - sin theta) with theta = 2 acos((r - s)/r), s clipped to
    0..2r (closed .. fully open).
    """
    if opening <= 0.0:
        return 0.0
    if opening >= 2.0 * radius:
        return math.pi * radius * radius
    theta = 2.0 * math.acos((radius - opening) / radius)
    return 0.5 * radius * radius * (theta - math.sin(theta))


@jit(inline=True)
def pump_area(x: float, radius: float, count: int, gap_height: float) -> float:
    """Eq. 17: pump-side opening area A(x) (m^2): `count` holes plus a plane gap 2 r h_gap at each."""
    return count * (segment_area(x, radius) + 2.0 * radius * gap_height)


@jit(inline=True)
def tank_area(
    x: float, radius: float, count: int, gap_height: float, pilot_radius: float, hole_offset: float
) -> float:
    """Tank-side opening area (m^2), "modelled in the same manner but also considering the small
    initial hole" (Sec. 4.2, reading R10): the pilot hole opens at x = 0, the `count` holes
    `hole_offset` later, each with its plane leakage gap. The opening is max(-x, 0)."""
    s = -x if x < 0.0 else 0.0
    holes = count * (segment_area(s - hole_offset, radius) + 2.0 * radius * gap_height)
    return holes + segment_area(s, pilot_radius) + 2.0 * pilot_radius * gap_height


@jit(inline=True)
def gap_geometry_factor(x_mm: float, fit: tuple[float, ...]) -> float:
    """Eq. 21: g_g(x) = a1 exp(b1 x) + a2 exp(b2 x), x in mm."""
    return fit[0] * math.exp(fit[1] * x_mm) + fit[2] * math.exp(fit[3] * x_mm)


@jit(inline=True)
def gap_discharge_coefficient(g_g: float, area: float, perimeter: float, nu: float, rho: float, dp: float) -> float:
    """Eqs. 18-19 solved in closed form (reading R5): laminar gap flow.

    C_q = g_g sqrt(Re) with Re = 4 q / (O nu) and q = C_q A sqrt(2|dp|/rho) (Eq. 16) give
    C_q = g_g^2 * 4 A sqrt(2|dp|/rho) / (O nu), so q = g_g^2 8 A^2 |dp| / (O nu rho): q is
    proportional to dp, as the text says of laminar gap leakage. O is the wetted perimeter.
    """
    return g_g * g_g * 4.0 * area * math.sqrt(2.0 * abs(dp) / rho) / (perimeter * nu)


@jit(inline=True)
def hole_geometry_factor(x_mm: float, fit: tuple[tuple[float, ...], ...]) -> float:
    """Eq. 22: g(x) = sum a_k sin(b_k x + c_k), x in mm."""
    total = 0.0
    for k in range(len(fit)):
        total += fit[k][0] * math.sin(fit[k][1] * x_mm + fit[k][2])
    return total


@jit(inline=True)
def transition_exponent(s_mm: float, fit: tuple[float, ...]) -> float:
    """Eqs. 23 and 25: gamma(s) = (pi/2 - atan(k (s - s0))) * span / pi, between span and 0.

    gamma = 1/2 would be laminar (q ~ dp), gamma = 0 turbulent (q ~ sqrt(dp)).
    """
    return (0.5 * math.pi - math.atan(fit[0] * (s_mm - fit[1]))) * fit[2] / math.pi


@jit(inline=True)
def hole_discharge_coefficient(g: float, gamma: float, dp: float) -> float:
    """Eq. 20: C_q,hole = g(x) |dp|^gamma(x), dp in Pa (reading R6)."""
    adp = abs(dp)
    return g * adp**gamma if adp > 0.0 else 0.0


@jit(inline=True)
def blend(x_mm: float, steepness: float) -> float:
    """Eq. 27 (reading R7): logistic L(x) = 1 / (1 + exp(-k x_mm)), written without overflow."""
    z = steepness * x_mm
    if z >= 0.0:
        return 1.0 / (1.0 + math.exp(-z))
    e = math.exp(z)
    return e / (1.0 + e)


@jit(inline=True)
def pump_discharge_coefficient(cq_gap: float, cq_hole: float, weight: float) -> float:
    """Eq. 26: C_q = C_q,gap (1 - L) + C_q,hole L, a smooth hand-over from gap to holes at x = 0."""
    return cq_gap * (1.0 - weight) + cq_hole * weight


@jit(inline=True)
def tank_geometry_factor(s_mm: float, fit: tuple[tuple[float, ...], ...]) -> float:
    """Eq. 24 (reading R8): g_r(s) = sum a exp(-((s - b)/c)^2), s = tank opening in mm."""
    total = 0.0
    for k in range(len(fit)):
        z = (s_mm - fit[k][1]) / fit[k][2]
        total += fit[k][0] * math.exp(-z * z)
    return total


@jit(inline=True)
def tank_discharge_coefficient(g_r: float, gamma_r: float, dp: float) -> float:
    """Eqs. 24-25 with Eq. 20's form: C_q,r = g_r |dp|^gamma_r (gap leakage lumped in)."""
    adp = abs(dp)
    return g_r * adp**gamma_r if adp > 0.0 else 0.0


@jit(inline=True)
def orifice_flow(cq: float, area: float, dp: float, rho: float) -> float:
    """Eq. 16: q = C_q A sqrt(2 |dp| / rho), signed like dp (m^3/s)."""
    q = cq * area * math.sqrt(2.0 * abs(dp) / rho)
    return q if dp >= 0.0 else -q
