"""The steering cylinder: its parameters' validation, and its equations' signs and units."""

import dataclasses
import math

import numpy as np
import pytest
import yaml

from pcv_sim.errors import ParameterError
from pcv_sim.params import section_from_mapping
from pcv_sim.plant import cylinder as cyl
from pcv_sim.plant.params import CylinderParams
from pcv_sim.rig.params import DEFAULT_RIG, load_rig, rig_from_mapping


def _raw():
    return yaml.safe_load(DEFAULT_RIG.read_text())


def test_shipped_rig_loads():
    rig = load_rig()
    assert [v.name for v in rig.valves] == ["left", "right"]
    assert rig.steps_per_period == 10
    assert rig.cylinder.area_a == pytest.approx(math.pi / 4 * (0.040**2 - 0.022**2), rel=1e-3)


@pytest.mark.parametrize(("edit", "match"), [
    (lambda d: d["cylinder"].update(aera_a=1.0), r"cylinder: unknown key 'aera_a' \(did you mean 'area_a'\?\); accepted: area_a"),
    (lambda d: d["cylinder"].update(area_a=877.0), r"cylinder\.area_a: got 877\.0; accepted is a plausible value 1e-05 \.\. 0\.1 \(m\^2\) \(piston area"),
    (lambda d: d["cylinder"].update(mass="50 kg"), r"cylinder\.mass: got '50 kg' \(str\)"),
    (lambda d: d["cylinder"].update(load_stiffness="1e5"), r"write 1\.0e\+9"),
    (lambda d: d["cylinder"].pop("mass"), r"missing key\(s\) cylinder\.mass"),
    (lambda d: d["cylinder"].update(initial_position=0.2), r"initial_position=0\.2: accepted is stroke_min"),
    (lambda d: d["rig"].update(control_period=1.5e-4), r"rig\.control_period=0\.00015 s: accepted is a whole number"),
    (lambda d: d["rig"].update(timestep=1e-4), r"rig: unknown key 'timestep' \(did you mean 'time_step'\?\)"),
    (lambda d: d["valves"]["right"].update(chamber="a"), r"chamber a is fed by \['left', 'right'\]; accepted is exactly one"),
    (lambda d: d["valves"]["left"].update(chamber="c"), r"valves\.left\.chamber: got 'c'; accepted is one of 'a', 'b', 'none'"),
    (lambda d: d["valves"]["left"].update(initial_duty=50), r"valves\.left\.initial_duty: got 50; accepted is a fraction"),
    (lambda d: d["valves"]["left"].update(config="nosuch.yaml"), r"cannot read parameter file .*nosuch\.yaml"),
    (lambda d: d.update(plant={}), r"unknown section\(s\) \['plant'\]"),
])
def test_bad_rig_yaml_is_refused_naming_the_key(edit, match):
    data = _raw()
    edit(data)
    with pytest.raises(ParameterError, match=match):
        rig_from_mapping(data, base=DEFAULT_RIG.parent)


def test_bad_yaml_file_is_refused(tmp_path):
    bad = tmp_path / "rig.yaml"
    bad.write_text("rig: [unclosed\n")
    with pytest.raises(ParameterError, match=r"not valid YAML"):
        load_rig(bad)


def _kernel(params, x, v, pa, pb, f_ext=0.0):
    p = cyl.pack(params)
    xs, u = np.array([x, v]), np.array([pa, pb, f_ext])
    dx, y = np.zeros(2), np.zeros(len(cyl.OUTPUTS))
    cyl.rhs(0.0, xs, u, p, (np.zeros(1),), np.zeros(1), dx)
    cyl.output(0.0, xs, u, p, (np.zeros(1),), np.zeros(1), y)
    return dx, dict(zip(cyl.OUTPUTS, y))


def test_cylinder_equations_signs_and_units():
    c = dataclasses.replace(load_rig().cylinder, area_b=5e-4, coulomb_friction=100.0, friction_velocity=1e-3)
    # Chamber volumes: hose + dead volume + A times the travel from the end where the chamber is smallest.
    _, y = _kernel(c, 0.02, 0.0, 0.0, 0.0)
    assert y["volume_a"] == pytest.approx(c.hose_volume_a + c.dead_volume_a + c.area_a * (0.02 - c.stroke_min))
    assert y["volume_b"] == pytest.approx(c.hose_volume_b + c.dead_volume_b + c.area_b * (c.stroke_max - 0.02))
    # Extending (v > 0): chamber a draws A_a v from its valve, chamber b pushes A_b v back.
    dx, y = _kernel(c, 0.0, 0.1, 0.0, 0.0)
    assert (y["flow_a"], y["flow_b"]) == pytest.approx((c.area_a * 0.1, -c.area_b * 0.1))
    assert dx[0] == 0.1
    # Force balance: m a = A_a p_a - A_b p_b - k x - c v - F_c tanh(v/v_s) + F.
    dx, y = _kernel(c, 0.01, 0.05, 100e5, 50e5, 200.0)
    expect = (c.area_a * 100e5 - c.area_b * 50e5 - c.load_stiffness * 0.01
              - (c.load_damping + c.viscous_friction) * 0.05 - 100.0 * math.tanh(50.0) + 200.0)
    assert dx[1] == pytest.approx(expect / c.mass, rel=1e-12)
    assert y["effort"] == pytest.approx(c.area_a * 100e5 - c.area_b * 50e5)
    # At the end stop with the force into it the piston stays; away from it, it leaves.
    dx, _ = _kernel(c, c.stroke_max, 0.0, 200e5, 0.0)      # 17.5 kN out, 10 kN spring back
    assert tuple(dx) == (0.0, 0.0)
    dx, _ = _kernel(c, c.stroke_max, 0.0, 0.0, 100e5)
    assert dx[1] < 0.0


def test_cylinder_params_defaults_are_not_silent():
    with pytest.raises(ParameterError, match=r"missing key\(s\) cylinder\.area_a"):
        section_from_mapping(CylinderParams, {}, "cylinder")
