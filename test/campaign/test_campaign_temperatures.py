"""Temperatures as campaign variables (docs/model.md R33, R34): the coils' ambient as a valve YAML
key, and a temperature profile of the scenario's timeline by its path in the file."""

import csv

import yaml

from pcv_sim.cli import main

from .conftest import REPO, SCENARIO


def _rig_with_options(tmp_path):
    """The shipped rig whose valves have a lumped coil with a 1 s time constant and the oil
    temperature as an input."""
    rig = yaml.safe_load((REPO / "config" / "rig.yaml").read_text())
    for name in rig["valves"]:
        valve = yaml.safe_load((REPO / "config" / "valve.yaml").read_text())
        valve["solenoid"].update(coil_temperature="lumped", coil_thermal_resistance=1.0, coil_heat_capacity=1.0)
        valve["fluid"]["temperature"] = "input"
        (tmp_path / f"{name}.yaml").write_text(yaml.safe_dump(valve))
        rig["valves"][name]["config"] = str(tmp_path / f"{name}.yaml")
    (tmp_path / "rig.yaml").write_text(yaml.safe_dump(rig))
    return tmp_path / "rig.yaml"


def test_campaign_over_ambient_and_a_cold_start_profile(write_campaign, tmp_path, capsys):
    """A sweep over `valves.solenoid.ambient_temperature_c` (the coils start at it) and over the
    start of a cold-start profile (`scenario.timeline[1].oil_temperature.ramp.from`): every
    variant runs, each column holds its SI value, and the variants' results differ (the valves
    see their temperatures)."""
    scenario = {**SCENARIO, "rig": str(_rig_with_options(tmp_path)),
                "timeline": [*SCENARIO["timeline"],
                             {"t": 0.0, "oil_temperature": {"ramp": {"from": "0 degC", "to": "40 degC",
                                                                     "duration": "0.3 s"}}}]}
    path = write_campaign({"sweep": {"parameters": {
        "valves.solenoid.ambient_temperature_c": [-20.0, 40.0],
        "scenario.timeline[1].oil_temperature.ramp.from": [253.15, 313.15]}}, "worst": 0,
        "gate": {"pass_rate": 0.0}}, scenario)
    assert main(["campaign", "run", str(path), "--out", str(tmp_path / "out"), "--json", "--workers", "1"]) == 0
    capsys.readouterr()
    with open(tmp_path / "out" / "results.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 4
    assert {r["status"] for r in rows} <= {"passed", "failed"}       # every variant ran (no error)
    assert {float(r["left.solenoid.ambient_temperature_c"]) for r in rows} == {-20.0, 40.0}
    assert {float(r["scenario.timeline[1].oil_temperature.ramp.from"]) for r in rows} == {253.15, 313.15}
    assert len({r["tracks.value"] for r in rows}) == 4
