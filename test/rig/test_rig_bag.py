"""The rig's bag without ROS: a rig run recorded with `DeviceRecorder` on the rig's `BagLayout` the way the node feeds it
(`Rig.on_input` for the inputs, the samples every control period), read back with rosbags, and
one valve replayed from it by namespace (`pcv-sim replay --namespace`)."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from pcv_sim.cli import main
from pcv_sim.device.recording import BagLayout, DeviceRecorder
from pcv_sim.io.recorder import WriterSettings
from pcv_sim.params import load_params
from pcv_sim.replay import ReplayError, load_recording, replay

DT_NS = 100_000
NS = "/bench/rig"


def rig_recorder(rig, directory, *, name, namespace="/"):
    """The rig's recorder as its node makes it (`pcv_sim.node.kinds`), writing inline."""
    chambers = {v.name: v.chamber for v in rig.params.valves if v.chamber in ("a", "b")}
    return DeviceRecorder(directory, BagLayout.of(rig, namespace=namespace, chambers=chambers), name=name,
                          namespace=namespace, writing=WriterSettings(writer="inline"))


def duties(t):
    return {"left": 0.7 if 0.05 <= t < 0.15 else 0.4 if t >= 0.15 else 0.5, "right": 0.3 if t >= 0.1 else 0.5}


@pytest.fixture
def rig_bag(rig, tmp_path):
    """0.3 s of the rig, recorded at the 1 ms control period; returns (bag path, samples)."""
    rec = rig_recorder(rig, tmp_path, name="b", namespace=NS)
    rig.on_input = lambda step, name, value: rec.input(step * DT_NS, name, value)
    samples = []
    for k in range(301):
        rig.advance_to(k * 10)
        y = rig.sample()
        if k == 0:
            rec.start(0, rig.input_values())
        rec.sample(rig.steps * DT_NS, y, rig.load_volumes())
        samples.append(y)
        for v, d in duties(rig.time + 1e-9).items():
            rig.set_duty(v, d)
    st = rec.close()
    assert st.dropped == 0 and st.error == ""
    return tmp_path / "b", np.array(samples)


def chamber_params(rig):
    """The valve YAML with the load volume of chamber a at the piston's initial position (the
    replayed valve feeds that volume in the rig; replay holds the volume constant)."""
    c = rig.params.cylinder
    p = load_params()
    volume = c.dead_volume_a + c.hose_volume_a + c.area_a * (c.initial_position - c.stroke_min)
    return dataclasses.replace(p, circuit=dataclasses.replace(p.circuit, load_volume=volume))


