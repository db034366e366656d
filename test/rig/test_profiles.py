"""Profiles: each shape against its formula, from its start time; a chain of segments; a CSV column
with its unit; on the rig (force, supply and duty profiles act at the control instants)."""

import math

import numpy as np
import pytest

from pcv_sim.rig.profiles import Profile, ProfileError, Segment, parse_segment
from pcv_sim.rig.scenario import run_scenario, scenario_from_mapping


def seg(raw, kind="length", t=1.0, **kw):
    return parse_segment("p", t, raw, kind, **kw)


def test_ramp_table_sine_chirp_follow_their_formulas():
    ramp = seg({"ramp": {"from": "0 mm", "to": "20 mm", "duration": "500 ms"}})
    for tau in (0.0, 0.1, 0.25, 0.5, 0.7):
        assert ramp.at(tau, 99.0) == pytest.approx(0.02 * min(tau / 0.5, 1.0), abs=1e-15)
    table = seg({"table": [[0, "0 mm"], ["0.2 s", "5 mm"], [0.4, "5 mm"], [0.5, "-5 mm"]]})
    for tau, want in ((0.0, 0.0), (0.1, 0.0025), (0.3, 0.005), (0.45, 0.0), (0.5, -0.005), (2.0, -0.005)):
        assert table.at(tau, 0.0) == pytest.approx(want, abs=1e-15)
    sine = seg({"sine": {"amplitude": "10 mm", "frequency": "0.5 Hz", "offset": "2 mm"}})
    for tau in np.linspace(0.0, 3.0, 13):
        assert sine.at(tau, 0.0) == pytest.approx(0.002 + 0.01 * math.sin(2 * math.pi * 0.5 * tau), abs=1e-15)
    chirp = seg({"chirp": {"amplitude": "1 mm", "from": "1 Hz", "to": "11 Hz", "duration": "2 s"}})
    for tau in np.linspace(0.0, 2.0, 17):
        phase = 1.0 * tau + (11.0 - 1.0) * tau ** 2 / (2 * 2.0)
        assert chirp.at(tau, 0.0) == pytest.approx(0.001 * math.sin(2 * math.pi * phase), abs=1e-15)
    # after the sweep: on at 11 Hz with a continuous phase
    end = 1.0 * 2.0 + 10.0 * 2.0 / 2
    assert chirp.at(2.3, 0.0) == pytest.approx(0.001 * math.sin(2 * math.pi * (end + 11.0 * 0.3)), abs=1e-15)


def test_a_profile_chains_its_segments_and_a_ramp_starts_from_the_value_before():
    p = Profile([Segment(0.0, "value", value=1.0), seg({"ramp": {"to": 3.0, "duration": 2.0}}, "number", t=1.0),
                 seg({"sine": {"amplitude": 1.0, "frequency": 1.0}}, "number", t=4.0)], initial=-5.0)
    assert p(0.5) == 1.0
    assert p(1.0) == 1.0 and p(2.0) == pytest.approx(2.0) and p(3.5) == 3.0
    assert p(4.25) == pytest.approx(1.0)
    assert Profile([seg(2.0, "number", t=1.0)], initial=-5.0)(0.5) == -5.0


def test_a_csv_column_plays_with_its_unit(tmp_path):
    f = tmp_path / "profile.csv"
    f.write_text("time [s],position [mm],force\n10.0,0,1\n10.5,5,2\n11.0,5,3\n")
    s = seg({"file": {"path": "profile.csv", "column": "position"}}, base=tmp_path)
    assert s.times == (0.0, 0.5, 1.0)
    assert s.at(0.25, 0.0) == pytest.approx(0.0025)
    k = seg({"file": {"path": "profile.csv", "column": "force", "unit": "kN"}}, "force", base=tmp_path)
    assert k.at(1.0, 0.0) == pytest.approx(3000.0)
    with pytest.raises(ProfileError, match=r"p\.file\.column: no column 'positon' .*did you mean 'position'"):
        seg({"file": {"path": "profile.csv", "column": "positon"}}, base=tmp_path)
    with pytest.raises(ProfileError, match=r"cannot read"):
        seg({"file": {"path": "nosuch.csv", "column": "x"}}, base=tmp_path)


