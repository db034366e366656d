"""pcv_sim.model.orifice: Eqs. 16-27 (areas, discharge coefficients, orifice flow).

Geometry from Sec. 2 and Table 1: 12 holes of 1.5 mm diameter (r = 0.75 mm, reading R4),
h_gap = 15 um, a 0.8 mm pilot hole on the tank side, the 12 tank holes 0.3 mm after it.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from pcv_sim.model import orifice as orf
from pcv_sim.model.valve import ValveModel
from pcv_sim.params import default_params

R_HOLE = 0.75e-3      # m, Sec. 2: 1.5 mm diameter (R4)
N_HOLES = 12          # Sec. 2
H_GAP = 1.5e-5        # m, Table 1
R_PILOT = 0.4e-3      # m, Sec. 2: 0.8 mm diameter
OFFSET = 0.3e-3       # m, Sec. 2
RHO, NU = 900.0, 46e-6   # Table 1


def segment_by_chord(s: float, r: float) -> float:
    """Independent closed form of a circular segment of height s: r^2 acos((r-s)/r) - (r-s) sqrt(2rs - s^2)."""
    s = min(max(s, 0.0), 2 * r)
    return r * r * math.acos((r - s) / r) - (r - s) * math.sqrt(max(2 * r * s - s * s, 0.0))


# --- areas ---------------------------------------------------------------------------------


def test_segment_area_limits() -> None:
    r = R_HOLE
    assert orf.segment_area(0.0, r) == 0.0
    assert orf.segment_area(-1e-3, r) == 0.0
    assert orf.segment_area(r, r) == pytest.approx(math.pi * r * r / 2, rel=1e-12)      # half open
    assert orf.segment_area(2 * r, r) == pytest.approx(math.pi * r * r, rel=1e-12)      # fully open
    assert orf.segment_area(5 * r, r) == pytest.approx(math.pi * r * r, rel=1e-12)      # beyond: still the hole


@pytest.mark.parametrize("s", [1e-6, 0.05e-3, 0.2e-3, 0.5e-3, 0.75e-3, 1.1e-3, 1.49e-3])
def test_segment_area_matches_the_chord_formula(s: float) -> None:
    # Two closed forms of the same area; near s = 0 both lose relative precision to cancellation.
    assert orf.segment_area(s, R_HOLE) == pytest.approx(segment_by_chord(s, R_HOLE), rel=1e-7)


def test_segment_area_is_monotonic() -> None:
    s = np.linspace(-0.1e-3, 1.7e-3, 721)
    a = np.array([orf.segment_area(float(v), R_HOLE) for v in s])
    assert np.all(np.diff(a) >= 0.0)
    assert np.all(np.diff(a[(s > 0) & (s < 2 * R_HOLE)]) > 0.0)


@pytest.mark.parametrize("x", [0.0, -1e-9, -0.1e-3, -0.55e-3])
def test_pump_area_when_closed_is_the_gap_leakage(x: float) -> None:
    # Eq. 17 with the segment term zero: 12 * 2 r h_gap = 12 * 2 * 0.75e-3 * 1.5e-5 = 2.7e-7 m^2 (reading R25).
    assert orf.pump_area(x, R_HOLE, N_HOLES, H_GAP) == pytest.approx(2.7e-7, rel=1e-12)


def test_pump_area_open() -> None:
    x = 0.3e-3
    expected = 12 * (segment_by_chord(x, R_HOLE) + 2 * R_HOLE * H_GAP)
    assert orf.pump_area(x, R_HOLE, N_HOLES, H_GAP) == pytest.approx(expected, rel=1e-9)
    # Fully open (x >= 2r = 1.5 mm): 12 pi r^2 + the gaps = 2.1206e-5 + 2.7e-7 m^2.
    assert orf.pump_area(1.5e-3, R_HOLE, N_HOLES, H_GAP) == pytest.approx(12 * math.pi * R_HOLE**2 + 2.7e-7, rel=1e-12)


def tank(x: float) -> float:
    return orf.tank_area(x, R_HOLE, N_HOLES, H_GAP, R_PILOT, OFFSET)


def test_tank_area_closed_is_the_leakage_of_all_holes() -> None:
    # x >= 0: 12 gaps 2 r h + the pilot's gap 2 r_p h = 2.7e-7 + 1.2e-8 = 2.82e-7 m^2 (Sec. 2 geometry, R10).
    for x in (0.0, 0.1e-3, 0.85e-3):
        assert tank(x) == pytest.approx(2.82e-7, rel=1e-12)


def test_tank_area_pilot_first_then_the_twelve_holes() -> None:
    closed = tank(0.0)
    # Before the 0.3 mm offset only the 0.8 mm pilot hole opens.
    for s in (0.05e-3, 0.2e-3, 0.3e-3):
        assert tank(-s) - closed == pytest.approx(segment_by_chord(s, R_PILOT), rel=1e-7)
    # 0.1 mm beyond the offset the 12 big holes add their segments.
    s = 0.4e-3
    expected = segment_by_chord(s, R_PILOT) + 12 * segment_by_chord(s - OFFSET, R_HOLE)
    assert tank(-s) - closed == pytest.approx(expected, rel=1e-7)


def test_tank_area_grows_as_x_goes_negative() -> None:
    xs = np.linspace(0.0, -0.55e-3, 221)
    a = np.array([tank(float(x)) for x in xs])
    assert np.all(np.diff(a) > 0.0)
    # The gradient jumps where the 12 holes start (the "smoother area gradient" of Sec. 2 before it).
    slope_before = (tank(-0.29e-3) - tank(-0.28e-3)) / 0.01e-3
    slope_after = (tank(-0.36e-3) - tank(-0.35e-3)) / 0.01e-3
    assert slope_after > 5 * slope_before


# --- discharge coefficients ------------------------------------------------------------------


def test_gap_geometry_factor_eq_21() -> None:
    fit = default_params().fits.gap_geometry
    assert fit == (0.02477, 1.314, 0.0642, 24.41)   # Eq. 21 as printed
    assert orf.gap_geometry_factor(0.0, fit) == pytest.approx(0.02477 + 0.0642, rel=1e-14)
    x = -0.1
    assert orf.gap_geometry_factor(x, fit) == pytest.approx(
        0.02477 * math.exp(1.314 * x) + 0.0642 * math.exp(24.41 * x), rel=1e-14)


@pytest.mark.parametrize("x_mm", [0.0, -0.05, -0.3])
@pytest.mark.parametrize("dp", [1e5, 80e5, 190e5])
def test_gap_law_is_eqs_18_19_and_laminar(x_mm: float, dp: float) -> None:
    """Reading R5: C_q = g_g sqrt(Re), Re = 4 q / (O nu), q = C_q A sqrt(2 dp / rho), all at once."""
    fit = default_params().fits.gap_geometry
    area = orf.pump_area(x_mm * 1e-3, R_HOLE, N_HOLES, H_GAP)
    perimeter = 12 * 2 * (2 * R_HOLE + H_GAP)       # wetted perimeter of 12 slots 2r x h_gap
    g_g = orf.gap_geometry_factor(x_mm, fit)

    def flow(p: float) -> tuple[float, float]:
        cq = orf.gap_discharge_coefficient(g_g, area, perimeter, NU, RHO, p)
        return cq, orf.orifice_flow(cq, area, p, RHO)

    cq, q = flow(dp)
    re = 4 * q / (perimeter * NU)                                    # Eq. 18
    assert cq == pytest.approx(g_g * math.sqrt(re), rel=1e-12)       # Eq. 19
    # Laminar: q proportional to dp, so doubling the drop doubles the flow.
    assert flow(2 * dp)[1] == pytest.approx(2 * q, rel=1e-12)
    # Closed form: q = 8 g_g^2 A^2 dp / (O nu rho).
    assert q == pytest.approx(8 * g_g**2 * area**2 * dp / (perimeter * NU * RHO), rel=1e-12)


def test_model_uses_the_slot_perimeter() -> None:
    assert ValveModel(default_params()).gap_perimeter == pytest.approx(12 * 2 * (2 * R_HOLE + H_GAP), rel=1e-15)


def test_hole_coefficient_and_exponent_eqs_20_23() -> None:
    f = default_params().fits
    x = 0.2
    g = (0.3973 * math.sin(3.493 * x - 0.6221) + 3.789 * math.sin(6.942 * x + 1.088)
         + 3.626 * math.sin(7.047 * x + 4.173) + 0.0009295 * math.sin(22.45 * x + 2.653))   # Eq. 22
    assert orf.hole_geometry_factor(x, f.hole_geometry) == pytest.approx(g, rel=1e-12)
    gamma = (-math.atan(5 * (x - 0.3)) + math.pi / 2) * 0.3 / math.pi                       # Eq. 23
    assert orf.transition_exponent(x, f.hole_exponent) == pytest.approx(gamma, rel=1e-14)
    assert orf.hole_discharge_coefficient(g, gamma, 50e5) == pytest.approx(g * 50e5**gamma, rel=1e-14)  # Eq. 20, Pa (R6)
    assert orf.hole_discharge_coefficient(g, gamma, -50e5) == orf.hole_discharge_coefficient(g, gamma, 50e5)
    assert orf.hole_discharge_coefficient(g, gamma, 0.0) == 0.0


@pytest.mark.parametrize("fit", [(5.0, 0.3, 0.3), (10.0, 0.4, 0.3)])
def test_transition_exponent_between_zero_and_span(fit: tuple[float, float, float]) -> None:
    _k, s0, span = fit
    s = np.linspace(-50.0, 50.0, 2001)
    g = np.array([orf.transition_exponent(float(v), fit) for v in s])
    assert np.all((g > 0.0) & (g < span))
    assert np.all(np.diff(g) < 0.0)                                   # laminar -> turbulent as it opens
    assert orf.transition_exponent(s0, fit) == pytest.approx(span / 2, rel=1e-14)
    assert orf.transition_exponent(-1e9, fit) == pytest.approx(span, rel=1e-9)
    assert orf.transition_exponent(1e9, fit) == pytest.approx(0.0, abs=1e-9)


def test_tank_coefficient_eqs_24_25() -> None:
    f = default_params().fits
    s = 0.5556
    g_r = 0.1267 + 10880 * math.exp(-(((s - 3.269) / 0.7823) ** 2))   # Eq. 24 as a Gaussian sum (R8)
    assert orf.tank_geometry_factor(s, f.tank_geometry) == pytest.approx(g_r, rel=1e-12)
    gamma_r = (-math.atan(10 * (abs(s) - 0.4)) + math.pi / 2) * 0.3 / math.pi                    # Eq. 25
    assert orf.transition_exponent(s, f.tank_exponent) == pytest.approx(gamma_r, rel=1e-14)
    assert orf.tank_discharge_coefficient(g_r, gamma_r, 1e6) == pytest.approx(g_r * 1e6**gamma_r, rel=1e-14)
    assert orf.tank_discharge_coefficient(g_r, gamma_r, 0.0) == 0.0


def test_blend_is_the_logistic_of_eq_27() -> None:
    k = 1000.0
    assert orf.blend(0.0, k) == 0.5
    assert orf.blend(0.001, k) == pytest.approx(1 / (1 + math.exp(-1.0)), rel=1e-14)    # x = 1 um
    for x in (1e-4, 3e-3, 0.2):
        assert orf.blend(x, k) + orf.blend(-x, k) == pytest.approx(1.0, rel=1e-14)
    # Overflow-free far from 0 (as printed, 1/(1 - e^{1000 x}) would overflow and be singular at 0).
    assert orf.blend(1e6, k) == 1.0
    assert orf.blend(-1e6, k) == 0.0
    xs = np.linspace(-0.02, 0.02, 801)
    w = np.array([orf.blend(float(x), k) for x in xs])
    assert np.all((w >= 0.0) & (w <= 1.0))
    assert np.all(np.diff(w) >= 0.0)


def test_pump_discharge_coefficient_eq_26() -> None:
    assert orf.pump_discharge_coefficient(0.2, 0.6, 0.0) == 0.2
    assert orf.pump_discharge_coefficient(0.2, 0.6, 1.0) == 0.6
    assert orf.pump_discharge_coefficient(0.2, 0.6, 0.25) == pytest.approx(0.3, rel=1e-14)


def test_discharge_coefficients_meet_at_the_closed_edge() -> None:
    """Readings R5/R6: at x = 0 and an 80 bar drop C_q,gap and C_q,hole are both 0.5-0.8 and within
    a factor 1.5 of each other, so the Eq. 26 blend does not jump (in bar, C_q,hole would be 17x off)."""
    f = default_params().fits
    dp = 80e5
    area = orf.pump_area(0.0, R_HOLE, N_HOLES, H_GAP)
    cq_gap = orf.gap_discharge_coefficient(orf.gap_geometry_factor(0.0, f.gap_geometry), area,
                                           12 * 2 * (2 * R_HOLE + H_GAP), NU, RHO, dp)
    cq_hole = orf.hole_discharge_coefficient(orf.hole_geometry_factor(0.0, f.hole_geometry),
                                             orf.transition_exponent(0.0, f.hole_exponent), dp)
    assert 0.5 < cq_gap < 0.8
    assert 0.5 < cq_hole < 0.8
    assert 1 / 1.5 < cq_gap / cq_hole < 1.5
    # With dp in bar (80) instead of Pa the hole coefficient would be off by (1e5)^gamma(0) ~ 17.
    cq_hole_bar = orf.hole_discharge_coefficient(orf.hole_geometry_factor(0.0, f.hole_geometry),
                                                 orf.transition_exponent(0.0, f.hole_exponent), 80.0)
    assert cq_hole / cq_hole_bar == pytest.approx(1e5 ** orf.transition_exponent(0.0, f.hole_exponent), rel=1e-12)
    assert cq_hole / cq_hole_bar > 15


def test_orifice_flow_eq_16() -> None:
    # Hand value: 0.7 * 1e-6 m^2 * sqrt(2 * 1e5 Pa / 900 kg/m^3) = 0.7e-6 * 14.9071 = 1.04350e-5 m^3/s.
    assert orf.orifice_flow(0.7, 1e-6, 1e5, RHO) == pytest.approx(1.04350e-5, rel=1e-5)
    assert orf.orifice_flow(0.7, 1e-6, -1e5, RHO) == -orf.orifice_flow(0.7, 1e-6, 1e5, RHO)
    assert orf.orifice_flow(0.7, 1e-6, 0.0, RHO) == 0.0
    for dp in (-1e7, -1.0, 1.0, 1e7):
        assert math.copysign(1.0, orf.orifice_flow(0.6, 2e-6, dp, RHO)) == math.copysign(1.0, dp)