def test_each_valve_is_recorded_under_its_namespace_and_replays_with_a_good_fit(rig, rig_bag, tmp_path, capsys):
    bag, y = rig_bag
    with AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        got = {t: [] for t in types}
        for conn, t, raw in reader.messages():
            got[conn.topic].append((t, reader.deserialize(raw, conn.msgtype)))
    for v in ("left", "right"):
        assert types[f"{NS}/{v}/pressure"] == "sensor_msgs/msg/FluidPressure"
        assert types[f"{NS}/{v}/duty_cycle"] == "std_msgs/msg/Float64"
    assert types[f"{NS}/cylinder/joint_states"] == "sensor_msgs/msg/JointState"
    p = got[f"{NS}/left/pressure"]
    assert [t for t, _ in p] == [k * 1_000_000 for k in range(301)]
    assert [m.fluid_pressure for _, m in p] == list(y[:, rig.signals.index("left.pressure")])
    assert [m.data for _, m in got[f"{NS}/left/duty_cycle"]] == [0.5, 0.7, 0.4]
    assert [t for t, _ in got[f"{NS}/left/duty_cycle"]] == [0, 50_000_000, 150_000_000]
    assert [m.position[0] for _, m in got[f"{NS}/cylinder/joint_states"]] == \
        list(y[:, rig.signals.index("cylinder.position")])

    params = chamber_params(rig)
    for v in ("left", "right"):
        rec = load_recording(bag, namespace=v)
        assert rec.topics["pressure"] == f"{NS}/{v}/pressure" and "load_flow" in rec.inputs
        fit = replay(rec, params, model="simplified").scalar_metrics()
        assert fit["pressure_fit_percent"] > 97, (v, fit)      # measured 99.0 (left), 99.1 (right)
    with pytest.raises(ReplayError, match=r"--namespace 'middle': no device .* the bag's device namespaces: "
                                          rf"{NS}/left, {NS}/right"):
        load_recording(bag, namespace="middle")
    with pytest.raises(ReplayError, match=r"choose one with --topic duty_cycle=.*--namespace NS"):
        load_recording(bag)
    config = tmp_path / "valve.yaml"
    config.write_text((Path(__file__).parents[2] / "config/valve.yaml").read_text()
                      .replace("load_volume: 1.0e-4", f"load_volume: {params.circuit.load_volume!r}"))
    assert main(["--config", str(config), "replay", str(bag), "--namespace", "rig/left", "--model", "simplified",
                 "--fail-below", "pressure_fit_percent=95"]) == 0
    assert main(["replay", str(bag), "--namespace", "right", "--model", "simplified", "--load-volume",
                 repr(params.circuit.load_volume), "--fail-below", "pressure_fit_percent=95"]) == 0
    assert main(["replay", str(bag), "--namespace", "left/x"]) == 2
    assert "the bag's device namespaces" in capsys.readouterr().err
    assert main(["replay", str(bag), "--namespace", "left", "--load-volume", "208"]) == 2
    assert "--load-volume 208: accepted is a volume in m^3" in capsys.readouterr().err


