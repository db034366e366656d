"""The solenoid: a resistor in series with a nonlinear, hysteretic inductor (Sec. 4.1, Eqs. 1-13).

State: the flux linkage lambda (Wb). Inputs: the supply voltage V_s (V) and the core position
(mm from the core's end position, positive closes the air gap: `core_mm = x_mm + core_offset_mm`,
reading R2). The paper's fits take the core position in mm; that is the only non-SI quantity here.
"""

from __future__ import annotations

import math
from typing import Any

from pcv_sim.jit import jit

__all__ = [
    "coefficients_at",
    "dissipating_current",
    "dissipating_range",
    "dissipating_slope",
    "flux_linkage_at_rest",
    "flux_linkage_derivative",
    "force_from_coefficients",
    "poly",
    "restoring_coefficients",
    "restoring_current",
    "solenoid_force",
    "solenoid_force_slope",
    "solve_current",
    "solve_current_in",
]


@jit(inline=True)
def poly(coeffs, z):
    """Horner evaluation, highest power first (the order of Table 1)."""
    acc = 0.0
    for c in coeffs:
        acc = acc * z + c
    return acc


@jit(inline=True)
def coefficients_at(core_mm, f1, f2, f3, force):
    """Eqs. 5-7 and 10-13 at one core position (mm): (f_1, f_2, f_3, p_fs1, p_fs2, p_fs3, p_fs4).

    The same polynomials as `restoring_coefficients` and `solenoid_force`, in one pass: this runs
    twice per real-time step. `force` is 4 rows of 4 (tuples or a 4x4 array).
    """
    z = core_mm
    c1 = poly(f1, z)
    c2 = poly(f2, z)
    c3 = poly(f3, z)
    k1 = ((force[0][0] * z + force[0][1]) * z + force[0][2]) * z + force[0][3]
    k2 = ((force[1][0] * z + force[1][1]) * z + force[1][2]) * z + force[1][3]
    k3 = ((force[2][0] * z + force[2][1]) * z + force[2][2]) * z + force[2][3]
    k4 = ((force[3][0] * z + force[3][1]) * z + force[3][2]) * z + force[3][3]
    return c1, c2, c3, k1, k2, k3, k4


@jit(inline=True)
def force_from_coefficients(i: float, k1: float, k2: float, k3: float, k4: float) -> float:
    """Eq. 9: F_s = p_fs1 i^5 + p_fs2 i^4 + p_fs3 i^3 + p_fs4 i^2 (N)."""
    return (((k1 * i + k2) * i + k3) * i + k4) * i * i


def restoring_coefficients(core_mm: float, f1: Any, f2: Any,
                           f3: Any) -> tuple[float, float, float]:
    """Eqs. 5-7: f_1(x), f_2(x), f_3(x) of the restoring current, x = core position in mm (fits as
    tuples or arrays)."""
    return poly(f1, core_mm), poly(f2, core_mm), poly(f3, core_mm)


@jit(inline=True)
def restoring_current(lam: float, c1: float, c2: float, c3: float) -> float:
    """Eq. 4: energy-restoring current i_R = f_1 lam^3 + f_2 lam^2 + f_3 lam (A); lam in Wb."""
    return ((c1 * lam + c2) * lam + c3) * lam


@jit(inline=True)
def dissipating_current(v_l, pd):
    """Eq. 8: energy-dissipating current i_d(V_L) = p_d1 V_L^3 + ... + p_d4 (A); V_L in V.

    It carries the magnetic hysteresis: the same flux linkage needs more current while the flux
    rises (V_L > 0) than while it falls.
    """
    return ((pd[0] * v_l + pd[1]) * v_l + pd[2]) * v_l + pd[3]


def dissipating_slope(v_l: float, pd: tuple[float, ...]) -> float:
    """d i_d / d V_L (A/V), for the Newton step of `solve_current`."""
    return (3.0 * pd[0] * v_l + 2.0 * pd[1]) * v_l + pd[2]


def dissipating_range(pd: tuple[float, ...]) -> tuple[float, float]:
    """The V_L interval where Eq. 8's cubic rises (d' >= 0): its fit range (reading R29).

    With Table 1's p_d that is -6.53 .. 6.03 V. Outside it the cubic turns over (d(12 V) =
    -0.16 A), which would give Eq. 2 no root for a 0 -> 100 % step from zero flux.
    """
    a, b, c = 3.0 * pd[0], 2.0 * pd[1], pd[2]
    if a == 0.0:
        return (-math.inf, math.inf) if b == 0.0 else ((-c / b, math.inf) if b > 0 else (-math.inf, -c / b))
    disc = b * b - 4.0 * a * c
    if disc <= 0.0:
        return (-math.inf, math.inf)
    r1, r2 = sorted(((-b - math.sqrt(disc)) / (2 * a), (-b + math.sqrt(disc)) / (2 * a)))
    return (r1, r2) if a < 0 else (-math.inf, math.inf)


