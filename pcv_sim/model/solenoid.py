"""The solenoid: a resistor in series with a nonlinear, hysteretic inductor (Sec. 4.1, Eqs. 1-13).

State: the flux linkage lambda (Wb). Inputs: the supply voltage V_s (V) and the core position
(mm from the core's end position, positive closes the air gap: `core_mm = x_mm + core_offset_mm`,
reading R2). The paper's fits take the core position in mm; that is the only non-SI quantity here.
"""

from __future__ import annotations

import math

__all__ = [
    "poly",
    "coefficients_at",
    "restoring_coefficients",
    "restoring_current",
    "dissipating_current",
    "dissipating_slope",
    "solve_current",
    "flux_linkage_derivative",
    "solenoid_force",
    "force_from_coefficients",
    "solenoid_force_slope",
    "flux_linkage_at_rest",
]


def poly(coeffs: tuple[float, ...], z: float) -> float:
    """Horner evaluation, highest power first (the order of Table 1)."""
    acc = 0.0
    for c in coeffs:
        acc = acc * z + c
    return acc


def coefficients_at(
    core_mm: float,
    f1: tuple[float, ...],
    f2: tuple[float, ...],
    f3: tuple[float, ...],
    force: tuple[tuple[float, ...], ...],
) -> tuple[float, float, float, float, float, float, float]:
    """Eqs. 5-7 and 10-13 at one core position (mm): (f_1, f_2, f_3, p_fs1, p_fs2, p_fs3, p_fs4).

    The same polynomials as `restoring_coefficients` and `solenoid_force`, unrolled: this runs
    twice per real-time step.
    """
    z = core_mm
    a, b, c, d, e, f = f1
    c1 = ((((a * z + b) * z + c) * z + d) * z + e) * z + f
    a, b, c, d, e, f = f2
    c2 = ((((a * z + b) * z + c) * z + d) * z + e) * z + f
    a, b, c = f3
    c3 = (a * z + b) * z + c
    (a1, b1, c1_, d1), (a2, b2, c2_, d2), (a3, b3, c3_, d3), (a4, b4, c4_, d4) = force
    k1 = ((a1 * z + b1) * z + c1_) * z + d1
    k2 = ((a2 * z + b2) * z + c2_) * z + d2
    k3 = ((a3 * z + b3) * z + c3_) * z + d3
    k4 = ((a4 * z + b4) * z + c4_) * z + d4
    return c1, c2, c3, k1, k2, k3, k4


def force_from_coefficients(i: float, k1: float, k2: float, k3: float, k4: float) -> float:
    """Eq. 9: F_s = p_fs1 i^5 + p_fs2 i^4 + p_fs3 i^3 + p_fs4 i^2 (N)."""
    return (((k1 * i + k2) * i + k3) * i + k4) * i * i


def restoring_coefficients(
    core_mm: float, f1: tuple[float, ...], f2: tuple[float, ...], f3: tuple[float, ...]
) -> tuple[float, float, float]:
    """Eqs. 5-7: f_1(x), f_2(x), f_3(x) of the restoring current, x = core position in mm."""
    return poly(f1, core_mm), poly(f2, core_mm), poly(f3, core_mm)


def restoring_current(lam: float, c1: float, c2: float, c3: float) -> float:
    """Eq. 4: energy-restoring current i_R = f_1 lam^3 + f_2 lam^2 + f_3 lam (A); lam in Wb."""
    return ((c1 * lam + c2) * lam + c3) * lam


def dissipating_current(v_l: float, pd: tuple[float, ...]) -> float:
    """Eq. 8: energy-dissipating current i_d(V_L) = p_d1 V_L^3 + ... + p_d4 (A); V_L in V.

    It carries the magnetic hysteresis: the same flux linkage needs more current while the flux
    rises (V_L > 0) than while it falls.
    """
    return ((pd[0] * v_l + pd[1]) * v_l + pd[2]) * v_l + pd[3]


def dissipating_slope(v_l: float, pd: tuple[float, ...]) -> float:
    """d i_d / d V_L (A/V), for the Newton step of `solve_current`."""
    return (3.0 * pd[0] * v_l + 2.0 * pd[1]) * v_l + pd[2]


def solve_current(
    i_r: float, v_s: float, resistance: float, pd: tuple[float, ...], i_guess: float
) -> float:
    """Eqs. 1-2 as an algebraic loop: the coil current i with i = i_R + d(V_s - i R).

    The dissipating current depends on the inductive voltage V_L = V_s - i R (Eq. 1), which
    depends on i (reading R17). g(i) = i - i_R - d(V_s - iR) has g' = 1 + R d'(V_L) > 0 for
    V_L < 13.4 V with Table 1's p_d, so Newton from the last current converges in 2-3 steps.
    """
    p1, p2, p3, p4 = pd
    i = i_guess
    for _ in range(8):
        v_l = v_s - i * resistance
        g = i - i_r - (((p1 * v_l + p2) * v_l + p3) * v_l + p4)       # Eq. 8 inlined: hot path
        step = g / (1.0 + resistance * ((3.0 * p1 * v_l + 2.0 * p2) * v_l + p3))
        i -= step
        if -1e-12 < step < 1e-12:
            break
    return i


def flux_linkage_derivative(v_s: float, i: float, resistance: float) -> float:
    """Eq. 3: d lambda / dt = V_L = V_s - i R (V = Wb/s)."""
    return v_s - i * resistance


def solenoid_force(i: float, core_mm: float, force: tuple[tuple[float, ...], ...]) -> float:
    """Eqs. 9-13: static solenoid force F_s(i, x) (N), positive closes the air gap (+x).

    Each of p_fs1..p_fs4 is a cubic in the core position (mm); F_s = p_fs1 i^5 + ... + p_fs4 i^2.
    """
    return force_from_coefficients(i, *(poly(row, core_mm) for row in force))


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
