"""pcv_sim.model.solenoid: Eqs. 1-13 of the paper (the flux-linkage solenoid and its force map).

Reference values are hand-evaluated from Table 1's numbers, written out here (not read from the
config), with each power spelled out rather than through Horner's scheme.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from pcv_sim.model import solenoid as sol
from pcv_sim.model.valve import ValveModel
from pcv_sim.params import default_params

# Table 1 (paper appendix A.2), highest power first, as printed.
PF1 = (-69.18, 335.12, -449.62, 99.99, 36.65, 324.00)          # p_f11..p_f16
PF2 = (15.23, -72.02, 87.96, -7.55, -5.17, -31.69)             # p_f21..p_f26
PF3 = (2.13, -9.48, 19.14)                                      # p_f31..p_f33
PD = (-0.0004, -0.0003, 0.0472, 0.0059)                         # p_d1..p_d4
PFS = (
    (-1.06, 4.30, -2.30, -1.55),                                # p_fs11..p_fs14
    (6.07, -23.45, 9.16, 14.69),                                # p_fs21..p_fs24
    (-12.83, 47.77, -17.55, -41.77),                            # p_fs31..p_fs34
    (10.76, -40.61, 23.38, 47.33),                              # p_fs41..p_fs44
)
R = 5.6  # ohm, reading R16: 0.7 * 12 V / 1.5 A


def test_config_carries_table_1_solenoid_constants() -> None:
    s = default_params().solenoid
    assert (s.restoring_f1, s.restoring_f2, s.restoring_f3, s.dissipating, s.force) == (PF1, PF2, PF3, PD, PFS)


def test_solenoid_force_matches_hand_evaluated_eqs_9_to_13() -> None:
    z, i = 1.7, 1.5   # core 1.7 mm (spool x = 0, reading R2), the working-point current
    # Eqs. 10-13, each a cubic in the core position (mm), powers written out:
    k1 = -1.06 * z**3 + 4.30 * z**2 - 2.30 * z - 1.55
    k2 = 6.07 * z**3 - 23.45 * z**2 + 9.16 * z + 14.69
    k3 = -12.83 * z**3 + 47.77 * z**2 - 17.55 * z - 41.77
    k4 = 10.76 * z**3 - 40.61 * z**2 + 23.38 * z + 47.33
    expected = k1 * i**5 + k2 * i**4 + k3 * i**3 + k4 * i**2      # Eq. 9
    got = sol.solenoid_force(i, z, PFS)
    # Horner vs expanded powers differ only by rounding: rel 1e-12.
    assert got == pytest.approx(expected, rel=1e-12)
    # Plausibility (docs/model.md R1): the static balance at 120 bar needs ~37-39 N from the solenoid.
    assert 30.0 < got < 45.0
    # Eq. 9 has no i^1 or i^0 term: no force without current.
    assert sol.solenoid_force(0.0, z, PFS) == 0.0


def test_restoring_coefficients_hand_evaluated() -> None:
    z = 1.2
    f1 = -69.18 * z**5 + 335.12 * z**4 - 449.62 * z**3 + 99.99 * z**2 + 36.65 * z + 324.00   # Eq. 5
    f2 = 15.23 * z**5 - 72.02 * z**4 + 87.96 * z**3 - 7.55 * z**2 - 5.17 * z - 31.69         # Eq. 6
    f3 = 2.13 * z**2 - 9.48 * z + 19.14                                                        # Eq. 7
    assert sol.restoring_coefficients(z, PF1, PF2, PF3) == pytest.approx((f1, f2, f3), rel=1e-12)
    lam = 0.08
    assert sol.restoring_current(lam, f1, f2, f3) == pytest.approx(f1 * lam**3 + f2 * lam**2 + f3 * lam, rel=1e-12)  # Eq. 4


def test_poly_is_highest_power_first() -> None:
    assert sol.poly((2.0, 3.0, 5.0), 10.0) == 235.0   # 2*100 + 3*10 + 5
    assert sol.poly(np.array([2.0, 3.0, 5.0]), 10.0) == 235.0   # arrays too (the compiled core passes arrays)


@pytest.mark.parametrize("core_mm", [1.0, 1.15, 1.7, 2.2, 2.55])
def test_coefficients_at_agrees_with_the_generic_functions(core_mm: float) -> None:
    c1, c2, c3, k1, k2, k3, k4 = sol.coefficients_at(core_mm, PF1, PF2, PF3, PFS)
    assert (c1, c2, c3) == pytest.approx(sol.restoring_coefficients(core_mm, PF1, PF2, PF3), rel=1e-13)
    assert (k1, k2, k3, k4) == pytest.approx(tuple(sol.poly(row, core_mm) for row in PFS), rel=1e-13)
    for i in (0.3, 1.07, 1.5, 2.1):
        assert sol.force_from_coefficients(i, k1, k2, k3, k4) == pytest.approx(
            sol.solenoid_force(i, core_mm, PFS), rel=1e-13)


def test_dissipating_current_eq_8() -> None:
    assert sol.dissipating_current(0.0, PD) == 0.0059                      # p_d4
    v = 3.6
    assert sol.dissipating_current(v, PD) == pytest.approx(
        -0.0004 * v**3 - 0.0003 * v**2 + 0.0472 * v + 0.0059, rel=1e-12)
    h = 1e-6
    for v in (-8.0, 0.0, 3.6, 10.0):
        fd = (sol.dissipating_current(v + h, PD) - sol.dissipating_current(v - h, PD)) / (2 * h)
        assert sol.dissipating_slope(v, PD) == pytest.approx(fd, rel=1e-7)   # cubic: central FD exact to rounding


@pytest.mark.parametrize(
    ("i_r", "v_s"),
    [(1.3, 8.4), (1.3, 12.0), (1.3, 0.0), (0.0, 6.0), (2.0, 12.0), (0.8, 3.0), (0.64, 12.0)],
)
@pytest.mark.parametrize("guess", [None, 1.5, 5.0, -3.0])
def test_solve_current_satisfies_the_algebraic_loop(i_r: float, v_s: float, guess: float | None) -> None:
    """Eqs. 1-2 (readings R17, R29): i = i_R + d(V_s - i R) with V_L in d clamped to the cubic's
    rising range, from a good or a poor first guess."""
    i0 = i_r if guess is None else guess
    i = sol.solve_current(i_r, v_s, R, PD, i0)
    assert abs(i - i_r - _clamped_d(v_s - i * R)) < 1e-10


def _clamped_d(v_l: float) -> float:
    """Eq. 8 with V_L held inside the cubic's rising range (reading R29): -6.53 .. 6.03 V for
    Table 1's p_d, the roots of d'(V) = -0.0012 V^2 - 0.0006 V + 0.0472."""
    root = (0.0006**2 + 4 * 0.0012 * 0.0472) ** 0.5
    lo, hi = (0.0006 + root) / -0.0024, (0.0006 - root) / -0.0024
    return sol.dissipating_current(min(max(v_l, lo), hi), PD)


def test_dissipating_range_is_where_the_cubic_rises() -> None:
    lo, hi = sol.dissipating_range(PD)
    assert lo == pytest.approx(-6.5266, abs=1e-4) and hi == pytest.approx(6.0266, abs=1e-4)
    assert sol.dissipating_slope(lo, PD) == pytest.approx(0.0, abs=1e-12)
    assert sol.dissipating_slope(hi, PD) == pytest.approx(0.0, abs=1e-12)


def test_the_loop_has_no_root_at_zero_flux_and_full_voltage() -> None:
    """Why reading R29 clamps V_L: with Table 1's cubic p_d, d(12 V) = -0.16 A (the fit turns over
    beyond its measured range), and g(i) = i - i_R - d(V_s - i R) stays > 0 for every i when
    i_R = 0 and V_s = 12 V: Eq. 2 has no solution at zero flux under full voltage (a cold start
    to 100 % duty)."""
    assert sol.dissipating_current(12.0, PD) == pytest.approx(-0.6912 - 0.0432 + 0.5664 + 0.0059, rel=1e-12)
    g = [i - sol.dissipating_current(12.0 - i * R, PD) for i in [k * 0.001 for k in range(-3000, 5001)]]
    assert min(g) > 0.1


@pytest.mark.parametrize(
    ("i_r", "v_s", "guess"),
    [
        # Before reading R29 plain Newton returned non-solutions here:
        (1.3, 12.0, 0.0),    # -1.64 A (residual 4.6e-4 A) although a root exists near 1.6 A
        (0.0, 12.0, 0.0),    # -0.71 A: the unclamped Eq. 2 has no root at all (test above)
        (0.5, 0.0, 2.14),    # -7.27 A
        (0.0, 12.0, -50.0),  # a wild guess
        (2.2, 0.0, 50.0),
    ],
)
def test_solve_current_always_returns_the_root(i_r: float, v_s: float, guess: float) -> None:
    """With Eq. 8 clamped to its rising range (R29), g(i) = i - i_R - d(V_s - i R) has g' >= 1:
    exactly one root, which must come back whatever the guess."""
    i = sol.solve_current(i_r, v_s, R, PD, guess)
    assert abs(i - i_r - _clamped_d(v_s - i * R)) < 1e-10
    lo, hi = sol.dissipating_range(PD)
    # The root lies in the bracket [i_R + d(lo), i_R + d(hi)] the docstring names.
    assert i_r + sol.dissipating_current(lo, PD) - 1e-9 <= i <= i_r + sol.dissipating_current(hi, PD) + 1e-9


def test_solve_current_raises_when_no_root_exists() -> None:
    # Unclamped (the paper's cubic as printed over all V_L), zero flux under 12 V has no root.
    with pytest.raises(ArithmeticError, match=r"no coil current solves Eq\. 2 for i_R=0\.0 A, V_s=12\.0 V"):
        sol.solve_current(0.0, 12.0, R, PD, 0.0, v_range=(-math.inf, math.inf))
    with pytest.raises(ArithmeticError, match=r"no coil current solves Eq\. 2 for i_R=nan A"):
        sol.solve_current(math.nan, 12.0, R, PD, 0.0)


@pytest.mark.parametrize(
    ("pd", "expected"),
    [
        ((0.0, 0.0, 0.05, 0.0), (-math.inf, math.inf)),     # linear: rises everywhere
        ((0.0, 0.01, 0.05, 0.0), (-2.5, math.inf)),         # quadratic: d' = 0.02 V + 0.05 >= 0 from -2.5 V
        ((0.0, -0.01, 0.05, 0.0), (-math.inf, 2.5)),        # d' = -0.02 V + 0.05 >= 0 up to 2.5 V
        ((0.001, 0.0, 0.05, 0.0), (-math.inf, math.inf)),   # d' = 0.003 V^2 + 0.05 > 0: no turn-over
    ],
)
def test_dissipating_range_other_shapes(pd: tuple[float, ...], expected: tuple[float, float]) -> None:
    assert sol.dissipating_range(pd) == pytest.approx(expected, rel=1e-12)


def test_current_at_zero_inductive_voltage_is_restoring_plus_p_d4() -> None:
    i_r = 1.2
    v_s = (i_r + 0.0059) * R            # chosen so that V_L = V_s - i R = 0 at the solution
    i = sol.solve_current(i_r, v_s, R, PD, 0.0)
    assert i == pytest.approx(i_r + 0.0059, abs=1e-12)
    assert sol.flux_linkage_derivative(v_s, i, R) == pytest.approx(0.0, abs=1e-10)   # Eq. 3


def test_flux_linkage_derivative_eq_3() -> None:
    assert sol.flux_linkage_derivative(12.0, 1.5, R) == pytest.approx(12.0 - 8.4, rel=1e-15)


@pytest.mark.parametrize("core_mm", [1.15, 1.7, 2.55])
@pytest.mark.parametrize("i", [0.3, 1.0, 1.5, 2.14])
def test_flux_linkage_at_rest_inverts_the_restoring_function(core_mm: float, i: float) -> None:
    c1, c2, c3 = sol.restoring_coefficients(core_mm, PF1, PF2, PF3)
    lam = sol.flux_linkage_at_rest(i, c1, c2, c3, PD)
    assert lam > 0.0
    # At rest V_L = 0, so i = f(lam, x) + p_d4 (Eqs. 2, 4, 8).
    assert sol.restoring_current(lam, c1, c2, c3) + PD[3] == pytest.approx(i, abs=1e-12)


def test_flux_linkage_at_rest_below_the_offset_current_is_zero() -> None:
    c = sol.restoring_coefficients(1.7, PF1, PF2, PF3)
    assert sol.flux_linkage_at_rest(0.005, *c, PD) == 0.0    # 0.005 A < p_d4 = 0.0059 A
    assert sol.flux_linkage_at_rest(0.0, *c, PD) == 0.0


def test_flux_linkage_at_rest_reports_a_failed_inversion() -> None:
    with pytest.raises(ArithmeticError, match=r"no flux linkage found for i=1\.5 A"):
        sol.flux_linkage_at_rest(1.5, 0.0, 0.0, math.nan, PD)


def test_hysteresis_rising_flux_needs_more_current() -> None:
    """Eq. 8: for the same lambda and core position, the current while the flux rises (V_L > 0)
    exceeds the current while it falls (V_L < 0)."""
    model = ValveModel(default_params())
    x = -0.08e-3
    lam = model.flux_linkage_at_rest(1.5, x)
    i_rise = model.current(lam, x, 12.0, 1.5)     # supply on: V_L = 12 - i R > 0
    i_fall = model.current(lam, x, 0.0, 1.5)      # supply off: V_L = -i R < 0
    assert 12.0 - i_rise * R > 0.0 > -i_fall * R
    assert i_rise > i_fall
    # The rest current lies between the two branches.
    assert i_fall < 1.5 < i_rise
    # Size: about p_d3 * dV_L = 0.0472 A/V * 12 V ~ 0.57 A apart (the cubic terms and the loop
    # through R shrink it): between 0.3 and 0.6 A.
    assert 0.3 < i_rise - i_fall < 0.6


@pytest.mark.parametrize(("i", "core_mm"), [(0.5, 1.2), (1.5, 1.7), (1.5, 1.6674), (2.1, 2.5)])
def test_solenoid_force_slope_matches_finite_differences(i: float, core_mm: float) -> None:
    d_di, d_dx = sol.solenoid_force_slope(i, core_mm, PFS)
    h = 1e-6
    fd_i = (sol.solenoid_force(i + h, core_mm, PFS) - sol.solenoid_force(i - h, core_mm, PFS)) / (2 * h)
    fd_x = (sol.solenoid_force(i, core_mm + h, PFS) - sol.solenoid_force(i, core_mm - h, PFS)) / (2 * h)
    # Central differences of polynomials: truncation ~h^2 * F''' ~ 1e-10, rounding ~1e-16 * 40 N / 1e-6 ~ 4e-9.
    assert d_di == pytest.approx(fd_i, rel=1e-7, abs=1e-7)
    assert d_dx == pytest.approx(fd_x, rel=1e-7, abs=1e-7)
