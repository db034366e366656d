"""pcv_sim.analysis.static and .calibrate: the static characteristic against the paper.

Reference numbers: the working-point table of Sec. 5 ("Table 1. The working points for
frequency analysis": P1 1.5 A, -0.0326 mm, 120.4 bar; P2 1.49 A, 0.2482 mm, 109.6 bar, both on
the 70 % curve, P1 where pressure falls with flow, P2 where it rises) and the shapes of Fig. 10.
"""

from __future__ import annotations

import numpy as np
import pytest

from pcv_sim.analysis.calibrate import (
    compare_working_points,
    fit_calibration,
    fit_net_area,
    point_params,
    required_constants,
    write_calibration,
)
from pcv_sim.analysis.paper import WORKING_POINT_DUTY, WORKING_POINTS
from pcv_sim.analysis.static import (
    EquilibriumError,
    balance_pressure,
    equilibrium_at_flow,
    pressure_flow_curve,
    static_point,
    zero_flow_equilibrium,
)
from pcv_sim.errors import ParameterError, PcvSimError
from pcv_sim.model.valve import ValveModel
from pcv_sim.params import default_params, replace_param

BAR = 1e5
LPM = 1e-3 / 60


@pytest.fixture(scope="module")
def model() -> ValveModel:
    return ValveModel(default_params())


@pytest.fixture(scope="module")
def printed():
    return replace_param(default_params(), "calibration.net_area", None)


@pytest.fixture(scope="module")
def calibrated_points():
    return {r.name: r for r in compare_working_points(default_params())}


@pytest.fixture(scope="module")
def printed_points(printed):
    return {r.name: r for r in compare_working_points(printed)}


@pytest.fixture(scope="module")
def curve_70(model: ValveModel):
    return pressure_flow_curve(model, 0.7, 200)


def test_table_as_coded() -> None:
    # The paper's working-point table, transcribed in pcv_sim.analysis.paper.
    assert WORKING_POINT_DUTY == 0.7
    (p1, p2) = WORKING_POINTS
    assert (p1.current, p1.spool_position, p1.pressure, p1.branch) == (1.5, -0.0326e-3, 120.4e5, "falling")
    assert (p2.current, p2.spool_position, p2.pressure, p2.branch) == (1.49, 0.2482e-3, 109.6e5, "rising")


# --- the working points -----------------------------------------------------------------------


@pytest.mark.parametrize("name", ["P1", "P2"])
def test_calibrated_model_reproduces_the_working_points(calibrated_points, name: str) -> None:
    r = calibrated_points[name]
    # Tolerances: 1 bar ~ the table's 0.1 bar print precision plus what one constant cannot fit at
    # two points; 0.05 mm ~ 1/30 of the stroke; the model's current is D*V/R = 1.5 A exactly
    # (R16), the table says 1.49 A at P2: 0.01 A (+1e-9 for the float subtraction).
    assert abs(r.pressure_error) < 1.0 * BAR
    assert abs(r.position_error) < 0.05e-3
    assert abs(r.current_error) <= 0.01 + 1e-9
    assert r.branch == {"P1": "falling", "P2": "rising"}[name]
    # P1 is near zero flow, P2 in reducing mode (positive load flow).
    assert r.load_flow_at_table_x > 0.0
    assert r.load_flow_at_table_x < 2 * LPM if name == "P1" else r.load_flow_at_table_x > 5 * LPM


@pytest.mark.parametrize("name", ["P1", "P2"])
def test_as_printed_pressure_is_about_10_bar_low(printed_points, name: str) -> None:
    """docs/model.md, Calibration: with Table 1 as printed the balance is ~3 N short at both points; 3 N over the
    net area 3.1e-6 m^2 is ~10 bar. Assert 5..15 bar low."""
    r = printed_points[name]
    assert -15 * BAR < r.pressure_error < -5 * BAR
    assert r.branch == {"P1": "falling", "P2": "rising"}[name]


