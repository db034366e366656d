"""The emulator's configuration of the device's recorder (`pcv_sim.device.recording`) without ROS:
direct calls with scripted signals, and the real ValveDevice.

The recorder is called at every model step with the device's signals (pcv_sim.device.valve.SIGNALS);
inputs go into the bag on change, stamped with the step at which they took effect, outputs at every
`every`-th step. Bags are real files (tmp_path), read back with pcv_sim's reader.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np
import pytest

from pcv_sim.device.recording import RECORDABLE, DeviceRecorder, check_signals
from pcv_sim.device.valve import ValveDevice
from pcv_sim.errors import BagError
from pcv_sim.io import read_bag
from pcv_sim.io.recorder import Writer, WriterSettings, bag_name
from pcv_sim.params import load_params, replace_param
from pcv_sim.replay import load_recording, replay

T0 = 1_700_000_000_000_000_000
DT = 100_000                      # ns, the model step
PARAMS = load_params()


def signals(k: int, duty: float = 0.5, q: float = 0.0, ps: float = 200e5) -> dict[str, float]:
    """Made-up device signals at step k: outputs that encode k, so the grid can be checked."""
    return {"duty_command": duty, "duty": duty, "load_flow": q, "supply_pressure": ps,
            "pressure": 1e5 + k, "current": 1e-3 * k, "spool_position": 1e-9 * k}


def record(rec: DeviceRecorder, n: int, script: dict[int, dict[str, float]]) -> None:
    """start() at step 0, then a call per step; script[k] changes inputs from step k on (as the
    device does: the call for step k shows the inputs in force from step k on)."""
    inputs = {"duty": 0.5, "q": 0.0, "ps": 200e5}
    rec.start(T0, signals(0, **inputs))
    for k in range(1, n + 1):
        inputs.update(script.get(k, {}))
        rec(T0 + k * DT, signals(k, **inputs))


@pytest.mark.parametrize("writer", ["process", "thread", "inline"])
def test_inputs_on_change_stamped_where_they_took_effect_outputs_decimated(tmp_path: Path, writer: Writer, emulator_recorder) -> None:
    rec = emulator_recorder(tmp_path, name="b", every=10, frame_id="load_port", writing=WriterSettings(writer=writer))
    record(rec, 1000, {100: {"duty": 0.7}, 250: {"q": 1e-5}, 400: {"duty": 0.3, "ps": 150e5}, 401: {"duty": 0.3}})
    st = rec.close()
    assert (st.state, st.dropped, st.queued, st.error) == ("closed", 0, 0, "")
    bag = read_bag(tmp_path / "b")
    assert bag.closed_cleanly and not bag.warnings, bag.warnings
    assert bag.topic_types == {"/duty_cycle": "std_msgs/msg/Float64", "/load_flow": "std_msgs/msg/Float64",
                               "/supply_pressure": "sensor_msgs/msg/FluidPressure",
                               "/pressure": "sensor_msgs/msg/FluidPressure", "/current": "std_msgs/msg/Float64",
                               "/spool_position": "std_msgs/msg/Float64"}
    duty = bag["/duty_cycle"]
    assert duty.t_ns.tolist() == [T0, T0 + 100 * DT, T0 + 400 * DT]          # a repeat adds nothing
    assert duty.value.tolist() == [0.5, 0.7, 0.3]
    assert bag["/load_flow"].t_ns.tolist() == [T0, T0 + 250 * DT]
    assert bag["/load_flow"].value.tolist() == [0.0, 1e-5]
    sp = bag["/supply_pressure"]
    assert sp.value.tolist() == [200e5, 150e5] and sp.stamp_ns.tolist() == sp.t_ns.tolist()
    p = bag["/pressure"]
    steps = np.arange(0, 1001, 10)
    assert p.t_ns.tolist() == (T0 + steps * DT).tolist()                  # every 10th step, from the start
    assert p.value.tolist() == (1e5 + steps).tolist()
    assert p.stamp_ns.tolist() == p.t_ns.tolist()                         # header stamp = log time
    assert np.array_equal(bag["/current"].t_ns, p.t_ns) and len(bag["/spool_position"]) == len(steps)
    assert st.messages == 3 + 2 + 2 + 3 * len(steps) and st.bytes > 0 and st.files == 1


def test_full_rate_and_signal_subset(tmp_path: Path, emulator_recorder) -> None:
    rec = emulator_recorder(tmp_path, name="b", every=1, signals=["duty", "pressure"], namespace="/left")
    record(rec, 500, {50: {"duty": 0.9}})
    rec.close()
    bag = read_bag(tmp_path / "b")
    assert set(bag.topic_types) == {"/left/duty_cycle", "/left/pressure"}
    assert len(bag["/left/pressure"]) == 501
    assert np.all(np.diff(bag["/left/pressure"].t_ns) == DT)
    assert bag["/left/duty_cycle"].t_ns.tolist() == [T0, T0 + 50 * DT]


def test_output_grid_is_anchored_at_the_start_and_survives_gaps(tmp_path: Path, emulator_recorder) -> None:
    """Skipped steps (the node far behind wall time) or a fault leave a gap; the grid stays."""
    rec = emulator_recorder(tmp_path, name="b", every=10, signals=["pressure"])
    rec.start(T0 + 3 * DT, signals(3))
    for k in [*range(4, 30), *range(57, 80)]:
        rec(T0 + k * DT, signals(k))
    rec.close()
    t = (read_bag(tmp_path / "b")["/pressure"].t_ns - T0) // DT
    assert t.tolist() == [3, 13, 23, 63, 73]


def test_split_files(tmp_path: Path, emulator_recorder) -> None:
    rec = emulator_recorder(tmp_path, name="b", every=1, writing=WriterSettings(split_size_bytes=20_000, chunk_size=16_384))
    record(rec, 6000, {})
    st = rec.close()
    bag = read_bag(tmp_path / "b")
    assert st.files >= 3 and len(bag.files) == st.files, (st, bag.files)
    assert bag.closed_cleanly and not bag.warnings, bag.warnings
    assert len(bag["/pressure"]) == 6001 and np.all(np.diff(bag["/pressure"].t_ns) == DT)


def test_a_bag_name_is_any_directory_name(tmp_path: Path, emulator_recorder) -> None:
    """An offline run's bag takes the name it is given (`pcv-sim scenario --bag 'run 1'`); the nodes'
    record.name has its own, stricter check."""
    emulator_recorder(tmp_path, name="run 1 (left)", writing=WriterSettings(writer="inline")).close()
    assert read_bag(tmp_path / "run 1 (left)").closed_cleanly


def test_refuses_to_overwrite_an_existing_bag(tmp_path: Path, emulator_recorder) -> None:
    (tmp_path / "b").mkdir()
    with pytest.raises(BagError, match=r"exists already; the recorder never overwrites"):
        emulator_recorder(tmp_path, name="b")
    assert list((tmp_path / "b").iterdir()) == []
    emulator_recorder(tmp_path, name="c", writing=WriterSettings(writer="inline")).close()
    with pytest.raises(BagError, match="exists already"):
        emulator_recorder(tmp_path, name="c")
    assert read_bag(tmp_path / "c").closed_cleanly


def test_timestamped_default_name(tmp_path: Path, emulator_recorder) -> None:
    when = time.mktime((2026, 3, 4, 5, 6, 7, 0, 0, -1))
    assert bag_name("/", when) == "emulator_20260304-050607"
    assert bag_name("/steer/left", when) == "emulator_steer_left_20260304-050607"
    rec = emulator_recorder(tmp_path / "new" / "dir", namespace="/left")     # directory made if missing
    rec.close()
    assert rec.path.parent == tmp_path / "new" / "dir" and rec.path.name.startswith("emulator_left_2")


@pytest.mark.parametrize("kwargs, match", [
    ({"signals": ["pressure", "torque"]}, r"'torque' is not a device signal; accepted are duty_cycle"),
    ({"signals": []}, "no signal selected"),
    ({"every": 0}, "every 0: accepted is an integer >= 1"),
    ({"every": 2.5}, "every 2.5"),
    ({"dt_ns": 0}, "dt_ns 0"),
    ({"max_queue_s": math.inf}, "max_queue_s"),
    ({"name": "../x"}, "plain directory name"),
    ({"name": ".."}, "plain directory name"),
    ({"name": "a/b"}, "plain directory name, without '/'"),
    ({"name": ""}, "plain directory name"),
])
def test_refuses_bad_arguments(tmp_path: Path, kwargs: dict, match: str, emulator_recorder) -> None:
    with pytest.raises(BagError, match=match):
        emulator_recorder(tmp_path, **{"name": "b", **kwargs})
    assert not (tmp_path / "b").exists()


@pytest.mark.parametrize("kwargs, match", [
    ({"batch_period": 0.0}, r"batch_period 0.0 s: accepted is 0 < batch_period <= 0.1"),
    ({"batch_period": math.nan}, r"batch_period nan s"),
    ({"writer": "disk"}, r"writer 'disk': accepted are 'process', 'thread' and 'inline'"),
])
def test_writer_settings_are_checked_when_made(kwargs: dict, match: str) -> None:
    """Every recorder's writing in one object, refused with what is accepted before any bag exists."""
    with pytest.raises(BagError, match=match):
        WriterSettings(**kwargs)


