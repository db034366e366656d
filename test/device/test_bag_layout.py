"""The one bag layout against the bags of the two layouts it replaced: the emulator's and the rig's
live recordings and the scenario runner's offline bag, written again by `DeviceRecorder` on
`BagLayout` from the same scripted runs, compared topic by topic and message by message (log time,
publish time, serialized bytes) and by their metadata, with the mcap reader. The reference bags
in test/device/data were written by the recorders before they became one (bag_drive.py: the
emulator's `BagRecorder`, the rig's `RigRecorder`, `pcv-sim scenario run --bag`)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml
from bag_drive import emulator_run, messages, rig_run

from pcv_sim.cli import main
from pcv_sim.device.recording import BagLayout, DeviceRecorder
from pcv_sim.device.valve import ValveDevice
from pcv_sim.errors import BagError
from pcv_sim.io.bag.metadata import detect_ros_distro
from pcv_sim.io.recorder import WriterSettings
from pcv_sim.params import load_params
from pcv_sim.rig import Rig, load_rig

DATA = Path(__file__).parent / "data"
REPO = Path(__file__).parents[2]
W = WriterSettings(writer="inline", ros_distro="kilted")

#: A short lockstep scenario: a fault on the left valve and its clearing, the example controller.
SCENARIO = """\
name: short
rig: {rig}
duration: 0.12
controller: pcv_sim.control.steering:PositionController
setpoint:
  - {{t: 0.0, value: 10 mm}}
timeline:
  - {{t: 0.03, fault: coil_open, target: left}}
  - {{t: 0.08, clear: coil_open, target: left}}
assertions:
  - {{name: flagged, type: flag_within, signal: controller.fault_detected, at: {{event: coil_open}}, within: 60 ms}}
"""


def recorder(directory: Path, *, name: str, device, **layout) -> DeviceRecorder:
    return DeviceRecorder(directory, BagLayout.of(device, **layout), name=name, dt_ns=device.dt_ns,
                          namespace=layout.get("namespace", "/"), writing=W)


def metadata(bag: Path) -> dict:
    """metadata.yaml's topics (by name: type, QoS, count), duration, start and message count."""
    info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    topics = {t["topic_metadata"]["name"]: t for t in info.pop("topics_with_message_count")}
    info.pop("relative_file_paths")
    info.pop("files")
    return {**info, "topics": topics}


def assert_same_bag(new: Path, old: Path, distro: str = "kilted") -> None:
    """`distro`: the ROS distribution the new bag names (the references were written as kilted's)."""
    got, want = messages(new), messages(old)
    assert sorted(got) == sorted(want)
    for topic, w in want.items():
        g = got[topic]
        assert (g["type"], g["encoding"], g["metadata"]) == (w["type"], w["encoding"], w["metadata"]), topic
        assert len(g["messages"]) == len(w["messages"]), topic
        for k, (a, b) in enumerate(zip(g["messages"], w["messages"], strict=True)):
            assert a == b, f"{topic} message {k}: {a} != {b}"
    assert metadata(new) == {**metadata(old), "ros_distro": distro}


def replayed(bag: Path, capsys: pytest.CaptureFixture[str], *args: str) -> dict:
    """What `pcv-sim replay --json` says of a bag (its path and the wall time it took left out)."""
    capsys.readouterr()
    assert main(["replay", str(bag), "--model", "simplified", "--json", *args]) == 0
    out = json.loads(capsys.readouterr().out)
    return {k: v for k, v in out.items() if k not in ("bag", "elapsed_s", "real_time_factor")}


def emulator() -> ValveDevice:
    return ValveDevice(load_params(), safe_duty=0.0, watchdog_timeout=0.0, sample_every=10, seed=1)