def test_required_constants_favour_the_net_area(printed) -> None:
    """R21: the net area each point asks for agrees far better than the force offset each asks for."""
    rows = {r["name"]: r for r in required_constants(printed)}
    a1, a2 = rows["P1"]["net_area_m2"], rows["P2"]["net_area_m2"]
    f1, f2 = rows["P1"]["force_offset_N"], rows["P2"]["force_offset_N"]
    area_spread = abs(a1 - a2) / (0.5 * (a1 + a2))
    offset_spread = abs(f1 - f2) / (0.5 * (abs(f1) + abs(f2)))
    assert area_spread < 0.02
    assert offset_spread > 5 * area_spread
    # Both offsets are the "~3 N short" of docs/model.md (the solenoid must give more), and both areas
    # are below the printed 3.1e-6 m^2 (less area -> more pressure for the same force).
    assert 2.0 < f1 < 4.0 and 2.0 < f2 < 4.0
    assert a1 < 3.1e-6 and a2 < 3.1e-6
    # The shipped calibration lies between (or within 1 % of) the two.
    cal = default_params().net_area
    assert min(a1, a2) * 0.99 < cal < max(a1, a2) * 1.01


def test_shipped_calibration_is_what_the_fit_produces(printed) -> None:
    # The shipped constant was fitted with 1.500 A at both points (the config's resistance).
    area, results = fit_net_area(printed, coil="config")
    # fit_net_area rounds to 4 significant digits, as the config carries.
    assert area == default_params().calibration.net_area
    assert [r.name for r in results] == ["P1", "P2"]


def test_table_currents_per_point() -> None:
    """Sec. 6.1: the coil resistance was calculated at the stationary points; with R = D V / i per
    point the model drives the table's 1.50 A and 1.49 A, with the config's R 1.500 A at both."""
    p1, p2 = (point_params(default_params(), wp) for wp in WORKING_POINTS)
    assert p1.solenoid.coil_resistance == pytest.approx(0.7 * 12.0 / 1.5, rel=1e-12)
    assert p2.solenoid.coil_resistance == pytest.approx(0.7 * 12.0 / 1.49, rel=1e-12)
    for r, wp in zip(compare_working_points(default_params()), WORKING_POINTS):
        assert r.model_current == pytest.approx(wp.current, rel=1e-12)
    config = compare_working_points(default_params(), coil="config")
    assert [r.model_current for r in config] == pytest.approx([1.5, 1.5], rel=1e-12)


@pytest.mark.parametrize("kind", ["net_area", "force_offset", "both"])
def test_calibration_kinds_fit_the_table(printed, kind: str) -> None:
    """Each calibration kind closes the ~10 bar gap at both points at the table's currents: one
    constant leaves errors of opposite sign below 0.5 bar (the fits' residual, 0.2-0.3 bar),
    two constants fit both pressures to the 4-digit rounding."""
    fit = fit_calibration(printed, kind)
    errors = [abs(r.pressure_error) for r in fit.results]
    assert max(errors) < (0.5 * BAR if kind != "both" else 0.05 * BAR)
    area, preload = fit.values["calibration.net_area"], fit.values["spool.spring_preload"]
    assert (area is None) == (kind == "force_offset")
    assert (preload == 2.0) == (kind == "net_area")
    rows = {r["name"]: r for r in required_constants(printed)}
    if kind == "net_area":      # the one area lies between what each point asks for
        assert min(rows["P1"]["net_area_m2"], rows["P2"]["net_area_m2"]) <= area
        assert area <= max(rows["P1"]["net_area_m2"], rows["P2"]["net_area_m2"])
    if kind == "force_offset":  # the offset (toward +x) is carried by the preload: f_0 - F
        assert fit.force_offset_N == pytest.approx(2.0 - preload, abs=1e-9)
        assert min(rows["P1"]["force_offset_N"], rows["P2"]["force_offset_N"]) <= fit.force_offset_N
    with pytest.raises(ParameterError, match=r"calibration kind 'offset': accepted are net_area, force_offset, both"):
        fit_calibration(printed, "offset")  # type: ignore[arg-type]


