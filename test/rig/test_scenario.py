"""Scenarios: validation of the file, assertions, the command (exit 0/1/2, --json, --bag,
--report, a directory in parallel) and the pytest fixture."""

import json
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from pcv_sim.cli import main
from pcv_sim.io import read_bag
from pcv_sim.rig.scenario import ScenarioError, scenario_from_mapping

pytest_plugins = ["pcv_sim.testing"]

REPO = Path(__file__).resolve().parents[2]
EXAMPLES = REPO / "examples"
sys.path.insert(0, str(EXAMPLES))
from steering import PositionController  # noqa: E402


def _step():
    return yaml.safe_load((EXAMPLES / "step.yaml").read_text())


@pytest.mark.parametrize(("edit", "match"), [
    (lambda d: d.update(durration=1.0), r"scenario: unknown key 'durration' \(did you mean 'duration'\?\); accepted: name, rig, duration"),
    (lambda d: d.pop("duration"), r"duration: missing"),
    (lambda d: d.update(duration=-1), r"duration: got -1; accepted is a duration in 0\.001 \.\. 3600 \(s\)"),
    (lambda d: d.update(controller="steering.PositionController"), r"controller: .* accepted is 'module:callable'"),
    (lambda d: d["setpoint"].append({"t": 0.05, "value": 0.0}), r"setpoint\[2\]\.t: got 0\.05; accepted is a time after the previous segment's > 0\.1 \(s\)"),
    (lambda d: d["setpoint"].append({"t": 0.5, "value": "2 cm"}), None),
    (lambda d: d["setpoint"].append({"t": 0.5, "value": "2000 mm"}),
     r"setpoint\[2\]\.value: got '2000 mm'; accepted is a position in -1 \.\. 1 \(m\)"),
    (lambda d: d.update(timeline=[{"t": 0.1, "fault": "coil_open", "target": "middle"}]),
     r"timeline\[0\]\.fault: target 'middle' for coil_open; accepted are left, right"),
    (lambda d: d.update(timeline=[{"t": 0.1, "fault": "supply_drop", "target": "left", "pressure": 200}]),
     r"timeline\[0\]\.pressure: 200 is 200 Pa, below any supply pressure; did you mean 200 bar\?"),
    (lambda d: d.update(timeline=[{"t": 0.1, "fault": "supply_drop", "target": "left", "pressure": "200 Pa"}]), None),
    (lambda d: d.update(timeline=[{"t": 0.1, "forces": 500}]),
     r"timeline\[0\]: accepted is exactly one of duty, force, supply, ambient_temperature, oil_temperature, fault, clear; got 'forces' \(did you mean 'force'\?\)"),
    (lambda d: d.update(timeline=[{"t": 0.1, "fault": "bias", "target": "left.pressure", "value": "5 mm"}]),
     r"timeline\[0\]\.value: unit 'mm' in '5 mm' \(mm is a unit of length\); accepted for a pressure are Pa"),
    (lambda d: d.update(timeline=[{"t": 0.1, "fault": "bias", "target": "left.pressure", "value": 5}]), None),
    (lambda d: d.update(timeline=[{"t": 0.1, "fault": "coil_opne", "target": "left"}]), r"did you mean 'coil_open'\?"),
    (lambda d: d["assertions"].append({"type": "never_above", "signal": "left.pressure", "max": 180}),
     r"assertions\[3\]\.max: 180 is 180 Pa, below any plausible pressure; did you mean 180 bar\?"),
    (lambda d: d["assertions"].append({"type": "never_above", "signal": "left.pressure", "max": "180 mm"}),
     r"assertions\[3\]\.max: unit 'mm' in '180 mm' \(mm is a unit of length\); accepted for a pressure are Pa"),
    (lambda d: d["assertions"].append({"type": "step_respons", "signal": "cylinder.position"}),
     r"assertions\[3\]\.type: got 'step_respons' \(did you mean 'step_response'\?\)"),
    (lambda d: d["assertions"].append({"type": "within_band", "signal": "cylinder.position", "reference": "setpoint",
                                       "tolerance": "1 mm", "after": {"event": "fault"}}),
     r"assertions\[3\]\.after\.event: 'fault' is not on the timeline"),
    (lambda d: d["setpoint"].append({"t": 0.5, "ramp": {"to": "10 mm", "duraton": "0.2 s"}}),
     r"setpoint\[2\]\.ramp: unknown key 'duraton' \(did you mean 'duration'\?\)"),
    (lambda d: d["setpoint"].append({"t": 0.5, "value": 20}),
     r"setpoint\[2\]\.value: 20 is 20 m, above any plausible length; did you mean 20 mm\?"),
    (lambda d: d.update(timeline=[{"t": 0.1, "duty": {"left": 70}}]), r"timeline\[0\]\.duty\.left: 70 is 70 \(a fraction\), above any plausible fraction; did you mean 70 %\?"),
    (lambda d: d.update(timeline=[{"t": 0.1, "force": 1.0, "duty": {"left": 0.5}}]), r"exactly one of duty, force, supply, ambient_temperature, oil_temperature, fault, clear \(got duty, force\)"),
    (lambda d: d["assertions"].append({"type": "always_fine", "signal": "left.pressure"}),
     r"assertions\[3\]\.type: got 'always_fine'; accepted are max_error"),
    (lambda d: d["assertions"].append({"type": "never_above", "signal": "left.presure", "max": 1.0}),
     r"assertions\[3\]\.signal: got 'left.presure' \(did you mean 'left.pressure'\?\); accepted are left\.pressure"),
    (lambda d: d["assertions"].append({"type": "never_above", "signal": "left.pressure"}), r"never_above needs max"),
    (lambda d: d.update(rig="nosuch.yaml"), r"rig: cannot read rig file"),
    (lambda d: d.update(controller={"ros": {"namespace": "rig ns"}}), r"controller\.ros\.namespace: got 'rig ns'"),
    (lambda d: d.update(controller={"ros": {"namespce": "/rig"}}), r"controller\.ros: unknown key 'namespce' \(did you mean 'namespace'\?\)"),
    (lambda d: d.update(controller={"ros": {"command": "steering_controller"}}),
     r"controller\.ros\.command: got 'steering_controller'; accepted is a list"),
    (lambda d: d.update(controller={"ros": {"command": ["{pyhton}"]}}), r"accepted placeholders are \{namespace\}"),
    (lambda d: d.update(controller={"ros": {"wait": 0}}), r"controller\.ros\.wait: got 0"),
    (lambda d: d.update(controller={"ros": {}}, controller_params={"kp": 1.0}),
     r"controller_params: for a Python callable"),
    (lambda d: d.update(controller={"ros": {"namespace": "/rig", "command": ["{python}", "-m", "x"], "wait": 5}}),
     None),
])
def test_bad_scenarios_are_refused_naming_the_key(edit, match):
    data = _step()
    edit(data)
    if match is None:           # a value written with its unit is taken at its word; a full ROS spec: accepted
        scenario_from_mapping(data, path=EXAMPLES / "step.yaml")
        return
    with pytest.raises(ScenarioError, match=match):
        scenario_from_mapping(data, path=EXAMPLES / "step.yaml")


