"""The valve options on the rig from a scenario file (docs/model.md R33-R35): the `valves:` overlay
(valve YAML keys over the rig's valve files, validated by the valve YAML's own schema, errors
naming the key; the campaign writes its variants over it), the options' outputs as rig signals,
their panels in the report, and the example scenarios (examples/cold_start.yaml,
coil_heating*.yaml, fast_release*.yaml), each run here in a short version against its physics."""

import copy
import dataclasses
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from pcv_sim.params import load_params, replace_param
from pcv_sim.rig import load_rig
from pcv_sim.rig.scenario import ScenarioError, load_scenario, run_scenario, scenario_from_mapping
from pcv_sim.units import kelvin

REPO = Path(__file__).resolve().parents[2]
EXAMPLES = REPO / "examples"
sys.path.insert(0, str(EXAMPLES))


def _data(name):
    return yaml.safe_load((EXAMPLES / name).read_text())


def _load(data, name="step.yaml"):
    return scenario_from_mapping(data, path=EXAMPLES / name)


# --- the overlay ------------------------------------------------------------------------------


def test_a_section_applies_to_every_valve_and_a_valves_own_keys_win():
    data = _data("step.yaml")
    data["valves"] = {"fluid": {"temperature": "input", "oil_temperature_c": 10.0},
                      "left": {"fluid": {"oil_temperature_c": -10.0}, "spool": {"core": "separate"}}}
    sc = _load(data)
    left, right = (v.params for v in sc.rig.valves)
    shipped = load_params()
    # exactly the valve YAML with those keys changed, as replace_param (the YAML's checks) makes it
    expected_right = replace_param(replace_param(shipped, "fluid.temperature", "input"), "fluid.oil_temperature_c", 10.0)
    expected_left = replace_param(replace_param(expected_right, "fluid.oil_temperature_c", -10.0), "spool.core",
                                  "separate")
    assert right == expected_right and left == expected_left
    assert sc.valve_changes["right"] == {("fluid", "temperature"): "input", ("fluid", "oil_temperature_c"): 10.0}
    # the file names the same rig: without the overlay the valves are the shipped ones
    assert all(v.params == shipped for v in load_rig(REPO / "config" / "rig.yaml").valves)
    # the overlay brings the inputs the timeline may then set, and the outputs assertions may name
    data["timeline"] = [{"t": 0.1, "oil_temperature": "0 degC"}]
    data["assertions"].append({"type": "never_above", "signal": "left.core_position", "max": "1 mm"})
    assert _load(data).timeline[0]["oil_temperature"].keys() == {"left", "right"}


@pytest.mark.parametrize(("valves", "match"), [
    ({"fluidd": {"temperature": "input"}}, r"valves: unknown key 'fluidd' \(did you mean 'fluid'\?\); accepted: solenoid"),
    ({"fluid": {"temperature": "cold"}}, r"valves\.left: fluid\.temperature.*'cold'.*fixed.*input"),
    ({"fluid": {"temprature": "input"}}, r"valves\.left: unknown parameter fluid\.temprature; accepted in fluid"),
    ({"left": {"spool": {"core": "separate", "core_mass": 0.05}}}, r"valves\.left: spool\.core_mass=0\.05 >= spool\.mass=0\.04.*accepted is 0 < core_mass < mass"),
    ({"fluid": "input"}, r"valves\.fluid: got 'input'; accepted is a mapping key: value of the valve YAML's fluid"),
    ({"middle": {"fluid": {"temperature": "input"}}}, r"valves: unknown key 'middle'.*accepted: solenoid.*left, right"),
    ({"left": {"fluidd": {}}}, r"valves\.left: unknown key 'fluidd' \(did you mean 'fluid'\?\)"),
    ({"simulation": {"time_step": 1e-5}}, r"valves\.left: its simulation\.time_step 1e-05 s differs from rig\.time_step"),
    ([1, 2], r"valves: got \[1, 2\]; accepted is a mapping"),
])
def test_a_bad_overlay_is_refused_naming_the_key(valves, match):
    data = _data("step.yaml")
    data["valves"] = valves
    with pytest.raises(ScenarioError, match=match):
        _load(data)


def test_a_ros_controller_refuses_the_overlay():
    """The rig node of a ROS controller loads the rig YAML itself: the overlay would not reach it."""
    data = _data("ros/step.yaml")
    data["valves"] = {"fluid": {"temperature": "input"}}
    with pytest.raises(ScenarioError, match=r"valves: the rig node of a ROS controller loads the rig YAML itself"):
        scenario_from_mapping(data, path=EXAMPLES / "ros" / "step.yaml")


def test_the_command_with_a_ros_node_refuses_the_overlay(capsys):
    from pcv_sim.cli import main

    assert main(["scenario", "run", str(EXAMPLES / "fast_release.yaml"), "--ros", "/steering", "--wait", "1"]) == 2
    assert "BAD FILE" in (err := capsys.readouterr().err) and "valves: with --ros the rig node loads the rig YAML" in err