def test_check_signals_orders_and_accepts_aliases() -> None:
    assert check_signals(["position", "duty", "pressure", "duty_cycle"]) == ("duty_cycle", "pressure", "spool_position")
    assert check_signals(RECORDABLE) == RECORDABLE


def test_queue_overflow_is_counted_not_silent(tmp_path: Path, emulator_recorder) -> None:
    rec = emulator_recorder(tmp_path, name="b", every=1, signals=["duty", "pressure", "current"],
                      writing=WriterSettings(batch_period=0.1))
    rec._max_items = 10
    rec.start(T0, signals(0))                              # 2 items: duty, outputs
    for k in range(1, 21):                                 # the writer thread sleeps 0.1 s first
        rec(T0 + k * DT, signals(k))
    st = rec.status()
    assert st.queued == 10 and st.dropped == 2 * 12        # 12 output samples x 2 topics refused
    st = rec.close()
    assert st.messages == 1 + 2 * 9 and st.dropped == 24
    assert len(read_bag(tmp_path / "b")["/pressure"]) == 9


@pytest.mark.parametrize("writer", ["thread", "inline"])
def test_write_failure_is_reported_and_later_messages_counted(tmp_path: Path, writer: Writer, emulator_recorder) -> None:
    rec = emulator_recorder(tmp_path, name="b", every=1, signals=["pressure"], writing=WriterSettings(writer=writer))
    record(rec, 10, {})
    rec.close()                                             # drain what came before
    rec._closed = False
    rec._writer.close = lambda: None                        # type: ignore[method-assign]
    rec._writer._closed = True
    rec(T0 + 11 * DT, signals(11))
    rec._drain()
    st = rec.status()
    assert st.state == "failed" and "is closed" in st.error and st.dropped == 1
    rec(T0 + 12 * DT, signals(12))
    assert rec.status().dropped == 2