def test_write_calibration_keeps_comments(tmp_path) -> None:
    from pcv_sim.params import DEFAULT_CONFIG, load_params

    path = tmp_path / "v.yaml"
    path.write_text(DEFAULT_CONFIG.read_text())
    write_calibration(path, {"calibration.net_area": None, "spool.spring_preload": -0.5})
    p = load_params(path)
    assert p.calibration.net_area is None and p.spool.spring_preload == -0.5
    assert "spring_preload: -0.5          # N, f_0 (T1)" in path.read_text()
    with pytest.raises(ParameterError, match=r"expected one 'nope:' line under spool"):
        write_calibration(path, {"spool.nope": 1.0})


# --- the static characteristic ----------------------------------------------------------------


def test_static_point_is_an_equilibrium(model: ValveModel) -> None:
    pt = static_point(model, 0.7, 0.1e-3)
    assert model.static_force(pt.current, pt.spool_position, pt.pressure, 200e5) == pytest.approx(0.0, abs=1e-6)
    h = model.hydraulics(pt.spool_position, pt.pressure, 200e5)
    assert pt.load_flow == h.valve_flow == pt.pump_flow - pt.tank_flow
    assert pt.flow_force == h.flow_force
    assert pt.current == pytest.approx(1.5, rel=1e-15)


def test_reducing_curve_has_a_pressure_minimum_inside(curve_70) -> None:
    """Fig. 10a / Sec. 4.2: in reducing mode the 70 % pressure first falls with flow, then rises
    (the negative characteristic)."""
    q, p = curve_70.load_flow, curve_70.pressure
    assert np.all(np.diff(q) > 0.0)                 # flow grows with the spool opening
    red = q > 0.0
    qr, pr = q[red], p[red]
    k = int(np.argmin(pr))
    assert 0 < k < len(pr) - 1
    assert pr[0] - pr[k] > 5 * BAR and pr[-1] - pr[k] > 5 * BAR
    # The minimum lies at a moderate flow, between the two working points' flows (0.4 and 16 L/min).
    assert 1 * LPM < qr[k] < 20 * LPM


def test_relieving_pressure_rises_with_relief_flow(curve_70) -> None:
    q, p = curve_70.load_flow, curve_70.pressure
    rel = q < 0.0
    assert rel.sum() > 10
    # Ordered by x (= by q): the more flow is relieved (q more negative), the higher the pressure.
    assert np.all(np.diff(p[rel]) < 0.0)
    assert np.all(curve_70.spool_position[rel] < 0.0)   # relieving opens the tank side


def test_zero_flow_rests_on_the_tank_side_and_pressure_rises_with_duty(model: ValveModel) -> None:
    duties = [0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0]
    pts = [zero_flow_equilibrium(model, d) for d in duties]
    # Sec. 4.2: "the spool works with an offset from the centre position towards the tank side".
    assert all(pt.spool_position < 0.0 for pt in pts)
    assert all(abs(pt.load_flow) < 1e-12 for pt in pts)
    pressures = [pt.pressure for pt in pts]
    assert np.all(np.diff(pressures) > 0.0)
    # Range check against the rig (Sec. 3.2): 30 % gives a low pressure, 100 % stays below 200 bar supply.
    assert pressures[0] < 50 * BAR and 150 * BAR < pressures[-1] < 200 * BAR
    # The pump leakage at rest is what the tank side passes.
    for pt in pts:
        assert pt.pump_flow == pytest.approx(pt.tank_flow, rel=1e-9)


def test_equilibrium_at_flow_delivers_the_flow(model: ValveModel) -> None:
    for q in (-5 * LPM, 2 * LPM, 10 * LPM):
        pt = equilibrium_at_flow(model, 0.7, q)
        assert pt.load_flow == pytest.approx(q, rel=1e-9, abs=1e-12)


def test_equilibrium_beyond_reach_raises(model: ValveModel) -> None:
    # 1 m^3/s = 60000 L/min: not even a stop-held rest state passes it.
    with pytest.raises(EquilibriumError, match=r"load flow 1 m\^3/s cannot be held with the spool on its max stop"):
        equilibrium_at_flow(model, 0.7, 1.0)
    with pytest.raises(EquilibriumError, match=r"cannot be held with the spool on its min stop"):
        equilibrium_at_flow(model, 0.7, -1.0)
    err = EquilibriumError("x")
    assert isinstance(err, PcvSimError) and isinstance(err, ArithmeticError)