def test_the_oil_of_the_overlay_is_checked_against_the_rigs_step():
    """A separate core keeps the explicit bound on the spool's pole (R34): oil at -20 degC at the
    rig's 0.1 ms step is refused when the rig is built, naming the key, not integrated into a
    diverging state."""
    from pcv_sim.errors import ParameterError
    from pcv_sim.rig import Rig

    data = _data("step.yaml")
    data["valves"] = {"fluid": {"temperature": "input", "oil_temperature_c": -20.0}, "spool": {"core": "separate"}}
    with pytest.raises(ParameterError, match=r"valves\.left: fluid\.oil_temperature_c: oil temperature -20\.0 degC"):
        Rig(_load(data).rig)


def test_a_campaign_writes_its_variants_over_the_overlay():
    """The campaign's valve keys go over the scenario's `valves:` (its mechanism, one): a varied
    key of the overlay takes the variant's value, the other overlay keys stay, also in a variant
    that varies only the plant."""
    from pcv_sim.campaign.targets import load_base

    data = _data("step.yaml")
    data["rig"] = str(REPO / "config" / "rig.yaml")
    data["controller"] = "steering:PositionController"
    data["valves"] = {"fluid": {"temperature": "input", "oil_temperature_c": -10.0}}
    base = load_base(data, EXAMPLES / "campaign.yaml")
    assert all(v.params.fluid.oil_temperature_c == -10.0 for v in base.scenario.rig.valves)
    varied = base.scenario_for({"left.fluid.oil_temperature_c": 25.0})
    left, right = (v.params.fluid for v in varied.rig.valves)
    assert (left.temperature, left.oil_temperature_c) == ("input", 25.0)
    assert (right.temperature, right.oil_temperature_c) == ("input", -10.0)
    plant = base.scenario_for({"cylinder.mass": 60.0})
    assert plant.rig.cylinder.mass == 60.0
    assert all(v.params.fluid.oil_temperature_c == -10.0 for v in plant.rig.valves)


# --- the example scenarios ----------------------------------------------------------------------


def _run(data, name, **changes):
    sc = dataclasses.replace(_load(data, name), **changes)
    result = run_scenario(sc)
    assert result.run is not None, result.summary()
    return result


def test_cold_start_the_cold_steering_is_slower_than_the_warm():
    """examples/cold_start.yaml, its first step (at 1 s, the oil at -19 degC) against the same
    scenario in oil at 40 degC: the warm step settles within 0.5 s, the cold one is still > 5 mm
    away 1.5 s after it (~100x the viscosity: slow spools)."""
    cold_data = _data("cold_start.yaml")
    sc = _load(cold_data, "cold_start.yaml")
    assert all(v.params.fluid.oil_temperature_model and v.params.fluid.oil_temperature_c == -20.0
               for v in sc.rig.valves)
    warm_data = copy.deepcopy(cold_data)
    warm_data["valves"]["fluid"]["oil_temperature_c"] = 40.0
    warm_data["timeline"] = []
    errors = {}
    for name, data in (("cold", cold_data), ("warm", warm_data)):
        result = _run(data, "cold_start.yaml", duration=3.0)
        run = result.run
        late = run.times >= 2.5
        errors[name] = float(np.max(np.abs(run.signal("cylinder.position") - run.signal("setpoint"))[late]))
        if name == "cold":
            oil = result.inputs["left.oil_temperature"]
            assert oil[0] == pytest.approx(kelvin(-20.0)) and oil[-1] == pytest.approx(kelvin(-17.0), abs=0.01)
    assert errors["warm"] < 0.5e-3
    assert errors["cold"] > 5e-3


@pytest.fixture(scope="module")
def heating_runs():
    """coil_heating.yaml (90 % duty, open loop) and coil_heating_closed_loop.yaml (PI on pressure)
    for 20 s with a coil of 2 J/K (tau = R_th C_th = 5 s instead of 500 s: 4 time constants)."""
    out = {}
    for name in ("coil_heating.yaml", "coil_heating_closed_loop.yaml"):
        data = _data(name)
        data["valves"]["solenoid"]["coil_heat_capacity"] = 2.0
        out[name] = _run(data, name, duration=20.0)
    return out