# --- with the real device -------------------------------------------------------------------------


def test_device_recording_replays_exactly_with_a_fall_rate_limiter(tmp_path: Path, emulator_recorder) -> None:
    """The duty in the bag is what the model used (after the limiter), stamped with the step it acted
    on; replaying it (on the emulator's device) with the limiter off gives the recorded pressure.

    Tolerance 1e-3 Pa on ~50-120 bar: the same arithmetic in the same order, from the same rest state."""
    limited = replace_param(PARAMS, "command.duty_fall_rate_limit", 2.0)
    rec = emulator_recorder(tmp_path, name="b", every=10, frame_id="load_port")
    dev = ValveDevice(limited, safe_duty=0.5, watchdog_timeout=0.0, recorder=rec)
    rec.start(dev.stamp_ns(), dev.record_values())
    for at, duty in [(0.05, 0.8), (0.2, 0.55), (0.4, 0.7), (0.55, 0.3)]:
        assert dev.submit("duty_cycle", duty, at_step=round(at / dev.dt)) is None
    dev.run(8000)
    st = rec.close()
    assert st.dropped == 0
    bag = read_bag(tmp_path / "b")
    ramp = np.diff(bag["/duty_cycle"].value)
    assert len(bag["/duty_cycle"]) > 100 and np.all(np.abs(ramp[ramp < 0]) <= 2.0 * dev.dt + 1e-12)
    result = replay(load_recording(tmp_path / "b"), PARAMS, model="simplified", solver="stepper")
    assert result.signals["pressure"].fit.max_error < 1e-3, result.signals["pressure"].fit
    assert result.signals["pressure"].fit.nrmse_fit_percent > 99.999


