"""Values with units in files: parsed to SI in one place, a unit slip refused with its likely meaning."""

import pytest

from pcv_sim.keys import closest, missing_message, unknown_message
from pcv_sim.units import UnitError, quantity


@pytest.mark.parametrize(("raw", "kind", "si"), [
    ("100 bar", "pressure", 1.0e7), ("5 mm", "length", 5.0e-3), ("20 ms", "time", 0.02), ("-1 kN", "force", -1000.0),
    ("12 L/min", "flow", 12.0e-3 / 60.0), ("2.5e-1 MPa", "pressure", 2.5e5), ("70 %", "fraction", 0.7),
    (1.0e7, "pressure", 1.0e7), (0.005, "length", 0.005), (3, "time", 3.0), ("0.5", "time", 0.5),
    (0, "pressure", 0.0), ("+.5 s", "time", 0.5),
])
def test_values_with_units_are_si(raw, kind, si):
    assert quantity(raw, kind, "x") == pytest.approx(si, rel=1e-12)


def test_a_rate_takes_its_unit_per_time():
    assert quantity("2 bar/s", "pressure", "drift", rate=True) == pytest.approx(2.0e5)
    assert quantity("6 mm/min", "length", "drift", rate=True) == pytest.approx(1.0e-4)
    with pytest.raises(UnitError, match=r"drift: unit 'bar' in '2 bar'.*accepted for a pressure rate are Pa/s"):
        quantity("2 bar", "pressure", "drift", rate=True)


@pytest.mark.parametrize(("raw", "kind", "role", "match"), [
    (100, "pressure", "supply pressure", r"p: 100 is 100 Pa, below any supply pressure; did you mean 100 bar\? "
                                         r"Write the unit: '100 bar'"),
    (180, "pressure", "", r"180 is 180 Pa, below any plausible pressure; did you mean 180 bar\?"),
    (5, "length", "", r"5 is 5 m, above any plausible length; did you mean 5 mm\?"),
    (12, "flow", "", r"did you mean 12 L/min\?"),
    (70, "fraction", "", r"did you mean 70 %\?"),
    ("5 kg", "length", "", r"p: unit 'kg' in '5 kg'; accepted for a length are m, cm, mm"),
    ("5 ms", "length", "", r"unit 'ms' in '5 ms' \(ms is a unit of time\)"),
    ("bar 5", "pressure", "", r"accepted is '<number> <unit>'"),
    (True, "time", "", r"got True; accepted is a number \(s\)"),
    (float("nan"), "time", "", r"accepted is a finite number"),
    ([1, "bar"], "pressure", "", r"accepted is a number \(Pa\) or a value with a unit"),
])
def test_unit_slips_and_bad_values_are_refused_with_the_likely_meaning(raw, kind, role, match):
    with pytest.raises(UnitError, match=match):
        quantity(raw, kind, "p", role=role)


def test_a_value_written_with_its_unit_is_taken_at_its_word():
    assert quantity("100 Pa", "pressure", "p") == 100.0
    assert quantity("5 m", "length", "p") == 5.0


def test_misspelt_keys_name_the_closest_accepted_one():
    assert closest("forces", ("duty", "force", "fault")) == "force"
    assert closest("Pressure", ("pressure",)) == "pressure"
    assert closest("zzz", ("duty", "force")) is None
    msg = unknown_message("timeline[2].ramp", {"to": 1, "duraton": 2}, ("to", "duration", "from"))
    assert msg == "timeline[2].ramp: unknown key 'duraton' (did you mean 'duration'?); accepted: to, duration, from"
    assert unknown_message("x", {"to": 1}, ("to",)) is None
    assert missing_message("timeline[0]", {"t": 0.1, "forces": 1}, ("duty", "force")) == (
        "timeline[0]: accepted is exactly one of duty, force; got 'forces' (did you mean 'force'?)")
    assert missing_message("timeline[0]", {"t": 0.1}, ("duty", "force")).endswith("got none")


def test_the_rig_yaml_takes_values_with_units(tmp_path):
    from pathlib import Path

    from pcv_sim.errors import PcvSimError
    from pcv_sim.rig.params import load_rig

    config = Path(__file__).resolve().parents[1] / "config"
    text = (config / "rig.yaml").read_text().replace("config: valve.yaml", f"config: {config / 'valve.yaml'}")
    assert "control_period: 1.0e-3 " in text and "coulomb_friction: 150.0 " in text
    path = tmp_path / "rig.yaml"
    path.write_text(text.replace("control_period: 1.0e-3 ", "control_period: 1 ms ")
                    .replace("coulomb_friction: 150.0 ", "coulomb_friction: 0.15 kN "))
    rig = load_rig(path)
    assert rig.timing.control_period == pytest.approx(1e-3) and rig.cylinder.coulomb_friction == pytest.approx(150.0)
    path.write_text(text.replace("coulomb_friction: 150.0 ", "coulomb_friction: 150 bar "))
    with pytest.raises(PcvSimError, match=r"coulomb_friction: unit 'bar' in '150 bar' \(bar is a unit of pressure\)"):
        load_rig(path)


def test_a_difference_is_shown_without_the_units_zero():
    from pcv_sim.units import fmt

    assert fmt(275.15, "temperature") == "2 degC"
    assert fmt(2.0, "temperature", difference=True) == "2 degC"      # a bias of 2 K