def test_the_fixture_runs_a_users_controller_through_a_scenario(rig_scenario):
    result = rig_scenario(EXAMPLES / "step.yaml", controller=PositionController(), duration=1.0)
    assert result.passed, result.summary()
    assert result.run.signal("cylinder.position")[-1] == pytest.approx(0.02, abs=5e-4)
    # A controller that does nothing leaves the piston where it was: the settling assertion fails.
    lazy = rig_scenario(EXAMPLES / "step.yaml", controller=lambda t, m: {"left": 0.5, "right": 0.5}, duration=1.0)
    assert not lazy.passed
    failed = [o.name for o in lazy.outcomes if not o.passed]
    assert failed == ["settles within 0.5 mm", "no false fault alarm"]      # the lazy one reports no flag either


def test_scenario_with_noise_repeats_bit_for_bit(rig_scenario):
    data = _step()
    data.update(duration=0.3, rig=str(REPO / "config" / "rig.yaml"),
                timeline=[{"t": 0.1, "fault": "noise", "target": "cylinder.position", "std": 2e-4}])
    a = rig_scenario(data, controller=PositionController())
    b = rig_scenario(data, controller=PositionController())
    assert np.array_equal(a.run.true, b.run.true) and np.array_equal(a.run.measured, b.run.measured, equal_nan=True)
    c = rig_scenario({**data, "seed": 1}, controller=PositionController())
    assert not np.array_equal(a.run.true, c.run.true)       # other noise, other commands, other physics