def test_when_full_wait_blocks_instead_of_dropping(tmp_path: Path, emulator_recorder) -> None:
    rec = emulator_recorder(tmp_path, name="b", every=1, signals=["pressure"],
                      writing=WriterSettings(batch_period=0.005, when_full="wait"))
    rec._max_items = 50
    record(rec, 2000, {})
    st = rec.close()
    assert st.dropped == 0 and st.messages == 2001


def test_when_full_is_checked(tmp_path: Path, emulator_recorder) -> None:
    with pytest.raises(BagError, match="when_full 'block': accepted are 'drop' and 'wait'"):
        emulator_recorder(tmp_path, name="b", writing=WriterSettings(when_full="block"))  # type: ignore[arg-type]


def test_the_device_s_stretches_of_steps_record_what_single_steps_record(tmp_path: Path, emulator_recorder) -> None:
    """ValveDevice hands a recorder of every step its stretches between events as one block
    (`record_block`); a recorder without that method gets every step alone. Same bag, to the bit."""
    from mcap.reader import make_reader

    def run(rec, hook) -> None:
        dev = ValveDevice(PARAMS, safe_duty=0.5, watchdog_timeout=0.0, sample_every=10)
        dev.recorder, dev.record_every = hook, 1
        rec.start(dev.stamp_ns(), dev.record_values())
        for at, duty in [(0.013, 0.8), (0.0551, 0.3), (0.08, 0.6)]:
            dev.submit("duty_cycle", duty, at_step=round(at / dev.dt))
        for _ in range(120):
            dev.run(10)
        assert rec.close().dropped == 0

    blocks = emulator_recorder(tmp_path, name="blocks", every=2, frame_id="load_port")
    single = emulator_recorder(tmp_path, name="single", every=2, frame_id="load_port")
    run(blocks, blocks)
    def single_steps(t_ns: int, s: dict[str, float]) -> None:   # no record_block: one step at a time
        single(t_ns, s)

    run(single, single_steps)
    got = {}
    for name in ("blocks", "single"):
        with open(next((tmp_path / name).glob("*.mcap")), "rb") as f:
            got[name] = sorted((c.topic, m.log_time, bytes(m.data)) for _s, c, m in make_reader(f).iter_messages())
    assert len(got["blocks"]) > 3 * 600 and got["blocks"] == got["single"]


