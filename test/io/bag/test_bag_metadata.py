"""metadata.yaml and MCAP channel metadata: the ROS distribution and each topic's offered QoS,
read back by independent readers (rosbags, mcap) as rosbag2 would read them for playback."""

from __future__ import annotations

import importlib.metadata
from pathlib import Path

import pytest
import yaml
from mcap.reader import make_reader
from rosbags.interfaces import QosDurability, QosHistory, QosReliability
from rosbags.rosbag2 import Reader
from rosbags.rosbag2.storage_mcap import get_qos

from pcv_sim.errors import BagError
from pcv_sim.io import FLOAT64, FLUID_PRESSURE, BagWriter
from pcv_sim.io.bag import COMMAND_QOS, SENSOR_DATA_QOS, Qos, detect_ros_distro
from pcv_sim.io.recorder import WriterSettings

T0 = 1_700_000_000_000_000_000
TOPICS = {"/pressure": FLUID_PRESSURE, "/duty_cycle": FLOAT64, "/other": FLOAT64}


def _write(path: Path, **kw: object) -> Path:
    with BagWriter(path, topics=TOPICS, flush_thread=False, **kw) as w:  # type: ignore[arg-type]
        w.write_fluid_pressure("/pressure", T0, 1e7, 0.0)
        w.write_float64("/duty_cycle", T0, 0.5)
    return path


def test_distro_and_qos_read_back_by_rosbags(tmp_path: Path) -> None:
    bag = _write(tmp_path / "b", ros_distro="kilted",
                 qos={"/pressure": SENSOR_DATA_QOS, "/duty_cycle": [COMMAND_QOS]})
    with Reader(bag) as r:
        assert r.ros_distro == "kilted"
        qos = {c.topic: c.ext.offered_qos_profiles for c in r.connections}  # type: ignore[union-attr]
    (p,), (d,) = qos["/pressure"], qos["/duty_cycle"]
    assert (p.history, p.depth, p.reliability, p.durability) == (
        QosHistory.KEEP_LAST, 5, QosReliability.BEST_EFFORT, QosDurability.VOLATILE)
    assert (d.history, d.depth, d.reliability, d.durability) == (
        QosHistory.KEEP_LAST, 10, QosReliability.RELIABLE, QosDurability.VOLATILE)
    assert qos["/other"] == []
    info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert info["version"] == 9 and info["ros_distro"] == "kilted"


def test_qos_in_mcap_channel_metadata_is_rosbag2s_yaml_string(tmp_path: Path) -> None:
    bag = _write(tmp_path / "b", ros_distro="jazzy", qos={"/pressure": SENSOR_DATA_QOS})
    with open(bag / "b_0.mcap", "rb") as f:
        reader = make_reader(f)
        channels = {c.topic: c for c in reader.get_summary().channels.values()}
        rosbag2 = next(m for m in reader.iter_metadata() if m.name == "rosbag2")
    text = channels["/pressure"].metadata["offered_qos_profiles"]
    assert text.startswith("- history: keep_last\n  depth: 5\n  reliability: best_effort\n")
    assert yaml.safe_load(text) == [{
        "history": "keep_last", "depth": 5, "reliability": "best_effort", "durability": "volatile",
        "deadline": {"sec": 9223372036, "nsec": 854775807},
        "lifespan": {"sec": 9223372036, "nsec": 854775807},
        "liveliness": "automatic",
        "liveliness_lease_duration": {"sec": 9223372036, "nsec": 854775807},
        "avoid_ros_namespace_conventions": False,
    }]
    (q,) = get_qos(b"".join(_mcap_string(s) for s in ("offered_qos_profiles", text)))
    assert q.reliability == QosReliability.BEST_EFFORT and q.depth == 5
    assert channels["/other"].metadata["offered_qos_profiles"] == "[]"  # as rosbag2 dumps none
    inner = yaml.safe_load(rosbag2.metadata["serialized_metadata"])
    assert inner["ros_distro"] == "jazzy"


def _mcap_string(s: str) -> bytes:
    raw = s.encode()
    return len(raw).to_bytes(4, "little") + raw


def test_recorder_writes_the_emulators_qos_and_distro(tmp_path: Path, emulator_recorder) -> None:
    rec = emulator_recorder(tmp_path, name="r", writing=WriterSettings(writer="inline", ros_distro="kilted"))
    rec.close()
    with Reader(tmp_path / "r") as r:
        assert r.ros_distro == "kilted"
        rel = {c.topic: c.ext.offered_qos_profiles[0].reliability for c in r.connections}  # type: ignore[union-attr]
    best, reliable = QosReliability.BEST_EFFORT, QosReliability.RELIABLE
    assert rel == {"/pressure": best, "/current": best, "/spool_position": best,
                   "/duty_cycle": reliable, "/load_flow": reliable, "/supply_pressure": reliable}


def test_distro_detection(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("ROS_DISTRO", "rolling")
    assert detect_ros_distro() == "rolling"
    monkeypatch.delenv("ROS_DISTRO")
    versions = {"rclpy": "9.1.2"}

    def version(name: str) -> str:
        if name not in versions:
            raise importlib.metadata.PackageNotFoundError(name)
        return versions[name]

    monkeypatch.setattr(importlib.metadata, "version", version)
    assert detect_ros_distro() == "kilted"
    versions["rclpy"] = "7.1.4"
    assert detect_ros_distro() == "jazzy"
    versions["rclpy"] = "42.0.0"
    assert detect_ros_distro() == ""
    del versions["rclpy"]
    assert detect_ros_distro() == ""
    versions["ros-jazzy-rclpy"] = "7.1.6"          # the Jazzy wheels' distribution name
    assert detect_ros_distro() == "jazzy"


def test_bad_distro_and_qos_are_refused(tmp_path: Path) -> None:
    with pytest.raises(BagError, match="ros_distro 'Kilted 9': accepted is a lower-case"):
        BagWriter(tmp_path / "a", topics=TOPICS, ros_distro="Kilted 9")
    with pytest.raises(BagError, match=r"qos given for undeclared topic\(s\) \['/nope'\]"):
        BagWriter(tmp_path / "b", topics=TOPICS, qos={"/nope": COMMAND_QOS})
    with pytest.raises(BagError, match=r"qos for '/other': expected a pcv_sim\.io\.bag\.Qos"):
        BagWriter(tmp_path / "c", topics=TOPICS, qos={"/other": "reliable"})  # type: ignore[dict-item]
    with pytest.raises(BagError, match="QoS reliability 'sometimes': accepted are"):
        Qos("sometimes", 5)  # type: ignore[arg-type]
    with pytest.raises(BagError, match="QoS depth -1: accepted is an integer >= 0"):
        Qos("reliable", -1)