def test_dropped_measurements_have_no_message_and_joint_states_match_the_generic_serialization(rig, tmp_path):
    """As on the wire: a dropped (NaN) sample has no message, a JointState leaves a dropped field
    empty; the joint states written from the template are the generic serializer's bytes."""
    from pcv_sim.io.bag import cdr
    from pcv_sim.io.topics import JOINT_STATE

    rec = rig_recorder(rig, tmp_path, name="d")
    y = rig.sample()
    rec.start(0, rig.input_values())
    rec.sample(0, y, rig.load_volumes())
    y2 = y.copy()
    y2[rig.signals.index("left.pressure")] = np.nan
    y2[rig.signals.index("cylinder.velocity")] = np.nan
    rec.sample(1_000_000, y2, rig.load_volumes())
    data, _, _ = rec._joint_template()
    assert data == cdr.serialize("/j", JOINT_STATE, {
        "header": {"stamp": {"sec": 0x1A2B3C4D, "nanosec": 0x0E1F2A3B}, "frame_id": "cylinder"}, "name": ["steering"],
        "position": np.array([1.2345678901234567e-300]), "velocity": np.array([-2.3456789012345678e-301]),
        "effort": np.array([3.4567890123456789e-302])})
    rec.close()
    with AnyReader([tmp_path / "d"], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        got = {}
        for conn, t, raw in reader.messages():
            got.setdefault(conn.topic, []).append((t, reader.deserialize(raw, conn.msgtype)))
    assert [t for t, _ in got["/left/pressure"]] == [0] and [t for t, _ in got["/right/pressure"]] == [0, 1_000_000]
    (_, j0), (_, j1) = got["/cylinder/joint_states"]
    assert list(j0.velocity) == [y[rig.signals.index("cylinder.velocity")]] and list(j1.velocity) == []
    assert list(j1.position) == [y[rig.signals.index("cylinder.position")]] and j1.header.stamp.nanosec == 1_000_000


def test_the_valve_options_are_recorded_under_their_valve_and_read_back_by_the_mcap_reader(options_rig, tmp_path):
    """A valve's options in a rig bag as in the emulator's (io.topics.OPTION_INTERFACE): the
    temperatures it takes on change, stamped at the step they act from; the coil's temperature and
    resistance with every sample, at its stamp; read back with the mcap reader (CDR decoded here)."""
    import struct

    from mcap.reader import make_reader

    from pcv_sim.rig import Rig, load_rig
    from pcv_sim.units import kelvin

    rig = Rig(load_rig(options_rig))
    assert rig.option_inputs == ("probe.ambient_temperature", "probe.oil_temperature")
    assert rig.option_outputs == ("probe.coil_temperature", "probe.coil_resistance")
    rec = rig_recorder(rig, tmp_path, name="o", namespace=NS)
    rig.on_input = lambda step, name, value: rec.input(step * DT_NS, name, value)
    rig.set_duty("probe", 0.9)                  # the coil heats
    start = rig.input_values()
    sampled = []
    for k in range(101):
        rig.advance_to(k * 10)
        y = rig.sample()
        if k == 0:
            rec.start(0, rig.input_values())
        rec.sample(rig.steps * DT_NS, y, rig.load_volumes())
        sampled.append((rig.steps * DT_NS, *rig.option_sample))
        if k == 50:
            rig.set_temperature("probe", "oil_temperature", kelvin(50.0))
    st = rec.close()
    assert st.dropped == 0 and st.error == ""

    [mcap_file] = (tmp_path / "o").glob("*.mcap")
    got: dict[str, list[tuple[int, float]]] = {}
    types = {}
    with open(mcap_file, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            types[channel.topic] = schema.name
            if schema.name == "std_msgs/msg/Float64":
                got.setdefault(channel.topic, []).append((message.log_time, struct.unpack_from("<d", message.data, 4)[0]))
    for name in ("ambient_temperature", "oil_temperature", "coil_temperature", "coil_resistance"):
        assert types[f"{NS}/probe/{name}"] == "std_msgs/msg/Float64", name
        assert f"{NS}/left/{name}" not in types                       # the paper's valves have none
    assert got[f"{NS}/probe/coil_temperature"] == [(t, c) for t, c, _ in sampled]
    assert got[f"{NS}/probe/coil_resistance"] == [(t, r) for t, _, r in sampled]
    assert sampled[-1][1] > sampled[0][1]                              # K: the coil warmed at 90 % duty
    assert got[f"{NS}/probe/oil_temperature"] == [(0, start["probe.oil_temperature"]), (500 * DT_NS, kelvin(50.0))]
    assert got[f"{NS}/probe/ambient_temperature"] == [(0, start["probe.ambient_temperature"])]


def test_the_options_outputs_are_recorded_as_published_sensor_faults_included(options_rig, tmp_path):
    """Through the node's hooks (`attach`, `begin`, `shown` with the measured sample): a sensor fault
    on a valve option's output shows in the bag as it shows on the wire; read back with rosbags."""
    from pcv_sim.rig import Rig, load_rig

    rig = Rig(load_rig(options_rig))
    rec = rig_recorder(rig, tmp_path, name="m", namespace=NS)
    rec.attach(rig)
    rec.begin(rig)
    j = rig.signals.index("probe.coil_temperature")
    assert rig.submit_fault("{fault: bias, signal: probe.coil_temperature, value: 5.0}", 200) is None
    shown = []
    while rig.steps < 400:
        for sample in rig.run_to(rig.steps + rig.sample_every):
            measured = rig.measure(sample).tolist()
            rec.shown(rig, sample, measured)
            shown.append((rig.stamp_ns(sample.step), measured[j], sample.values[j]))
    assert rec.close().dropped == 0
    with AnyReader([tmp_path / "m"], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        got = [(t, reader.deserialize(raw, c.msgtype).data) for c, t, raw in reader.messages()
               if c.topic == f"{NS}/probe/coil_temperature"]
    assert got == [(t, m) for t, m, _ in shown]
    assert all(m - true == pytest.approx(5.0) for t, m, true in shown if t >= 200 * DT_NS)
    assert all(m == true for t, m, true in shown if t < 200 * DT_NS)
