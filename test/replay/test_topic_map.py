"""Topic mapping: rig bags use other names (--topic ROLE=/topic); namespaced emulator bags."""

from __future__ import annotations

import pytest

from pcv_sim.cli import main
from pcv_sim.io.bag import FLOAT64
from pcv_sim.replay import ReplayError, load_recording, parse_topic_map, replay

from .helpers import write_bag

RIG = {"duty": "/rig/cmd", "pressure": "/rig/p", "current": "/rig/i", "position": "/rig/x"}


def test_renamed_topics_replay_with_mapping(tmp_path, params, capsys):
    renamed = write_bag(tmp_path / "rig", RIG, types={"pressure": FLOAT64})  # rig: pressure as Float64, Pa
    device = write_bag(tmp_path / "dev", {"duty": "/duty_cycle", "pressure": "/pressure",
                                          "current": "/current", "position": "/spool_position"})
    mapping = parse_topic_map(["duty=/rig/cmd", "pressure=/rig/p", "current=/rig/i", "position=rig/x"])
    assert mapping == {"duty_cycle": "/rig/cmd", "pressure": "/rig/p", "current": "/rig/i",
                       "spool_position": "/rig/x"}
    a = replay(load_recording(renamed, mapping), params, model="simplified")
    b = replay(load_recording(device), params, model="simplified")
    assert a.scalar_metrics() == b.scalar_metrics()
    assert a.scalar_metrics()["pressure_fit_percent"] > 99.99
    assert main(["replay", str(renamed), "--model", "simplified", "--topic", "duty=/rig/cmd",
                 "--topic", "pressure=/rig/p", "--topic", "current=/rig/i", "--topic", "position=/rig/x",
                 "--fail-above", "pressure_rmse_bar=0.05"]) == 0
    assert "pressure" in capsys.readouterr().out


def test_renamed_topics_without_mapping_say_what_exists(tmp_path, capsys):
    renamed = write_bag(tmp_path / "rig", RIG, until_s=0.3)
    with pytest.raises(ReplayError, match=r"no duty command .*topics in the bag: /rig/cmd \(std_msgs/msg/Float64\).*"
                                          r"--topic duty_cycle="):
        load_recording(renamed)
    assert main(["replay", str(renamed)]) == 2
    assert "--topic duty_cycle=" in capsys.readouterr().err
    with pytest.raises(ReplayError, match=r"nothing to compare.*--topic pressure=/rig/p"):
        load_recording(renamed, {"duty_cycle": "/rig/cmd"})
    with pytest.raises(ReplayError, match=r"--topic pressure=/rig/pressure: topic '/rig/pressure' is not in the bag; "
                                          r"topics in the bag: .*/rig/p \("):
        load_recording(renamed, parse_topic_map(["duty=/rig/cmd", "pressure=/rig/pressure"]))


def test_namespaced_emulator_topics_are_found(tmp_path, params):
    bag = write_bag(tmp_path / "left", {"duty": "/left/duty_cycle", "pressure": "/left/pressure"}, until_s=0.5)
    rec = load_recording(bag)
    assert rec.topics == {"duty_cycle": "/left/duty_cycle", "pressure": "/left/pressure"}
    assert any("using /left/pressure" in n for n in rec.notes)
    assert any("current: no topic /current" in n and "not compared" in n for n in rec.notes)
    r = replay(rec, params, model="simplified")
    assert set(r.signals) == {"pressure"}


def test_two_namespaces_are_ambiguous(tmp_path):
    bag = write_bag(tmp_path / "two", {"duty": "/left/duty_cycle", "pressure": "/left/pressure",
                                       "current": "/right/pressure"}, until_s=0.2,
                    types={"current": "sensor_msgs/msg/FluidPressure"})
    with pytest.raises(ReplayError, match=r"several topics could be the pressure: \['/left/pressure', "
                                          r"'/right/pressure'\]; choose one with --topic pressure=/left/pressure, or a "
                                          r"device with --namespace NS \(the bag's device namespaces: /left\)"):
        load_recording(bag)


@pytest.mark.parametrize(("item", "match"), [
    ("pressure", r"expected ROLE=/topic"),
    ("flux=/x", r"unknown role 'flux'; roles: duty_cycle, load_flow"),
    ("pressure=", r"expected ROLE=/topic"),
])
def test_bad_topic_option(item, match):
    with pytest.raises(ReplayError, match=match):
        parse_topic_map([item])