def test_balance_pressure_failure_branches(model: ValveModel) -> None:
    # 0.1 A cannot hold the spool against the 2 N preload at +0.8 mm, even with no pressure.
    with pytest.raises(EquilibriumError, match=r"the spool cannot rest at x=0\.0008 m with i=0\.1 A"):
        balance_pressure(model, 0.1, 0.8e-3, 200e5)
    # With 1 bar supply the bracket [0, 3 bar] holds no balance for ~37 N of solenoid force
    # (37 N / 2.859e-6 m^2 ~ 130 bar).
    with pytest.raises(EquilibriumError, match=r"no balance pressure below 3e\+05 Pa"):
        balance_pressure(model, 1.5, -0.05e-3, 1e5)


def test_zero_flow_equilibrium_below_30_percent(model: ValveModel) -> None:
    # Independent evidence that it exists: static_point's load flow changes sign near -0.2 mm.
    lo, hi = static_point(model, 0.28, -0.25e-3), static_point(model, 0.28, -0.15e-3)
    assert lo.load_flow < 0.0 < hi.load_flow
    pt = zero_flow_equilibrium(model, 0.28)
    assert -0.25e-3 < pt.spool_position < -0.15e-3
    assert abs(pt.load_flow) < 1e-12


def test_rest_states_held_by_the_stops(model: ValveModel) -> None:
    """R30: where no free equilibrium delivers the flow, the spool rests on a stop and the
    pressure is what continuity (Eq. 15 with dp/dt = 0) gives there."""
    # 0 %: no solenoid force, the 2 N preload holds the spool on x_min; the tank side is wide
    # open and the pump side only leaks, so the load pressure sits near tank pressure.
    rest = zero_flow_equilibrium(model, 0.0)
    assert rest.spool_position == model.x_min
    assert 0.0 < rest.pressure < 0.1 * BAR
    h = model.hydraulics(model.x_min, rest.pressure, 200e5)
    assert h.pump_flow == pytest.approx(h.tank_flow, rel=1e-6)
    # 30 L/min drawn at 100 %: more than any free position delivers -> the max stop.
    up = equilibrium_at_flow(model, 1.0, 30 * LPM)
    assert up.spool_position == model.x_max
    assert up.load_flow == pytest.approx(30 * LPM, rel=1e-9)
    assert model.static_force(up.current, model.x_max, up.pressure, 200e5) > 0.0   # pushes into the stop
    # 30 L/min pushed in at 30 %: the min stop, the pressure above supply.
    down = equilibrium_at_flow(model, 0.3, -30 * LPM)
    assert down.spool_position == model.x_min
    assert down.pressure > 200 * BAR
    assert model.static_force(down.current, model.x_min, down.pressure, 200e5) < 0.0


def test_flow_in_the_gap_of_free_positions_raises(model: ValveModel) -> None:
    # At 28 % the solenoid cannot hold the spool between ~0.1 and ~0.27 mm (the flow-force
    # peak), which would deliver ~9 .. 32 L/min: 20 L/min has no rest state.
    with pytest.raises(EquilibriumError, match=r"load flow 0\.0003333 m\^3/s is outside what the valve holds at rest at duty 0\.28"):
        equilibrium_at_flow(model, 0.28, 20 * LPM)


def test_pressure_flow_curve_skips_positions_without_equilibrium(model: ValveModel) -> None:
    # At 30 % the solenoid cannot hold the spool where the flow force peaks: those x are left out.
    c = pressure_flow_curve(model, 0.3, 50)
    assert 0 < len(c.spool_position) < 50
    assert len(c.spool_position) == len(c.pressure) == len(c.load_flow)
    full = pressure_flow_curve(default_params(), 0.7, 50)     # a ValveParams works too
    assert len(full.spool_position) == 50