@pytest.mark.parametrize("faults", [True, False])
def test_fault_commands_are_recorded_at_the_step_they_acted_with_faults_on(tmp_path: Path, faults: bool, emulator_recorder) -> None:
    """As the rig's bag: `faults` (std_msgs/String) holds each command that acted, as given, at its
    step (`ValveDevice.on_fault_command`); one refused when due is not in it; without `faults` the
    bag has no such topic. Read back with the mcap reader (CDR decoded here)."""
    import struct

    from mcap.reader import make_reader

    rec = emulator_recorder(tmp_path, name="b", faults=faults, writing=WriterSettings(writer="inline"))
    dev = ValveDevice(PARAMS, safe_duty=0.5, watchdog_timeout=0.0, recorder=rec)
    dev.on_fault_command = lambda step, text: rec.fault_command(dev.stamp_ns(step), text)
    rec.start(dev.stamp_ns(), dev.record_values())
    assert dev.submit_fault("{fault: coil_open}", at_step=100) is None
    assert dev.submit_fault("{clear: bias, signal: pressure}", at_step=150) is None    # not active when due
    assert dev.submit_fault("{clear: coil_open}", at_step=200) is None
    dev.run(300)
    assert dev.counts.rejected["faults"] == 1
    st = rec.close()
    assert st.dropped == 0 and st.error == ""
    texts, topics = [], set()
    [mcap_file] = (tmp_path / "b").glob("*.mcap")
    with open(mcap_file, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            topics.add(channel.topic)
            if channel.topic == "/faults":
                assert schema.name == "std_msgs/msg/String"
                (n,) = struct.unpack_from("<I", message.data, 4)
                texts.append((message.log_time, message.data[8:8 + n - 1].decode()))
    if faults:
        assert texts == [(100 * dev.dt_ns, "{fault: coil_open}"), (200 * dev.dt_ns, "{clear: coil_open}")]
    else:
        assert "/faults" not in topics and "/pressure" in topics


def test_the_valve_options_outputs_go_with_the_outputs_at_every_step(tmp_path: Path) -> None:
    """A valve with the options of docs/model.md R33, R34 recorded at the full rate: the device hands
    its stretches of steps over as blocks (`record_block`) with every signal, the options' outputs
    among them, and each is recorded at every step like the pressure; the options' inputs on change."""
    import yaml

    from pcv_sim.device.recording import BagLayout

    valve = yaml.safe_load((Path(__file__).parents[2] / "config" / "valve.yaml").read_text())
    valve["solenoid"].update(coil_temperature="lumped", coil_thermal_resistance=1.0, coil_heat_capacity=1.0)
    valve["fluid"]["temperature"] = "input"
    (tmp_path / "valve.yaml").write_text(yaml.safe_dump(valve))
    dev = ValveDevice(load_params(tmp_path / "valve.yaml"), safe_duty=0.0, watchdog_timeout=0.0, sample_every=10)
    assert dev.option_outputs == ("coil_temperature", "coil_resistance")
    rec = DeviceRecorder(tmp_path, BagLayout.of(dev, every=1, faults=False, events=False), name="b",
                         writing=WriterSettings(writer="inline"))
    rec.attach(dev)
    rec.begin(dev)
    assert dev.submit("duty_cycle", 0.9, 50) is None
    while dev.steps < 300:
        dev.run_to(dev.steps + dev.sample_every)
    st = rec.close()
    assert st.dropped == 0 and st.error == ""
    bag = read_bag(tmp_path / "b")
    p = bag["/pressure"]
    assert len(p) == 301 and np.all(np.diff(p.t_ns) == dev.dt_ns)
    for name in ("coil_temperature", "coil_resistance"):
        assert np.array_equal(bag[f"/{name}"].t_ns, p.t_ns), name
        assert bag[f"/{name}"].value[-1] == dev.record_values()[name], name
    assert np.all(np.diff(bag["/coil_temperature"].value) >= 0)            # K: the coil warms at 90 % duty
    assert len(bag["/ambient_temperature"]) == 1 and len(bag["/oil_temperature"]) == 1