def test_the_emulators_bags_are_as_before(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    dev = emulator()
    st = emulator_run(recorder, tmp_path, "emulator_all", dev, device=dev, every=1, namespace="/left",
                      frame_id="load_port", faults=True, events=False)
    assert st.dropped == 0 and st.error == "" and st.messages == 1812
    assert_same_bag(tmp_path / "emulator_all", DATA / "emulator_all")
    assert replayed(tmp_path / "emulator_all", capsys) == replayed(DATA / "emulator_all", capsys)
    dev = emulator()
    emulator_run(recorder, tmp_path, "emulator_every10", dev, device=dev, every=10, record=["duty", "pressure", "flow"],
                 frame_id="", faults=False, events=False)
    assert_same_bag(tmp_path / "emulator_every10", DATA / "emulator_every10")


def test_the_rigs_live_bag_is_as_before(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rig = Rig(load_rig(), seed=1)
    chambers = {v.name: v.chamber for v in rig.params.valves if v.chamber in ("a", "b")}
    st = rig_run(recorder, tmp_path, "rig", rig, device=rig, namespace="/bench", chambers=chambers)
    assert st.dropped == 0 and st.error == ""
    assert_same_bag(tmp_path / "rig", DATA / "rig")
    for valve in ("left", "right"):
        assert replayed(tmp_path / "rig", capsys, "--namespace", valve) == replayed(DATA / "rig", capsys,
                                                                                   "--namespace", valve)


def test_the_scenario_runners_bag_is_as_before(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "short.yaml").write_text(SCENARIO.format(rig=REPO / "config" / "rig.yaml"))
    monkeypatch.chdir(tmp_path)
    assert main(["scenario", "run", "short.yaml", "--bag", str(tmp_path / "scenario")]) == 0
    assert_same_bag(tmp_path / "scenario", DATA / "scenario", detect_ros_distro())     # it writes the running distro


def test_the_layout_follows_the_devices_names() -> None:
    """The emulator's roles alone under the namespace; the rig's valves each under their own, the
    chambers and the cylinder's JointState from the registry; a row is the device's signals."""
    dev = emulator()
    lay = BagLayout.of(dev, namespace="/left", every=10, faults=False, events=False)
    assert [(t.kind, t.topic) for t in lay.topics] == [
        ("input", "/left/duty_cycle"), ("input", "/left/load_flow"), ("input", "/left/supply_pressure"),
        ("column", "/left/pressure"), ("column", "/left/current"), ("column", "/left/spool_position")]
    assert lay.row == dev.signals and lay.prefix == "emulator"
    assert lay.of_kind("input")[0].source == "duty"      # the duty the model used (after the limiter)
    rig = Rig(load_rig())
    lay = BagLayout.of(rig, namespace="/b", chambers={"left": "a", "right": "b"})
    assert lay.topic("left.pressure", "column") == "/b/left/pressure"
    assert [t.topic for t in lay.topics if t.name == "left.pressure"] == ["/b/left/pressure", "/b/cylinder/pressure_a"]
    joint, = lay.of_kind("joint")
    assert joint.topic == "/b/cylinder/joint_states" and [lay.row[j] for j in joint.source] == [
        "cylinder.position", "cylinder.velocity", "cylinder.effort"]
    assert lay.topic("cylinder.external_force") == "/b/cylinder/external_force"
    assert lay.flows == ("left.load_flow", "right.load_flow") and lay.prefix == "rig"
    assert [t.topic for t in lay.of_kind("text")] == ["/b/faults", "/b/rig/events"]
    with pytest.raises(BagError, match=r"'nothing' is not in this bag; it has left.duty_cycle, "):
        lay.topic("nothing")
    with pytest.raises(BagError, match=r"every 0: accepted is an integer >= 1"):
        BagLayout.of(dev, every=0)


def test_the_lone_valve_is_the_devices_flag_not_a_guess_from_its_names() -> None:
    """The emulator's device says it is the lone valve (its names bare); the rig says it is not,
    and a device of one valve on a plant, or of two, cannot be one."""
    from pcv_sim.device.device import Device, ValveSpec

    dev = emulator()
    assert dev.lone_valve and dev.input_names[0] == "duty_cycle" and dev.signals[0] == "pressure"
    rig = Rig(load_rig())
    assert not rig.lone_valve
    # the same names offline: the flag decides the layout, not the absence of a dot
    lone = BagLayout.of_names(("valve",), dev.signals, dev.input_names, lone_valve=True)
    assert lone.topic("duty_cycle") == "/duty_cycle" and lone.prefix == "emulator"
    one = BagLayout.of_names(("left",), ("left.pressure",), ("left.duty_cycle",), lone_valve=False)
    assert one.topic("left.pressure", "column") == "/left/pressure" and one.prefix == "rig"

    class TwoLoneValves(Device):
        lone_valve = True

    params = load_params()
    with pytest.raises(ValueError, match=r"a lone valve is one valve and no plant; got 2 valves"):
        TwoLoneValves(params.simulation.time_step, [ValveSpec("a", params), ValveSpec("b", params)])