@pytest.mark.parametrize(("raw", "match"), [
    ({"ramp": {"to": 1.0}}, r"p\.ramp\.duration: missing; accepted is the ramp's time \(s\)"),
    ({"rampe": {"to": 1.0}}, r"p: accepted is exactly one of value, ramp, table, sine, chirp, file; got 'rampe' "
                             r"\(did you mean 'ramp'\?\)"),
    ({"table": [[0, 1.0]]}, r"at least two"),
    ({"table": [[0.2, 1.0], [0.1, 2.0]]}, r"increasing times"),
    ({"sine": {"amplitude": -1.0, "frequency": 1.0}}, r"p\.sine\.amplitude: got -1\.0; accepted is a value >= 0"),
    ({"sine": {"amplitude": 1.0, "frequency": "2 kHz"}}, r"p\.sine\.frequency: got '2 kHz'; accepted is a frequency in 0 \.\. 1000 \(Hz\)"),
    ({"sine": {"amplitude": 1.0, "frequency": 1.0, "ofset": 1.0}}, r"p\.sine: unknown key 'ofset' \(did you mean 'offset'\?\)"),
    ({"chirp": {"amplitude": 1.0, "from": 1.0, "to": 2.0, "duration": 0.0}}, r"p\.chirp\.duration: got 0\.0; accepted is a duration > 0 \(s\)"),
])
def test_bad_profiles_are_refused_naming_the_key(raw, match):
    with pytest.raises(ProfileError, match=match):
        seg(raw, "number")


def test_force_supply_and_duty_profiles_act_on_the_rig(rig):
    sc = scenario_from_mapping({
        "duration": 0.3,
        "timeline": [
            {"t": 0.05, "force": {"ramp": {"to": "-1 kN", "duration": "100 ms"}}},
            {"t": 0.1, "supply": {"left": {"ramp": {"to": "150 bar", "duration": "50 ms"}}}},
            {"t": 0.1, "duty": {"right": {"table": [[0, 0.5], ["100 ms", 0.7]]}}},
        ],
    })
    inputs: dict[str, list[tuple[float, float]]] = {}
    rig.on_input = lambda step, name, value: inputs.setdefault(name, []).append((step * rig.dt, value))
    result = run_scenario(sc, rig=rig)
    run = result.run
    t = run.times
    duty = run.signal("right.duty")
    # the duty in force after each instant: the table's value at that instant
    for k in np.flatnonzero((t >= 0.1 - 1e-9) & (t <= 0.3)):
        assert duty[k] == pytest.approx(np.interp(t[k] - 0.1, [0, 0.1], [0.5, 0.7]), abs=1e-12)
    assert duty[np.flatnonzero(t < 0.1 - 1e-9)] == pytest.approx(0.5)

    def last_before(name, when):
        return [v for tt, v in inputs[name] if tt <= when + 1e-9][-1]
    # the force: -1 kN x (t - 0.05) / 0.1 at each control instant of the ramp, then -1 kN
    for when in (0.05, 0.08, 0.1, 0.149):
        k = math.floor(when / 1e-3 + 1e-9) * 1e-3
        assert last_before("cylinder.external_force", when) == pytest.approx(-1000.0 * (k - 0.05) / 0.1, abs=1e-9)
    assert last_before("cylinder.external_force", 0.3) == -1000.0
    assert last_before("left.supply_pressure", 0.125) == pytest.approx(200e5 - 50e5 * 0.025 / 0.05)
    assert last_before("left.supply_pressure", 0.3) == pytest.approx(150e5)
    # one supply event in the log, not one per period
    assert sum("supply_drop" in text for _, text in run.log) == 1
    assert any("external force: ramp" in text and "-1000 N" in text for _, text in result.events)


def test_sampling_a_profile_at_many_times_is_calling_it_at_each():
    """`Profile.sample` (the lockstep's setpoint, evaluated before the run) gives the numbers of
    calling the profile at each time, to the last bit, across every shape and a segment start."""
    segs = [seg({"value": 0.01}, "length", t=0.0), seg({"ramp": {"to": 0.02, "duration": 0.05}}, "length", t=0.1),
            seg({"sine": {"amplitude": 0.003, "frequency": 7.0, "offset": 0.01}}, "length", t=0.2),
            seg({"table": [[0, 0.0], [0.05, 0.004]]}, "length", t=0.3)]
    p = Profile(segs, initial=0.0)
    times = [k * 1e-3 for k in range(400)]
    assert p.sample(times) == [p(t) for t in times]