def solve_current(
    i_r: float, v_s: float, resistance: float, pd: tuple[float, ...], i_guess: float,
    v_range: tuple[float, float] | None = None,
) -> float:
    """Eqs. 1-2 as an algebraic loop: the coil current i with i = i_R + d(V_s - i R).

    The dissipating current depends on the inductive voltage V_L = V_s - i R (Eq. 1), which
    depends on i (reading R17). Eq. 8 is evaluated with V_L clamped to `v_range`, where the
    cubic rises (reading R29, `dissipating_range`); then g(i) = i - i_R - d(V_s - iR) has
    g' = 1 + R d' >= 1, one root, and it lies in [i_R + d(lo), i_R + d(hi)]. Newton from the last
    current converges in 2-3 steps; bisection on that bracket backs it up.
    """
    lo, hi = dissipating_range(pd) if v_range is None else v_range
    try:
        return float(solve_current_in(i_r, v_s, resistance, pd, i_guess, lo, hi))
    except ArithmeticError as err:
        raise ArithmeticError(f"no coil current solves Eq. 2 for i_R={i_r!r} A, V_s={v_s!r} V ({err})") from None


@jit(inline=True)
def solve_current_in(i_r, v_s, resistance, pd, i_guess, v_lo, v_hi):
    """`solve_current` with the clamp interval given (the compiled kernel's form)."""
    p1, p2, p3, p4 = pd[0], pd[1], pd[2], pd[3]
    i = i_guess
    for _ in range(8):
        v_l = v_s - i * resistance
        if v_l > v_hi:
            v_l, slope = v_hi, 0.0
        elif v_l < v_lo:
            v_l, slope = v_lo, 0.0
        else:
            slope = (3.0 * p1 * v_l + 2.0 * p2) * v_l + p3
        g = i - i_r - (((p1 * v_l + p2) * v_l + p3) * v_l + p4)       # Eq. 8 inlined: hot path
        step = g / (1.0 + resistance * slope)
        i -= step
        if -1e-12 < step < 1e-12:
            return i
    return _bisect_current(i_r, v_s, resistance, pd, v_lo, v_hi)


@jit(inline=True)
def _current_residual(i, i_r, v_s, resistance, pd, v_lo, v_hi):
    v_l = min(max(v_s - i * resistance, v_lo), v_hi)
    return i - i_r - dissipating_current(v_l, pd)


@jit(inline=True)
def _bisect_current(i_r, v_s, resistance, pd, v_lo, v_hi):
    lo = i_r + dissipating_current(v_lo, pd) - 1e-9
    hi = i_r + dissipating_current(v_hi, pd) + 1e-9
    if not (math.isfinite(lo) and math.isfinite(hi)):
        raise ArithmeticError("no coil current solves Eq. 2: the state is not finite")
    if not (_current_residual(lo, i_r, v_s, resistance, pd, v_lo, v_hi) <= 0.0
            <= _current_residual(hi, i_r, v_s, resistance, pd, v_lo, v_hi)):
        raise ArithmeticError("no coil current solves Eq. 2 in its bracket")
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        if _current_residual(mid, i_r, v_s, resistance, pd, v_lo, v_hi) > 0.0:
            hi = mid
        else:
            lo = mid
        if hi - lo < 1e-13:
            break
    return 0.5 * (lo + hi)


@jit(inline=True)
def flux_linkage_derivative(v_s: float, i: float, resistance: float) -> float:
    """Eq. 3: d lambda / dt = V_L = V_s - i R (V = Wb/s)."""
    return v_s - i * resistance


def solenoid_force(i: float, core_mm: float, force: tuple[tuple[float, ...], ...]) -> float:
    """Eqs. 9-13: static solenoid force F_s(i, x) (N), positive closes the air gap (+x).

    Each of p_fs1..p_fs4 is a cubic in the core position (mm); F_s = p_fs1 i^5 + ... + p_fs4 i^2.
    """
    k = [poly(row, core_mm) for row in force]
    return force_from_coefficients(i, k[0], k[1], k[2], k[3])


def solenoid_force_slope(i: float, core_mm: float, force: tuple[tuple[float, ...], ...]) -> tuple[float, float]:
    """(dF_s/di in N/A, dF_s/dx in N/mm): K_fi and K_fx of appendix A.1, analytically."""
    k = [poly(row, core_mm) for row in force]
    dk = [poly(tuple(c * p for c, p in zip(row[:-1], (3, 2, 1))), core_mm) for row in force]
    d_di = ((5 * k[0] * i + 4 * k[1]) * i + 3 * k[2]) * i * i + 2 * k[3] * i
    d_dx = (((dk[0] * i + dk[1]) * i + dk[2]) * i + dk[3]) * i * i
    return d_di, d_dx


def flux_linkage_at_rest(i: float, c1: float, c2: float, c3: float, pd: tuple[float, ...]) -> float:
    """The flux linkage at steady state (V_L = 0): solves f(lam, x) + p_d4 = i for lam >= 0.

    Used for initial conditions. f is monotonic in lam over the working range, so Newton from
    the linear estimate converges.
    """
    target = i - dissipating_current(0.0, pd)
    if target <= 0.0:
        return 0.0
    lam = target / c3
    for _ in range(50):
        g = restoring_current(lam, c1, c2, c3) - target
        dg = (3.0 * c1 * lam + 2.0 * c2) * lam + c3
        step = g / dg
        lam -= step
        if abs(step) < 1e-14:
            break
    if not math.isfinite(lam):
        raise ArithmeticError(f"no flux linkage found for i={i} A")
    return lam