def test_command_json_bag_and_report(tmp_path, capsys):
    scen = tmp_path / "short.yaml"
    data = _step()
    data.update(duration=0.4, rig=str(REPO / "config" / "rig.yaml"),
                timeline=[{"t": 0.2, "fault": "dropout", "target": "right.current"}])
    data["assertions"] = [{"type": "never_above", "signal": "left.pressure", "max": 1.8e7},
                          {"type": "never_below", "signal": "cylinder.position", "min": 0.0}]
    scen.write_text(yaml.safe_dump(data))
    (tmp_path / "steering.py").write_text((EXAMPLES / "steering.py").read_text())
    code = main(["scenario", "run", str(scen), "--json", "--bag", str(tmp_path / "bag"),
                 "--report", str(tmp_path / "r.html")])
    out = json.loads(capsys.readouterr().out)
    assert code == 1 and out["status"] == 1                   # the step undershoots 0 first: never_below fails
    assert [a["passed"] for a in out["assertions"]] == [True, False]
    assert out["real_time_factor"] > 0
    bag = read_bag(tmp_path / "bag")
    topics = set(bag.topic_types)
    assert bag.topic_types["/cylinder/joint_states"] == "sensor_msgs/msg/JointState"
    assert {"/left/pressure", "/right/current", "/cylinder/joint_states", "/cylinder/pressure_a", "/setpoint",
            "/rig/events"} <= topics
    # 0.4 s at 1 kHz: 401 samples; the right current dropped out from 0.2 s on (no messages).
    assert len(bag["/left/pressure"]) == 401
    assert len(bag["/right/current"]) == 200
    # the controller's flag, one message per answered period (the last instant has no answer)
    assert bag.topic_types["/controller/fault_detected"] == "std_msgs/msg/Float64"
    assert len(bag["/controller/fault_detected"]) == 400
    html = (tmp_path / "r.html").read_text()
    assert "FAILED" in html and "data:image/png;base64," in html


def test_command_bad_file_exits_2_naming_the_key(tmp_path, capsys):
    scen = tmp_path / "bad.yaml"
    scen.write_text("duration: 1.0\ncontroler: steering:PositionController\n")
    assert main(["scenario", "run", str(scen)]) == 2
    assert "unknown key 'controler' (did you mean 'controller'?)" in capsys.readouterr().err


def test_command_runs_a_directory_in_parallel_with_one_summary(tmp_path, capsys):
    (tmp_path / "steering.py").write_text((EXAMPLES / "steering.py").read_text())
    for name, limit in (("good", 1.8e7), ("bad", 1.0e6)):
        data = {"rig": str(REPO / "config" / "rig.yaml"), "duration": 0.2, "controller": "steering:PositionController",
                "assertions": [{"type": "never_above", "signal": "left.pressure", "max": limit}]}
        (tmp_path / f"{name}.yaml").write_text(yaml.safe_dump(data))
    (tmp_path / "broken.yaml").write_text("duration: [\n")
    code = main(["scenario", "run", str(tmp_path), "--jobs", "2"])
    out = capsys.readouterr().out
    assert code == 2
    assert "3 scenarios: 1 passed, 1 failed, 1 bad files" in out
    assert "broken: BAD FILE" in out and "not valid YAML" in out


def test_command_refuses_a_valve_config_and_a_missing_path(tmp_path, capsys):
    assert main(["scenario", "run", str(EXAMPLES / "step.yaml"), "--config", "valve.yaml"]) == 2
    assert "valves.<name>.config" in capsys.readouterr().err
    assert main(["scenario", "run", str(tmp_path / "nope.yaml")]) == 2
    assert "no such scenario file or directory" in capsys.readouterr().err


def test_controller_module_beside_the_file_and_import_errors(tmp_path, capsys):
    (tmp_path / "mine.py").write_text("def ctrl(t, m):\n    return {'left': 0.6, 'right': 0.6}\n")
    data = {"rig": str(REPO / "config" / "rig.yaml"), "duration": 0.05, "controller": "mine:ctrl",
            "assertions": [{"type": "never_below", "signal": "left.duty", "min": 0.6, "after": 0.001}]}
    (tmp_path / "ok.yaml").write_text(yaml.safe_dump(data))
    assert main(["scenario", "run", str(tmp_path / "ok.yaml")]) == 0
    (tmp_path / "missing.yaml").write_text(yaml.safe_dump({**data, "controller": "nosuchmodule:ctrl"}))
    assert main(["scenario", "run", str(tmp_path / "missing.yaml")]) == 2
    assert "cannot import 'nosuchmodule'" in capsys.readouterr().err
    (tmp_path / "noattr.yaml").write_text(yaml.safe_dump({**data, "controller": "mine:nothing"}))
    assert main(["scenario", "run", str(tmp_path / "noattr.yaml")]) == 2
    assert "mine has no callable 'nothing'" in capsys.readouterr().err


