"""Campaigns: a variant is the scenario with its values written into the files; the tables do
not depend on the number of workers; bad files exit 2 before any variant runs; a failing
controller is a failed variant; an interrupted campaign resumes."""
import csv
import json
import math

import pytest
import yaml

from pcv_sim.cli import main

from .conftest import REPO, SCENARIO

SWEEP = {"sweep": {"parameters": {"left.spool.spring_preload": [1.8, 2.2],
                                  "scenario.timeline[0].force": {"from": -300.0, "to": 300.0, "steps": 2}}},
         "worst": 1}
MONTE_CARLO = {"monte_carlo": {"samples": 3, "seed": 7, "sampling": "latin_hypercube", "parameters": {
    "valves.solenoid.coil_resistance": {"distribution": "normal", "sd": "3%", "truncate": "9%"},
    "valves.fluid.bulk_modulus": {"distribution": "uniform", "tolerance": "10%", "tied": True},
    "cylinder.mass": {"distribution": "uniform", "low": 40.0, "high": 60.0}}}, "worst": 0}


def read_rows(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def run_campaign(path, out, *extra):
    return main(["campaign", "run", str(path), "--out", str(out), "--json", *extra])


def scenario_files(tmp, row):
    """The scenario with the row's values written into copies of its valve, rig and scenario
    YAML files, as a user would edit them by hand; the scenario file's path."""
    tmp.mkdir()
    rig = yaml.safe_load((REPO / "config" / "rig.yaml").read_text())
    scenario = json.loads(json.dumps(SCENARIO))
    valves = {}
    for name in rig["valves"]:
        valves[name] = yaml.safe_load((REPO / "config" / "valve.yaml").read_text())
    for column, text in row.items():
        if "." not in column or column.startswith(("metric.", "fault.")) or column.endswith(
                (".passed", ".value", ".limit", ".margin")):
            continue
        head, _, rest = column.partition(".")
        value = float(text)
        if head == "cylinder":
            rig["cylinder"][rest] = value
        elif head == "scenario":
            assert rest == "timeline[0].force"
            scenario["timeline"][0]["force"] = value
        else:
            section, _, key = rest.partition(".")
            valves[head][section][key] = value
    for name, data in valves.items():
        (tmp / f"{name}.yaml").write_text(yaml.safe_dump(data))
        rig["valves"][name]["config"] = f"{name}.yaml"
    (tmp / "rig.yaml").write_text(yaml.safe_dump(rig))
    scenario["rig"] = "rig.yaml"
    (tmp / "scenario.yaml").write_text(yaml.safe_dump(scenario))
    return tmp / "scenario.yaml"


@pytest.mark.parametrize("campaign", [SWEEP, MONTE_CARLO], ids=["sweep", "monte_carlo"])
def test_variant_is_the_scenario_with_its_values_in_the_files(campaign, write_campaign, tmp_path, capsys):
    path = write_campaign(campaign)
    assert run_campaign(path, tmp_path / "out", "--workers", "1") == 0
    capsys.readouterr()
    rows = read_rows(tmp_path / "out" / "results.csv")
    assert len(rows) in (4, 3)
    names = [a["name"] for a in SCENARIO["assertions"]]
    seen = set()
    for row in rows:
        file = scenario_files(tmp_path / f"v{row['index']}", row)
        status = main(["scenario", "run", str(file), "--json"])
        out = json.loads(capsys.readouterr().out)
        assert row["status"] == ("passed" if status == 0 else "failed")
        for name, a in zip(names, out["assertions"]):
            assert a["name"] == name
            assert float(row[f"{name}.value"]) == a["value"], (row["index"], name)   # every bit
            assert row[f"{name}.passed"] == ("true" if a["passed"] else "false")
        seen.add(row["tracks.value"])
    assert len(seen) == len(rows)           # the variants differ: the values did land in the runs


def test_one_and_two_workers_give_the_same_table(write_campaign, tmp_path, capsys):
    path = write_campaign({**MONTE_CARLO, "sweep": {"parameters": {"scenario.timeline[0].force": [0.0, 300.0]}}})
    assert run_campaign(path, tmp_path / "one", "--workers", "1") == 0
    assert run_campaign(path, tmp_path / "two", "--workers", "2") == 0
    capsys.readouterr()
    one = (tmp_path / "one" / "results.csv").read_bytes()
    assert one == (tmp_path / "two" / "results.csv").read_bytes()
    rows = read_rows(tmp_path / "one" / "results.csv")
    assert [int(r["index"]) for r in rows] == list(range(6))
    # --variant K alone (a fresh rig) gives the campaign's assertion values
    assert main(["campaign", "run", str(path), "--variant", "4", "--json", "--report", str(tmp_path / "v4.html"),
                 "--bag", str(tmp_path / "v4")]) == 0
    alone = json.loads(capsys.readouterr().out)
    for name in ("tracks", "chamber a"):
        assert alone[f"{name}.value"] == float(rows[4][f"{name}.value"])
    assert "tracks" in (tmp_path / "v4.html").read_text()
    from mcap.reader import make_reader

    (bag,) = (tmp_path / "v4").glob("*.mcap")
    with bag.open("rb") as f:
        topics = {ch.topic for _, ch, _ in make_reader(f).iter_messages()}
    assert {"/left/pressure", "/setpoint"} <= topics


def test_monte_carlo_draws_follow_the_file(write_campaign, tmp_path, capsys):
    mc = {"monte_carlo": {"samples": 40, "seed": 3, "parameters": {
        "valves.spool.spring_preload": {"distribution": "normal", "sd": "5%", "truncate": "10%"},
        "right.solenoid.coil_resistance": {"distribution": "uniform", "tolerance": 0.2}}}}
    from pcv_sim.campaign.spec import load_campaign
    from pcv_sim.campaign.variants import Variants

    v = Variants(load_campaign(write_campaign(mc)))
    left = [v[k].values["left.spool.spring_preload"] for k in range(40)]
    right = [v[k].values["right.spool.spring_preload"] for k in range(40)]
    coil = [v[k].values["right.solenoid.coil_resistance"] for k in range(40)]
    assert all(1.8 <= x <= 2.2 for x in left + right)             # truncated at +-10 % of 2.0 N
    assert left != right                                           # independent per valve
    assert all(5.4 <= x <= 5.8 for x in coil) and "left.solenoid.coil_resistance" not in v[0].values
    assert Variants(load_campaign(write_campaign(mc)))[17].values == v[17].values      # (file, k) -> values
    tied = {"monte_carlo": {**mc["monte_carlo"], "parameters": {"valves.spool.spring_preload": {
        "distribution": "normal", "sd": "5%", "tied": True}}}}
    t = Variants(load_campaign(write_campaign(tied)))
    assert all(t[k].values["left.spool.spring_preload"] == t[k].values["right.spool.spring_preload"]
               for k in range(40))


@pytest.mark.parametrize(("campaign", "words"), [
    ({"sweep": {"parameters": {"left.spool.spring_preload": [2.0]}}, "colour": 1}, ["colour", "accepted"]),
    ({"monte_carlo": {"samples": 3, "parameters": {"cylinder.mass": {"distribution": "normal", "sd": -1.0}}}},
     ["monte_carlo.parameters.cylinder.mass.sd", "> 0"]),
    ({"monte_carlo": {"samples": 3, "parameters": {"cylinder.mass": {"distribution": "uniform", "low": 60.0,
                                                                       "high": 40.0}}}}, ["cylinder.mass", "low < high"]),
    ({"sweep": {"parameters": {"left.solenoid.coil_resistance": [5.6, 5600.0]}}},
     ["left.solenoid.coil_resistance", "5600", "accepted"]),
    ({"sweep": {"parameters": {"middle.spool.spring_preload": [2.0]}}}, ["middle", "no valve", "left, right"]),
    ({"faults": {"kinds": ["coil_open"], "targets": ["middle"], "onsets": [0.1]}}, ["faults.targets[0]", "left, right"]),
    ({"sweep": {"parameters": {"scenario.timeline[3].t": [0.1]}}}, ["scenario.timeline[3].t", "no such value"]),
    ({"sweep": {"parameters": [2.0]}}, ["sweep.parameters", "accepted is a mapping key -> values"]),
    ({"monte_carlo": {"samples": 3, "parameters": {}}}, ["monte_carlo.parameters", "mapping key -> {distribution"]),
    ({"monte_carlo": {"samples": 50, "seed": 1, "parameters": {"cylinder.mass": {"distribution": "normal",
                                                                                   "sd": 200.0}}}},
     ["cylinder.mass", "accepted"]),
])
def test_bad_file_exits_2_naming_the_key_before_any_variant(campaign, words, write_campaign, tmp_path, capsys):
    path = write_campaign(campaign)
    assert run_campaign(path, tmp_path / "out") == 2
    err = capsys.readouterr().err
    for w in words:
        assert w in err, err
    assert not (tmp_path / "out").exists()


CONTROLLER = '''
from pcv_sim.control.steering import PositionController


class Fragile:
    """The example controller, raising from `fail_at` s on (never when fail_at < 0)."""

    def __init__(self, fail_at):
        self.fail_at = fail_at
        self.inner = PositionController()

    def __call__(self, t, m):
        if 0 <= self.fail_at <= t:
            raise ZeroDivisionError("the controller divided by zero")
        return self.inner(t, m)
'''


def test_a_raising_controller_is_a_failed_variant(write_campaign, tmp_path, capsys):
    (tmp_path / "fragile.py").write_text(CONTROLLER)
    scenario = {**SCENARIO, "controller": "fragile:Fragile", "controller_params": {"fail_at": -1.0}}
    path = write_campaign({"sweep": {"parameters": {"scenario.controller_params.fail_at": [-1.0, 0.15, -1.0]}},
                           "gate": {"pass_rate": 0.6}, "worst": 1}, scenario)
    assert run_campaign(path, tmp_path / "out", "--workers", "2") == 0     # 2 of 3 pass: the gate holds
    s = json.loads(capsys.readouterr().out)
    assert (s["passed"], s["errors"]) == (2, 1)
    rows = read_rows(tmp_path / "out" / "results.csv")
    assert [r["status"] for r in rows] == ["passed", "error", "passed"]
    assert "ZeroDivisionError" in rows[1]["error"]
    assert rows[0]["tracks.value"] == rows[2]["tracks.value"]          # the rig after the error is sound
    assert (tmp_path / "out" / "report.html").is_file()
    assert s["worst"][0]["index"] == 1


def test_resume_runs_only_what_is_missing(write_campaign, tmp_path, capsys):
    path = write_campaign({**SWEEP, "worst": 0})
    out = tmp_path / "out"
    assert run_campaign(path, out, "--workers", "1") == 0
    full = (out / "results.csv").read_bytes()
    lines = (out / "variants.jsonl").read_text().splitlines()
    (out / "variants.jsonl").write_text("\n".join(lines[:2]) + "\n" + lines[2][:10])  # cut short as at Ctrl-C
    assert run_campaign(path, out) == 2                    # not without --resume
    assert run_campaign(path, out, "--resume", "--workers", "1") == 0
    capsys.readouterr()
    assert (out / "results.csv").read_bytes() == full
    kept = [json.loads(x)["index"] for x in (out / "variants.jsonl").read_text().splitlines()[:2]]
    assert kept == [0, 1]
    rerun = [json.loads(x)["index"] for x in (out / "variants.jsonl").read_text().splitlines()[2:]]
    assert sorted(rerun) == [2, 3]


def test_fault_matrix_with_onset_following_assertion(write_campaign, tmp_path, capsys):
    scenario = {**SCENARIO, "assertions": [{"name": "flagged", "type": "flag_within",
                                            "signal": "controller.fault_detected", "at": 0.1, "within": 0.06}]}
    path = write_campaign({"faults": {"kinds": ["coil_open", "supply_loss"], "targets": ["left", "right"],
                                      "onsets": [0.1, 0.15], "at_onset": ["scenario.assertions[0].at"]},
                           "gate": {"pass_rate": 0.0}, "worst": 0}, scenario)
    assert run_campaign(path, tmp_path / "out", "--workers", "1") == 0
    s = json.loads(capsys.readouterr().out)
    rows = read_rows(tmp_path / "out" / "results.csv")
    assert [(r["fault.kind"], r["fault.target"], float(r["fault.onset"])) for r in rows] == [
        (k, t, o) for k in ("coil_open", "supply_loss") for t in ("left", "right") for o in (0.1, 0.15)]
    coil = [r for r in rows if r["fault.kind"] == "coil_open"]
    # the coil monitor flags an open coil within 60 ms of each onset (its `at` followed the onset)
    assert all(r["flagged.passed"] == "true" for r in coil), coil
    assert all(0.0 <= float(r["flagged.value"]) <= 0.06 for r in coil)
    assert s["done"] == 8 and not math.isnan(s["pass_rate"])


pytest_plugins = ["pcv_sim.testing"]


def test_testing_helper_asserts_on_pass_rate_and_margins(rig_campaign, tmp_path, monkeypatch):
    (tmp_path / "short.yaml").write_text(yaml.safe_dump(SCENARIO))
    monkeypatch.chdir(tmp_path)
    result = rig_campaign({"scenario": "short.yaml", "sweep": {"parameters": {"cylinder.mass": [40.0, 60.0]}}})
    assert result.passed and result.pass_rate == 1.0, result.text()
    assert 0 < result.worst_margin("tracks") < 2.5e-3
    assert result.worst_margin("tracks") == min(float(r["tracks.margin"]) for r in result.rows)
    with pytest.raises(KeyError, match="tracks"):
        result.worst_margin("nonesuch")


def test_example_campaigns_load():
    from pcv_sim.campaign.spec import load_campaign
    from pcv_sim.campaign.variants import Variants

    tol = load_campaign(REPO / "examples" / "campaigns" / "tolerances.yaml")
    v = Variants(tol, validate=True)
    assert len(v) == 500
    assert set(v[0].values) == {f"{s}.{k}" for s in ("left", "right") for k in (
        "spool.spring_preload", "solenoid.coil_resistance", "fluid.bulk_modulus")}
    faults = Variants(load_campaign(REPO / "examples" / "campaigns" / "valve_faults.yaml"), validate=True)
    assert len(faults) == 8 * 2 * 3
    assert faults[5].at == {("assertions", 0, "after"): 0.9}


@pytest.mark.parametrize("sig", ["SIGINT", "SIGTERM"])
def test_ctrl_c_keeps_finished_variants_and_resume_completes(sig, write_campaign, tmp_path, capsys):
    """SIGINT or SIGTERM to a running `pcv-sim campaign run` (2 workers): exit 130, every finished
    variant kept; --resume runs the rest and the table is that of an uninterrupted run. The child
    starts with SIGINT ignored, as a job put in the background by a non-interactive shell (a CI
    script's `&`, nohup) inherits it: the command must stop on it all the same."""
    import signal
    import subprocess
    import sys
    import time

    from .conftest import child_env

    mc = {"monte_carlo": {**MONTE_CARLO["monte_carlo"], "samples": 40}, "worst": 0, "gate": {"pass_rate": 0.0}}
    path = write_campaign(mc)
    out = tmp_path / "cut"
    ignoring_sigint = ["sh", "-c", 'trap "" INT; exec "$0" "$@"']      # as `cmd &` in a script
    p = subprocess.Popen([*ignoring_sigint, sys.executable, "-m", "pcv_sim", "campaign", "run", str(path), "--out",
                          str(out), "--workers", "2", "--json"], env=child_env(), stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE)
    try:
        log = out / "variants.jsonl"
        deadline = time.monotonic() + 240
        while not (log.is_file() and len(log.read_text().splitlines()) >= 3):
            assert p.poll() is None and time.monotonic() < deadline, p.communicate()
            time.sleep(0.05)
        p.send_signal(getattr(signal, sig))
        _, err = p.communicate(timeout=60)
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()
    assert p.returncode == 130, err
    kept = read_rows(out / "results.csv")
    assert 3 <= len(kept) < 40
    assert run_campaign(path, out, "--resume", "--workers", "1") == 0
    assert run_campaign(path, tmp_path / "whole", "--workers", "1") == 0
    capsys.readouterr()
    assert (out / "results.csv").read_bytes() == (tmp_path / "whole" / "results.csv").read_bytes()


@pytest.mark.parametrize("method", ["sobol", "morris"])
def test_sensitivity_ranks_the_coil_above_the_mass_for_the_pressure(method, write_campaign, tmp_path, capsys):
    """SALib's indices of each margin: the coil resistance sets the current and so the pressure;
    the moving mass barely changes the peak chamber pressure of a 10 mm step."""
    path = write_campaign({"sensitivity": {"method": method, "samples": 4, "seed": 1, "parameters": {
        "valves.solenoid.coil_resistance": {"tolerance": "3%", "tied": True},
        "cylinder.mass": {"low": 40.0, "high": 60.0}}}, "gate": {"pass_rate": 0.0}, "worst": 0})
    assert run_campaign(path, tmp_path / "out", "--workers", "1") == 0
    s = json.loads(capsys.readouterr().out)
    assert s["variants"] == 4 * (2 + 2 if method == "sobol" else 2 + 1)
    idx = s["sensitivity"]["indices"]["chamber a"]
    key = "ST" if method == "sobol" else "mu_star"
    assert idx["valves.solenoid.coil_resistance"][key] > 10 * idx["cylinder.mass"][key], idx
    rows = read_rows(tmp_path / "out" / "results.csv")
    assert all(r["left.solenoid.coil_resistance"] == r["right.solenoid.coil_resistance"] for r in rows)   # tied


def test_sensitivity_sobol_needs_a_power_of_two(write_campaign, tmp_path, capsys):
    path = write_campaign({"sensitivity": {"method": "sobol", "samples": 6, "parameters": {
        "cylinder.mass": {"low": 40.0, "high": 60.0}}}})
    assert run_campaign(path, tmp_path / "out") == 2
    assert "sensitivity.samples" in capsys.readouterr().err


def test_progress_on_a_terminal_only(capsys, monkeypatch):
    import argparse

    from pcv_sim.commands.campaign import Progress, _interactive

    p = Progress(0, True)
    p.start(2)
    p.update({"status": "passed"})
    p.update({"status": "error"})
    p.close()
    err = capsys.readouterr().err
    assert "2/2 done, 1 failed" in err and "ETA 0 s" in err
    monkeypatch.delenv("CI", raising=False)
    monkeypatch.setattr("sys.stderr.isatty", lambda: True)
    assert _interactive(argparse.Namespace(json=False))
    assert not _interactive(argparse.Namespace(json=True))
    monkeypatch.setenv("CI", "true")
    assert not _interactive(argparse.Namespace(json=False))


def test_campaign_over_oil_temperature_runs(write_campaign, tmp_path, capsys):
    """The valves' oil temperature (docs/model.md R34) as a campaign variable: a sweep over
    `valves.fluid.oil_temperature_c` with the valves' oil temperature an input runs every variant
    (-20 degC at the rig's step: the spool's pole taken exactly), and the cold oil shows in the
    tracking (a slower valve)."""
    rig = yaml.safe_load((REPO / "config" / "rig.yaml").read_text())
    for name in rig["valves"]:
        valve = yaml.safe_load((REPO / "config" / "valve.yaml").read_text())
        valve["fluid"]["temperature"] = "input"
        (tmp_path / f"{name}.yaml").write_text(yaml.safe_dump(valve))
        rig["valves"][name]["config"] = str(tmp_path / f"{name}.yaml")
    (tmp_path / "rig.yaml").write_text(yaml.safe_dump(rig))
    scenario = {**SCENARIO, "rig": str(tmp_path / "rig.yaml")}
    path = write_campaign({"sweep": {"parameters": {"valves.fluid.oil_temperature_c": [-20.0, 40.0]}}, "worst": 0},
                          scenario)
    assert run_campaign(path, tmp_path / "out", "--workers", "1") in (0, 1)
    capsys.readouterr()
    rows = read_rows(tmp_path / "out" / "results.csv")
    assert len(rows) == 2
    assert {r["status"] for r in rows} <= {"passed", "failed"}      # every variant ran (no error)
    cold, warm = sorted(rows, key=lambda r: float(r["left.fluid.oil_temperature_c"]))
    assert float(cold["left.fluid.oil_temperature_c"]) == -20.0
    assert all(math.isfinite(float(r["tracks.value"])) for r in rows)
    assert float(cold["tracks.value"]) > float(warm["tracks.value"])  # the cold valves track worse


def test_monte_carlo_over_a_scenario_value_written_with_its_unit(write_campaign, tmp_path, capsys):
    """`setpoint: 10 mm` in the scenario: a Monte Carlo of it draws in SI around 0.01 m (its other
    numbers may carry a unit of the same kind), and variant k runs the scenario with its SI value
    written in; a unit of another kind is refused naming the key."""
    scenario = json.loads(json.dumps(SCENARIO))
    scenario["setpoint"][1]["value"] = "10 mm"
    mc = {"monte_carlo": {"samples": 3, "seed": 5, "parameters": {
        "scenario.setpoint[1].value": {"distribution": "normal", "sd": "0.5 mm", "truncate": "10%"}}}, "worst": 0,
        "gate": {"pass_rate": 0.0}}
    path = write_campaign(mc, scenario=scenario)
    assert run_campaign(path, tmp_path / "out", "--workers", "1") == 0
    capsys.readouterr()
    rows = read_rows(tmp_path / "out" / "results.csv")
    values = [float(r["scenario.setpoint[1].value"]) for r in rows]
    assert all(0.009 <= v <= 0.011 for v in values) and len(set(values)) == 3
    for row, v in zip(rows, values):
        alone = json.loads(json.dumps(scenario))
        alone["setpoint"][1]["value"] = v
        (tmp_path / f"alone{row['index']}.yaml").write_text(yaml.safe_dump(alone))
        main(["scenario", "run", str(tmp_path / f"alone{row['index']}.yaml"), "--json"])
        out = json.loads(capsys.readouterr().out)
        assert float(row["tracks.value"]) == out["assertions"][0]["value"]        # every bit
    bad = {"monte_carlo": {**mc["monte_carlo"], "parameters": {
        "scenario.setpoint[1].value": {"distribution": "normal", "sd": "1 bar"}}}}
    assert run_campaign(write_campaign(bad, scenario=scenario, name="bad.yaml"), tmp_path / "bad") == 2
    err = capsys.readouterr().err
    assert "scenario.setpoint[1].value" in err and "sd" in err and "mm" in err


def test_margins_are_shown_in_engineering_units(write_campaign, tmp_path, capsys):
    """The summary's text and the report give each assertion's limit and worst margin in its
    engineering unit (mm for the position, bar for a pressure); the table and --json stay SI."""
    path = write_campaign({"sweep": {"parameters": {"cylinder.mass": [40.0, 60.0]}}, "worst": 0})
    assert main(["campaign", "run", str(path), "--out", str(tmp_path / "out"), "--workers", "1"]) == 0
    text = capsys.readouterr().out
    line = next(x for x in text.splitlines() if x.strip().startswith("tracks:"))
    assert " mm " in line and "limit 2.5 mm" in line, line
    assert "limit 180 bar" in next(x for x in text.splitlines() if x.strip().startswith("chamber a:"))
    html = (tmp_path / "out" / "report.html").read_text()
    assert "2.5 mm" in html and "180 bar" in html
    rows = read_rows(tmp_path / "out" / "results.csv")
    assert float(rows[0]["tracks.limit"]) == 2.5e-3


def test_chunks_fall_in_size_to_single_variants_at_the_end():
    """Each variant once, in order, in chunks of at most 8 that only shrink, the last 2 per worker
    single variants: no worker waits for another's last chunk longer than one variant."""
    from pcv_sim.campaign.executors import chunks

    for n, workers in ((40, 2), (1000, 16), (3, 2), (0, 2), (17, 1)):
        parts = chunks(list(range(100, 100 + n)), workers)
        assert [k for c in parts for k in c] == list(range(100, 100 + n))
        sizes = [len(c) for c in parts]
        assert all(1 <= s <= 8 for s in sizes) and sizes == sorted(sizes, reverse=True)
        tail = min(n, 2 * workers)
        assert sizes[len(sizes) - tail:] == [1] * tail
        assert n < 40 or sizes[0] == 8
