"""pcv_sim.model.valve: the right-hand side of Eqs. 1-3, 14-15, 28-29 and its sign conventions."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pcv_sim.analysis.static import static_point
from pcv_sim.model.valve import STATE_NAMES, ValveModel
from pcv_sim.params import default_params, replace_param

PS = 200e5   # Pa, supply (Sec. 3.2, R19)


@pytest.fixture(scope="module")
def model() -> ValveModel:
    return ValveModel(default_params(), "simplified")


@pytest.fixture(scope="module")
def full() -> ValveModel:
    return ValveModel(default_params(), "full")


def rhs(m: ValveModel, state: tuple[float, ...], duty: float = 0.7, q_l: float = 0.0) -> tuple[float, ...]:
    dy, _ = m.derivatives(0.0, state, duty, q_l, PS, m.steady_current(duty))
    return dy


def test_unknown_kind_is_refused() -> None:
    with pytest.raises(ValueError, match=r"model kind 'bogus': accepted are 'simplified' and 'full'"):
        ValveModel(default_params(), "bogus")  # type: ignore[arg-type]


def test_state_names(model: ValveModel, full: ValveModel) -> None:
    assert model.state_names == STATE_NAMES["simplified"] and len(model.state_names) == 4
    assert full.state_names == STATE_NAMES["full"] and full.state_names[-1] == "chamber_pressure"
    assert len(model.initial_state(0.7, 0.0, 100e5)) == 4
    _lam, x, v, p, p_c = full.initial_state(0.7, -0.05e-3, 100e5)
    assert (x, v, p, p_c) == (-0.05e-3, 0.0, 100e5, 100e5)


def test_building_blocks(model: ValveModel) -> None:
    assert model.core_mm(0.0) == pytest.approx(1.7, rel=1e-15)            # R2
    assert model.core_mm(-0.55e-3) == pytest.approx(1.15, rel=1e-12)
    assert model.steady_current(0.7) == pytest.approx(0.7 * 12.0 / 5.6, rel=1e-15)   # 1.5 A (R16)
    assert model.coil_voltage(0.7, 0.123) == pytest.approx(8.4, rel=1e-15)           # R15: averaged
    assert (model.x_min, model.x_max) == pytest.approx((-0.55e-3, 0.85e-3), rel=1e-15)
    # The simplified model's damper is B + A_cc^2/K_d with the calibrated A_cc (R20, R21).
    assert model.damping == pytest.approx(4.47 + (6.36e-5 - 2.859e-6) ** 2 / 1.24e-11, rel=1e-12)


def test_switched_coil_voltage_is_a_200_hz_square_wave() -> None:
    m = ValveModel(replace_param(default_params(), "solenoid.pwm", "switched"))
    period = 1 / 200.0
    on = [m.coil_voltage(0.3, k * period + phase) for k in (3, 40) for phase in (0.1e-3, 1.4e-3)]
    off = [m.coil_voltage(0.3, k * period + phase) for k in (3, 40) for phase in (1.6e-3, 4.9e-3)]
    assert on == [12.0] * 4 and off == [0.0] * 4


def test_project_clamps_to_the_stroke(model: ValveModel) -> None:
    assert model.project(-1e-3, -0.2) == (model.x_min, 0.0)        # inelastic: inward speed killed
    assert model.project(-1e-3, 0.2) == (model.x_min, 0.2)         # already leaving the stop
    assert model.project(1e-3, 0.2) == (model.x_max, 0.0)
    assert model.project(1e-3, -0.2) == (model.x_max, -0.2)
    assert model.project(0.1e-3, 0.3) == (0.1e-3, 0.3)             # inside: untouched


def test_hydraulics_forces_are_non_negative_and_flows_follow_the_drops(model: ValveModel) -> None:
    for x in np.linspace(-0.55e-3, 0.85e-3, 57):
        for p in (0.0, 1e5, 60e5, 120e5, 199e5, 250e5):
            h = model.hydraulics(float(x), p, PS)
            assert h.pump_force >= 0.0 and h.tank_force >= 0.0
            assert math.copysign(1.0, h.pump_flow) == math.copysign(1.0, PS - p) or p == PS
            assert h.tank_flow >= 0.0                              # p >= tank pressure 0
            assert h.valve_flow == h.pump_flow - h.tank_flow
            assert h.flow_force == h.pump_force - h.tank_force


def test_pump_flow_force_grows_with_a_small_opening(model: ValveModel) -> None:
    """Eq. 30 at fixed p: from 0.05 to 0.18 mm the jet force grows with the pump opening (the
    area outgrows the falling cos(delta)); beyond, cos(delta) -> 0 makes it fall (Fig. 5)."""
    xs = np.linspace(0.05e-3, 0.18e-3, 14)
    f = [model.hydraulics(float(x), 120e5, PS).pump_force for x in xs]
    assert np.all(np.diff(f) > 0.0)
    assert model.hydraulics(0.5e-3, 120e5, PS).pump_force < f[-1] / 100


@pytest.mark.parametrize("x", [-0.3e-3, -0.08e-3, 0.0, 0.1e-3, 0.25e-3])
@pytest.mark.parametrize("v", [0.0, 0.01, -0.02])
def test_eq_14_signs_in_the_derivatives(model: ValveModel, x: float, v: float) -> None:
    """dv/dt = (F_s - A_c p + A_cc p - K x - B v - (F_pump - F_tank) - f_0) / m (Eq. 14, p_c = p):
    the pump jet force pushes toward -x (closing the pump edge, which opens at +x), the tank jet
    force toward +x (closing the tank edge, which opens at -x) (R14)."""
    p, duty = 110e5, 0.7
    lam = model.flux_linkage_at_rest(1.5, x)
    (dlam, dx, dv, dp), i = model.derivatives(0.0, (lam, x, v, p), duty, 0.0, PS, 1.5)
    h = model.hydraulics(x, p, PS)
    prm = default_params()
    a_net = prm.net_area
    force = (model.solenoid_force(i, x) - a_net * p - 500.0 * x - model.damping * v
             - h.pump_force + h.tank_force - 2.0)
    assert dv == pytest.approx(force / 0.04, rel=1e-9, abs=1e-6)
    assert dx == v
    # Eq. 15 (simplified, R13): V/beta dp/dt = q_pump - q_tank - q_l + (A_c - A_cc) v.
    assert dp == pytest.approx(1e9 / 1e-4 * (h.pump_flow - h.tank_flow + a_net * v), rel=1e-9, abs=1e-3)
    assert dlam == pytest.approx(8.4 - 5.6 * i, rel=1e-12, abs=1e-12)             # Eq. 3


def test_load_flow_enters_continuity_with_beta_over_v(model: ValveModel) -> None:
    state = model.initial_state(0.7, -0.08e-3, 120e5)
    q = 5.0 / 60000.0     # 5 L/min drawn from the load
    d0, d1 = rhs(model, state), rhs(model, state, q_l=q)
    assert d1[3] - d0[3] == pytest.approx(-1e9 / 1e-4 * q, rel=1e-9)
    assert d1[:3] == d0[:3]


@pytest.mark.parametrize("x_table", [-0.0326e-3, 0.2482e-3, -0.15e-3])
def test_derivatives_vanish_at_a_static_point(model: ValveModel, x_table: float) -> None:
    pt = static_point(model, 0.7, x_table)
    state = model.initial_state(0.7, pt.spool_position, pt.pressure)
    dlam, dx, dv, dp = rhs(model, state, q_l=pt.load_flow)
    # Scales: one newton on 0.04 kg is 25 m/s^2; the load flow through beta/V is ~1e4-1e6 Pa/s.
    assert abs(dv) < 1e-6 * 25.0
    assert abs(dp) < 1e-6 * 1e9 / 1e-4 * max(abs(pt.load_flow), 1e-6)
    assert dx == 0.0
    assert abs(dlam) < 1e-9


def test_pressure_pushes_toward_minus_x_and_duty_toward_plus_x(model: ValveModel) -> None:
    pt = static_point(model, 0.7, -0.0326e-3)
    base = model.initial_state(0.7, pt.spool_position, pt.pressure)
    higher_p = model.initial_state(0.7, pt.spool_position, pt.pressure + 1e5)
    more_duty = model.initial_state(0.8, pt.spool_position, pt.pressure)    # rest flux of 0.8's current
    dv0 = rhs(model, base, 0.7, pt.load_flow)[2]
    assert rhs(model, higher_p, 0.7, pt.load_flow)[2] < dv0 - 1e5 * 2.0e-6 / 0.04   # at least A_net dp / m
    assert rhs(model, more_duty, 0.8, pt.load_flow)[2] > dv0 + 1.0 / 0.04          # >1 N more from the solenoid


def test_full_model_with_equal_pressures_at_rest_matches_the_simplified(model: ValveModel, full: ValveModel) -> None:
    for x, p, duty in [(-0.08e-3, 122e5, 0.7), (0.2e-3, 105e5, 0.7), (-0.3e-3, 40e5, 0.4)]:
        lam = model.flux_linkage_at_rest(model.steady_current(duty), x)
        ds = rhs(model, (lam, x, 0.0, p), duty)
        df = rhs(full, (lam, x, 0.0, p, p), duty)
        assert df[:4] == pytest.approx(ds, rel=1e-12, abs=1e-12)
        assert df[4] == 0.0                   # no restrictor flow, no spool motion: chamber at rest


def test_full_model_chamber_is_eqs_28_29(full: ValveModel) -> None:
    x, p, p_c, v = -0.08e-3, 120e5, 121e5, 0.01
    lam = full.flux_linkage_at_rest(1.5, x)
    _dlam, _dx, _dv, dp, dpc = rhs(full, (lam, x, v, p, p_c))
    prm = default_params()
    a_cc = prm.chamber_area
    q_c = 1.24e-11 * (p - p_c)                                           # Eq. 28
    assert dpc == pytest.approx(1e9 / 4.7e-11 * (q_c - a_cc * v), rel=1e-9)   # Eq. 29
    h = full.hydraulics(x, p, PS)
    assert dp == pytest.approx(1e9 / 1e-4 * (h.pump_flow - h.tank_flow - q_c + 6.36e-5 * v), rel=1e-9)  # Eq. 15
    assert full.damping == 4.47                                          # B of the full model (Table 1)


def test_end_stops_hold_the_spool_while_pushed_into_them(model: ValveModel) -> None:
    # At x_min with the pressure force far beyond the solenoid's: held.
    lam = model.flux_linkage_at_rest(0.64, model.x_min)
    d = rhs(model, (lam, model.x_min, 0.0, 190e5), 0.3)
    assert d[1] == 0.0 and d[2] == 0.0
    # At x_min with the force pointing away from the stop: released.
    d = rhs(model, (lam, model.x_min, 0.0, 1e5), 0.3)
    assert d[2] > 0.0
    # At x_max at high duty and low pressure: held.
    lam = model.flux_linkage_at_rest(2.14, model.x_max)
    d = rhs(model, (lam, model.x_max, 0.0, 1e5), 1.0)
    assert d[1] == 0.0 and d[2] == 0.0