def test_every_example_scenario_loads():
    from pcv_sim.rig.scenario import load_scenario

    # examples/campaigns holds campaign files (test/campaign loads them)
    files = sorted(f for f in EXAMPLES.rglob("*.yaml") if f.parent.name != "campaigns")
    assert EXAMPLES / "ros" / "step.yaml" in files
    for f in files:
        sc = load_scenario(f)
        assert (sc.ros is not None) == (f.parent.name == "ros"), f
    ros = load_scenario(EXAMPLES / "ros" / "step.yaml").ros
    assert ros.namespace == "/steering" and ros.argv("py")[:3] == ["py", "-m", "pcv_sim.node.steering_controller"]
    assert "__ns:=/steering" in ros.argv("py")


def test_a_ros_controller_is_refused_below_the_node_layer():
    """rig.scenario.run_scenario runs callables; a ROS controller needs the node layer's host."""
    from pcv_sim.rig.scenario import run_scenario

    data = _step()
    data["controller"] = {"ros": {"namespace": "/x", "wait": 1.0}}
    sc = scenario_from_mapping(data, path=EXAMPLES / "step.yaml")
    assert sc.ros is not None
    with pytest.raises(ScenarioError, match=r"the controller is a ROS node; run it with "
                                            r"pcv_sim\.node\.scenario_host\.run_ros_scenario"):
        run_scenario(sc)


def test_the_readme_example_works_for_a_controller_without_flags(rig_scenario):
    """The README's pytest example, run as written with a controller that reports no flags."""
    import re as _re

    readme = (REPO / "README.md").read_text()
    block = next(b for b in _re.findall(r"```python\n(.*?)```", readme, _re.S) if "def test_my_controller" in b)

    class MyController:                 # the example's PI, without its flags
        def __init__(self):
            self.inner = PositionController()

        def __call__(self, t, m):
            out = dict(self.inner(t, m))
            out.pop("flags", None)
            return out

    space = {"MyController": MyController}
    exec(block.replace("examples/", str(EXAMPLES) + "/"), space)
    space["test_my_controller"](rig_scenario)
    result = rig_scenario(EXAMPLES / "step.yaml", controller=MyController(), duration=1.0)
    assert not result.run.flags
    assert [o.name for o in result.outcomes if not o.passed] == ["no false fault alarm"]


def test_a_shorter_duration_drops_later_events_with_a_note(rig_scenario):
    result = rig_scenario(EXAMPLES / "coil_open.yaml", controller=PositionController(), duration=0.8)
    assert result.notes == ["timeline[1] (clear at 1 s) is after the run's end (0.8 s): dropped"]
    assert "note: timeline[1]" in result.summary()
    assert [text for _, text in result.events] == ["fault coil_open on left"]


def test_fault_values_take_units_and_are_told_in_them():
    """A fault's values in the timeline with units (their kind from the faults' declarations, a
    sensor fault's from its signal), stored in SI and told back in engineering units."""
    s = scenario_from_mapping({"duration": 1.0, "timeline": [
        {"t": 0.1, "fault": "supply_drop", "target": "left", "pressure": "80 bar"},
        {"t": 0.2, "fault": "drift", "target": "left.pressure", "rate": "0.5 bar/s"},
        {"t": 0.3, "fault": "delay", "target": "left.pressure", "delay": "20 ms"},
        {"t": 0.4, "fault": "coil_short", "target": "left", "resistance_factor": "50 %"},
        {"t": 0.5, "clear": "coil_short", "target": "left"}]})
    assert [{k: v for k, v in e.items() if k not in ("t", "fault", "clear", "target")} for e in s.timeline] == [
        {"pressure": pytest.approx(8e6)}, {"rate": pytest.approx(5e4)}, {"delay": pytest.approx(0.02)},
        {"resistance_factor": pytest.approx(0.5)}, {}]
    assert [text for _, text in s.events()] == [
        "fault supply_drop on left: pressure 80 bar", "fault drift on left.pressure: rate 0.5 bar/s",
        "fault delay on left.pressure: delay 20 ms", "fault coil_short on left: resistance_factor 50 %",
        "clear coil_short on left"]