def test_coil_heating_open_loop_the_current_and_pressure_fall(heating_runs):
    """At 90 % duty the coil settles where its heat balances, dT = R_th (D V)^2 / R(T) with copper's
    R(T) = R_ref (1 + alpha dT) (~44 K above the 40 degC ambient), 98 % of the way after 4 time
    constants; the current falls as D V / R(T), and so does the pressure."""
    result = heating_runs["coil_heating.yaml"]
    assert result.passed, result.summary()
    run = result.run
    temp, r, i, p = (run.signal(f"left.{s}") for s in ("coil_temperature", "coil_resistance", "current", "pressure"))
    rise = temp[-1] - kelvin(40.0)
    power_r = (0.9 * 12.0) ** 2 * 2.5 / 5.6                     # K (1 + alpha dT) at the balance
    steady = (-1.0 + np.sqrt(1.0 + 4.0 * 3.93e-3 * power_r)) / (2.0 * 3.93e-3)
    assert 0.95 * steady < rise < steady
    assert r[-1] == pytest.approx(5.6 * (1.0 + 3.93e-3 * rise), rel=1e-9)
    assert i[-1] == pytest.approx(0.9 * 12.0 / r[-1], rel=5e-3)
    k5 = int(np.searchsorted(run.times, 2.0))
    assert p[k5] - p[-1] > 5e5                      # the pressure falls by > 5 bar as the coil heats


def test_coil_heating_closed_loop_holds_the_pressure(heating_runs):
    """The PI on pressure raises the duty as the coil's resistance rises: the pressure holds at
    150 bar while the open loop's falls, and the duty ends higher than it settled at first."""
    result = heating_runs["coil_heating_closed_loop.yaml"]
    held = next(o for o in result.outcomes if o.name == "chamber a holds 150 bar")
    assert held.passed, result.summary()
    run = result.run
    after = run.times >= 5.0
    assert np.max(np.abs(run.signal("left.pressure")[after] - 150e5)) < 1e5
    duty = run.signal("left.duty")
    k5 = int(np.searchsorted(run.times, 5.0))
    assert duty[-1] - duty[k5] > 0.02
    assert run.signal("left.coil_temperature")[-1] - kelvin(40.0) > 20.0


def test_fast_release_parts_core_and_spool_at_the_stop_and_the_limit_keeps_them_close():
    """fast_release.yaml: 100 -> 0 % parts the core from the stopped spool by tens of um; the
    duty's return brings it back (contact regained). fast_release_limited.yaml: at 2 /s the gap
    stays below 1 um. Both pressures are the attached core's within 0.5 bar (R35)."""
    gaps = {}
    for name in ("fast_release.yaml", "fast_release_limited.yaml"):
        data = _data(name)
        result = _run(data, name)
        assert result.passed, result.summary()
        run = result.run
        gap = run.signal("left.spool_position") - run.signal("left.core_position")
        assert np.min(gap) >= 0.0                    # the core never passes the spool
        gaps[name] = float(np.max(gap))
        attached = copy.deepcopy(data)
        del attached["valves"]
        attached["assertions"] = []
        p_att = _run(attached, name).run.signal("left.pressure")
        assert np.max(np.abs(run.signal("left.pressure") - p_att)) < 0.5e5
    assert gaps["fast_release.yaml"] > 10e-6
    assert gaps["fast_release_limited.yaml"] < 1e-6


def test_every_option_example_loads_with_its_options():
    want = {"cold_start.yaml": ("oil",), "coil_heating.yaml": ("coil",), "coil_heating_closed_loop.yaml": ("coil",),
            "fast_release.yaml": ("core",), "fast_release_limited.yaml": ("core",)}
    for name, options in want.items():
        sc = load_scenario(EXAMPLES / name)
        for v in sc.rig.valves:
            on = {"oil": v.params.fluid.oil_temperature_model, "coil": v.params.solenoid.coil_thermal,
                  "core": v.params.spool.core_separation}
            assert {k for k, x in on.items() if x} == set(options), name


# --- the report -----------------------------------------------------------------------------------


def test_the_report_shows_the_options_panels(heating_runs):
    from pcv_sim.rig import report

    result = heating_runs["coil_heating.yaml"]
    extra = {**report._derived(result.run), **result.inputs}
    titles = [title for title, _, _ in report._panels(result.run, extra)]
    assert "temperatures" in titles and "coil resistances [ohm]" in titles and "core gap to the spool" not in titles
    names = dict((t, n) for t, _, n in report._panels(result.run, extra))["temperatures"]
    assert names == ["left.coil_temperature", "left.ambient_temperature", "right.coil_temperature",
                     "right.ambient_temperature"]
    assert report._scale("temperature") == ("degC", 1.0, 273.15)    # drawn in degC
    page = report.render_html(result)
    assert "data:image/png;base64," in page
    data = _data("fast_release.yaml")
    fast = _run(data, "fast_release.yaml", duration=0.1).run
    titles = [title for title, _, _ in report._panels(fast, report._derived(fast))]
    assert "core gap to the spool" in titles and "temperatures" not in titles
    assert np.array_equal(report._derived(fast)["left.core_gap"],
                          fast.signal("left.spool_position") - fast.signal("left.core_position"))
