"""Bag writer and reader: checked against two independent readers (rosbags, mcap).

Every file here is real (tmp_path); the SIGKILL test kills a real writer process.
"""

from __future__ import annotations

import io
import math
import os
import shutil
import signal
import struct
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
import zstandard
from mcap.exceptions import McapError
from mcap.reader import NonSeekingReader, make_reader
from mcap.records import Chunk
from mcap.stream_reader import StreamReader
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from pcv_sim.errors import BagError
from pcv_sim.io import FLOAT64, FLUID_PRESSURE, BagWriter, read_bag

REPO = Path(__file__).resolve().parents[3]
TS = get_typestore(Stores.ROS2_JAZZY)
DIAG = "diagnostic_msgs/msg/DiagnosticArray"
T0 = 1_700_000_000_000_000_000  # a realistic epoch time in ns
MAGIC = b"\x89MCAP0\r\n"

Float64 = TS.types[FLOAT64]
FluidPressure = TS.types[FLUID_PRESSURE]
Header = TS.types["std_msgs/msg/Header"]
Time = TS.types["builtin_interfaces/msg/Time"]


def fluid(t_ns: int, p: float, var: float, frame_id: str = "") -> Any:
    sec, nanosec = divmod(t_ns, 1_000_000_000)
    return FluidPressure(
        header=Header(stamp=Time(sec=sec, nanosec=nanosec), frame_id=frame_id),
        fluid_pressure=p,
        variance=var,
    )


def diag_dict(t_ns: int) -> dict[str, Any]:
    sec, nanosec = divmod(t_ns, 1_000_000_000)
    return {
        "header": {"stamp": {"sec": sec, "nanosec": nanosec}, "frame_id": "pcv"},
        "status": [
            {"level": 1, "name": "valve", "message": "warm", "hardware_id": "sim",
             "values": [{"key": "coil_temperature_K", "value": "341.2"}]},
        ],
    }


def write_sample(path: Path, n: int = 300, **kwargs: Any) -> Path:
    """A bag with Float64, FluidPressure and one diagnostics message."""
    topics = {"/pcv/command": FLOAT64, "/pcv/pressure": FLUID_PRESSURE, "/diagnostics": DIAG}
    with BagWriter(path, topics=topics, **kwargs) as w:
        for i in range(n):
            t = T0 + i * 1_000_000
            w.write_float64("/pcv/command", t, 0.01 * i)
            w.write_fluid_pressure("/pcv/pressure", t, 1e5 + 10.0 * i, 25.0, frame_id="pcv_p_a")
        w.write("/diagnostics", T0 + n * 1_000_000, diag_dict(T0 + n * 1_000_000))
    return path


def mcap_messages(data: bytes) -> tuple[list[tuple[str, str, int, bytes]], Exception | None]:
    """(topic, schema name, log time, payload) via mcap's NonSeekingReader on a pipe-like stream.

    Reading stops at the first error (an unclosed file has no footer); the error is returned.
    """

    class Pipe(io.RawIOBase):
        def __init__(self) -> None:
            self._b = io.BytesIO(data)

        def readable(self) -> bool:
            return True

        def seekable(self) -> bool:
            return False

        def readinto(self, buf: Any) -> int:
            chunk = self._b.read(len(buf))
            buf[: len(chunk)] = chunk
            return len(chunk)

    stream = io.BufferedReader(Pipe())
    reader = make_reader(stream)
    assert isinstance(reader, NonSeekingReader)
    out: list[tuple[str, str, int, bytes]] = []
    try:
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            assert schema is not None
            out.append((channel.topic, schema.name, message.log_time, message.data))
    except (McapError, struct.error, zstandard.ZstdError, ValueError) as exc:
        return out, exc
    return out, None


# --- round trip ---------------------------------------------------------------------------


def test_round_trip_with_rosbags_anyreader(tmp_path: Path) -> None:
    bag = write_sample(tmp_path / "bag", n=300)
    with AnyReader([bag], default_typestore=TS) as reader:
        conns = {c.topic: c for c in reader.connections}
        assert {t: (c.msgtype, c.msgcount) for t, c in conns.items()} == {
            "/pcv/command": (FLOAT64, 300),
            "/pcv/pressure": (FLUID_PRESSURE, 300),
            "/diagnostics": (DIAG, 1),
        }
        assert reader.message_count == 601
        assert reader.start_time == T0
        assert reader.duration == 300 * 1_000_000 + 1  # rosbags reports end - start + 1
        got: dict[str, list[tuple[int, Any]]] = {t: [] for t in conns}
        for conn, t, raw in reader.messages():
            got[conn.topic].append((t, reader.deserialize(raw, conn.msgtype)))
    for i, (t, msg) in enumerate(got["/pcv/command"]):
        assert t == T0 + i * 1_000_000
        assert msg.data == 0.01 * i
    for i, (t, msg) in enumerate(got["/pcv/pressure"]):
        assert t == T0 + i * 1_000_000
        assert msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec == t
        assert msg.header.frame_id == "pcv_p_a"
        assert (msg.fluid_pressure, msg.variance) == (1e5 + 10.0 * i, 25.0)
    [(_, diag)] = got["/diagnostics"]
    assert diag.status[0].values[0].key == "coil_temperature_K"

    meta = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert meta["version"] == 9
    assert meta["storage_identifier"] == "mcap"
    assert meta["relative_file_paths"] == ["bag_0.mcap"]
    assert meta["message_count"] == 601
    counts = {e["topic_metadata"]["name"]: e["message_count"]
              for e in meta["topics_with_message_count"]}
    assert counts == {"/pcv/command": 300, "/pcv/pressure": 300, "/diagnostics": 1}
    hashes = {e["topic_metadata"]["type"]: e["topic_metadata"]["type_description_hash"]
              for e in meta["topics_with_message_count"]}
    assert hashes[FLOAT64] == TS.hash_rihs01(FLOAT64)
    assert meta["files"] == [{
        "path": "bag_0.mcap",
        "starting_time": {"nanoseconds_since_epoch": T0},
        "duration": {"nanoseconds": 300 * 1_000_000},
        "message_count": 601,
    }]


def test_round_trip_with_mcap_reader(tmp_path: Path) -> None:
    bag = write_sample(tmp_path / "bag", n=200)
    with open(bag / "bag_0.mcap", "rb") as f:
        reader = make_reader(f)
        header = reader.get_header()
        assert (header.profile, header.library) == ("ros2", "pcv_sim")
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        assert summary.statistics.message_count == 401
        for schema in summary.schemas.values():
            assert schema.encoding == "ros2msg"
            msgdef, _ = TS.generate_msgdef(schema.name, ros_version=2)
            assert schema.data.decode() == msgdef  # full concatenated definition
        by_topic = {c.topic: c for c in summary.channels.values()}
        assert {c.message_encoding for c in by_topic.values()} == {"cdr"}
        assert "offered_qos_profiles" in by_topic["/pcv/pressure"].metadata
        counts = summary.statistics.channel_message_counts
        assert counts[by_topic["/pcv/command"].id] == 200
        values = [
            (channel.topic, message.log_time, TS.deserialize_cdr(message.data, schema.name))
            for schema, channel, message in reader.iter_messages(log_time_order=False)
        ]
    commands = [(t, m.data) for topic, t, m in values if topic == "/pcv/command"]
    assert commands == [(T0 + i * 1_000_000, 0.01 * i) for i in range(200)]
    pressures = [m.fluid_pressure for topic, _, m in values if topic == "/pcv/pressure"]
    assert pressures == [1e5 + 10.0 * i for i in range(200)]


def test_read_bag_round_trip(tmp_path: Path) -> None:
    bag = write_sample(tmp_path / "bag", n=250)
    for path in (bag, bag / "bag_0.mcap"):
        contents = read_bag(path)
        assert contents.closed_cleanly
        assert set(contents.topics) == {"/pcv/command", "/pcv/pressure"}
        assert contents.topic_types["/diagnostics"] == DIAG
        assert any("not decoded" in w and "/diagnostics" in w for w in contents.warnings)
        t = T0 + np.arange(250, dtype=np.int64) * 1_000_000
        cmd = contents["/pcv/command"]
        np.testing.assert_array_equal(cmd.t_ns, t)
        np.testing.assert_array_equal(cmd.value, 0.01 * np.arange(250))
        assert cmd.stamp_ns is None
        p = contents["/pcv/pressure"]
        assert p.msgtype == FLUID_PRESSURE and len(p) == 250
        np.testing.assert_array_equal(p.t_ns, t)
        np.testing.assert_array_equal(p.stamp_ns, t)
        np.testing.assert_array_equal(p.value, 1e5 + 10.0 * np.arange(250))
        np.testing.assert_array_equal(p.fields["variance"], np.full(250, 25.0))
    only = read_bag(bag, topics=["/pcv/pressure"])
    assert list(only.topics) == ["/pcv/pressure"] and not only.warnings


def test_chunks_are_zstd_compressed(tmp_path: Path) -> None:
    bag = write_sample(tmp_path / "zstd", n=2000, chunk_size=8192)
    none = write_sample(tmp_path / "none", n=2000, chunk_size=8192, compression="none")
    for path, expected in ((bag / "zstd_0.mcap", "zstd"), (none / "none_0.mcap", "")):
        with open(path, "rb") as f:
            chunks = [r for r in StreamReader(f, emit_chunks=True).records
                      if isinstance(r, Chunk)]
        assert len(chunks) >= 5
        assert {c.compression for c in chunks} == {expected}
    assert (bag / "zstd_0.mcap").stat().st_size < 0.5 * (none / "none_0.mcap").stat().st_size


@pytest.mark.parametrize("frame_id", ["", "a", "ab", "abc", "abcd", "pcv_p_a", "12345678", "ü"])
def test_fast_cdr_bytes_equal_rosbags_serializer(tmp_path: Path, frame_id: str) -> None:
    values = [0.0, -0.0, 1.5, -2.25e5, 1e300, math.inf, -math.inf, math.nan, 5e-324]
    times = [0, 1, 999_999_999, 1_000_000_000, T0, T0 + 123_456_789, (2**31 - 1) * 10**9]
    topics = {"/f": FLOAT64, "/p": FLUID_PRESSURE}
    with BagWriter(tmp_path / "bag", topics=topics) as w:
        for t in times:
            for v in values:
                w.write_float64("/f", t, v)
                w.write_fluid_pressure("/p", t, v, -v, frame_id=frame_id)
    with open(tmp_path / "bag" / "bag_0.mcap", "rb") as f:
        records = [(c.topic, m.log_time, m.data)
                   for _, c, m in make_reader(f).iter_messages(log_time_order=False)]
    expected = []
    for t in times:
        for v in values:
            expected.append(("/f", t, bytes(TS.serialize_cdr(Float64(data=v), FLOAT64))))
            msg = fluid(t, v, -v, frame_id)
            expected.append(("/p", t, bytes(TS.serialize_cdr(msg, FLUID_PRESSURE))))
    assert records == expected


def test_generic_write_accepts_objects_and_dicts(tmp_path: Path) -> None:
    topics = {"/p": FLUID_PRESSURE, "/d": DIAG}
    with BagWriter(tmp_path / "bag", topics=topics) as w:
        w.write("/p", T0, fluid(T0, 2e5, 1.0, "x"))
        w.write("/p", T0 + 1, {"header": {"stamp": {"sec": 1, "nanosec": 2}, "frame_id": "x"},
                               "fluid_pressure": 2e5, "variance": 1.0})
        w.write("/d", T0, diag_dict(T0))
        w.write("/d", T0, TS.deserialize_cdr(TS.serialize_cdr(
            TS.types[DIAG](header=Header(stamp=Time(sec=0, nanosec=0), frame_id=""), status=[]),
            DIAG), DIAG))
        with pytest.raises(BagError, match=r"'/p' is declared as 'sensor_msgs/msg/Fluid"):
            w.write("/p", T0, Float64(data=1.0))
        with pytest.raises(BagError, match=r"has no field\(s\) \['pressure'\]"):
            w.write("/p", T0, {"pressure": 1.0})
        with pytest.raises(BagError, match=r"needs field\(s\) \['variance'\]"):
            w.write("/p", T0, {"header": {"stamp": {"sec": 1, "nanosec": 2}, "frame_id": ""},
                               "fluid_pressure": 1.0})
    contents = read_bag(tmp_path / "bag", topics=["/p"])
    np.testing.assert_array_equal(contents["/p"].stamp_ns, [T0, 1_000_000_002])


def test_raw_order_is_kept(tmp_path: Path) -> None:
    """Non-monotonic log times come back in write order; the consumer judges them."""
    ts = [T0 + 3, T0 + 1, T0 + 2, T0 + 2, T0]
    with BagWriter(tmp_path / "bag", topics={"/f": FLOAT64}) as w:
        for i, t in enumerate(ts):
            w.write_float64("/f", t, float(i))
    contents = read_bag(tmp_path / "bag")
    np.testing.assert_array_equal(contents["/f"].t_ns, ts)
    np.testing.assert_array_equal(contents["/f"].value, [0.0, 1.0, 2.0, 3.0, 4.0])
    assert contents.closed_cleanly and not contents.warnings


# --- bags from other writers ---------------------------------------------------------------


@pytest.mark.parametrize("version", [8, 9])
def test_reads_bags_written_by_rosbags(tmp_path: Path, version: int) -> None:
    bag = tmp_path / "rb"
    with Writer(bag, version=version, storage_plugin=StoragePlugin.MCAP) as w:
        cf = w.add_connection("/f", FLOAT64, typestore=TS)
        cp = w.add_connection("/p", FLUID_PRESSURE, typestore=TS)
        for i in range(100):
            t = T0 + i * 1000
            w.write(cf, t, TS.serialize_cdr(Float64(data=float(i)), FLOAT64))
            # Big-endian CDR on purpose: the reader must honour the encapsulation header.
            w.write(cp, t, TS.serialize_cdr(fluid(t, 3e5 + i, 0.5, "frame"), FLUID_PRESSURE,
                                            little_endian=False))
    for path in (bag, bag / "rb.mcap"):
        contents = read_bag(path)
        assert contents.closed_cleanly and not contents.warnings
        np.testing.assert_array_equal(contents["/f"].value, np.arange(100.0))
        np.testing.assert_array_equal(contents["/p"].value, 3e5 + np.arange(100.0))
        np.testing.assert_array_equal(contents["/p"].stamp_ns, T0 + np.arange(100) * 1000)


def test_sqlite3_bag_is_refused_clearly(tmp_path: Path) -> None:
    bag = tmp_path / "sq"
    with Writer(bag, version=9, storage_plugin=StoragePlugin.SQLITE3) as w:
        conn = w.add_connection("/f", FLOAT64, typestore=TS)
        w.write(conn, T0, TS.serialize_cdr(Float64(data=1.0), FLOAT64))
    with pytest.raises(BagError, match=r"uses storage 'sqlite3'; only 'mcap' bags can be read"):
        read_bag(bag)


# --- split files ----------------------------------------------------------------------------


def test_split_files(tmp_path: Path) -> None:
    n = 3000
    split = 4096
    with BagWriter(tmp_path / "bag", topics={"/f": FLOAT64}, chunk_size=1024,
                   split_size_bytes=split) as w:
        for i in range(n):
            w.write_float64("/f", T0 + i, float(i))
        files = w.files
    assert len(files) >= 3
    meta = yaml.safe_load((tmp_path / "bag" / "metadata.yaml").read_text())
    info = meta["rosbag2_bagfile_information"]
    assert info["relative_file_paths"] == [f"bag_{i}.mcap" for i in range(len(files))]
    assert [p.name for p in files] == info["relative_file_paths"]
    assert sum(f["message_count"] for f in info["files"]) == info["message_count"] == n
    start = T0
    for path, entry in zip(files, info["files"], strict=True):
        data = path.read_bytes()
        assert data.endswith(MAGIC)
        if path != files[-1]:
            assert len(data) >= split
        with open(path, "rb") as f:
            summary = make_reader(f).get_summary()
        assert summary is not None and summary.statistics is not None
        assert summary.statistics.message_count == entry["message_count"]
        assert entry["starting_time"]["nanoseconds_since_epoch"] == start
        start += entry["message_count"]
    with AnyReader([tmp_path / "bag"], default_typestore=TS) as reader:
        values = [reader.deserialize(raw, c.msgtype).data for c, _, raw in reader.messages()]
    assert values == [float(i) for i in range(n)]
    contents = read_bag(tmp_path / "bag")
    assert contents.closed_cleanly and not contents.warnings
    assert contents.files == tuple(files)
    np.testing.assert_array_equal(contents["/f"].value, np.arange(n, dtype=float))


# --- flushing and unclosed bags -----------------------------------------------------------


class FakeClock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def test_flush_period_bounds_what_an_unclosed_bag_loses(tmp_path: Path) -> None:
    """Copy the files of an open writer (what a SIGKILL leaves): at most one period is lost."""
    clock = FakeClock()
    period = 0.1
    dt = 0.001
    bag = tmp_path / "bag"
    w = BagWriter(bag, topics={"/f": FLOAT64, "/p": FLUID_PRESSURE}, flush_period_s=period,
                  flush_thread=False, clock=clock)
    n = 1234
    for i in range(n):
        clock.now = i * dt
        w.write_float64("/f", T0 + i * 1_000_000, float(i))
        w.write_fluid_pressure("/p", T0 + i * 1_000_000, float(i), 0.0)
    killed = tmp_path / "killed"
    shutil.copytree(bag, killed)
    w.close()

    contents = read_bag(killed)
    assert not contents.closed_cleanly
    assert any(m.startswith("bag_0.mcap: not closed properly") for m in contents.warnings)
    got = contents["/f"].value
    np.testing.assert_array_equal(got, np.arange(len(got)))  # a prefix, no gaps
    lost = n - len(got)
    assert 0 < lost <= period / dt  # everything older than one flush period survived
    assert abs(len(contents["/p"]) - len(got)) <= 1

    stream_msgs, error = mcap_messages((killed / "bag_0.mcap").read_bytes())
    assert error is not None  # no footer: the stream just ends
    f_values = [TS.deserialize_cdr(d, s).data for topic, s, _, d in stream_msgs if topic == "/f"]
    assert f_values == list(got)

    final = read_bag(bag)
    assert final.closed_cleanly and len(final["/f"]) == n


def test_background_thread_flushes_an_idle_writer(tmp_path: Path) -> None:
    bag = tmp_path / "bag"
    with BagWriter(bag, topics={"/f": FLOAT64}, flush_period_s=0.05) as w:
        for i in range(5):
            w.write_float64("/f", T0 + i, float(i))
        deadline = time.monotonic() + 2.0
        while time.monotonic() < deadline:
            snapshot = tmp_path / f"snap{time.monotonic_ns()}"
            shutil.copytree(bag, snapshot)
            if len(read_bag(snapshot)["/f"]) == 5:
                break
            time.sleep(0.02)
        else:
            pytest.fail("the flush thread did not write the idle writer's messages within 2 s")


CHILD = """
import sys, time
from pcv_sim.io import BagWriter, FLOAT64, FLUID_PRESSURE
w = BagWriter(sys.argv[1], topics={"/f": FLOAT64, "/p": FLUID_PRESSURE},
              flush_period_s=float(sys.argv[2]))
i = 0
start = time.monotonic()
told = False
while True:
    t = time.monotonic_ns()
    w.write_float64("/f", t, float(i))
    w.write_fluid_pressure("/p", t, 1e5 + i, 1.0, "pcv")
    i += 1
    if not told and time.monotonic() - start > 0.2:
        print("writing", flush=True)
        told = True
    time.sleep(0.001)
"""


def test_sigkill_loses_at_most_the_last_second(tmp_path: Path) -> None:
    """A real writer process at ~1 kHz, killed with SIGKILL after more than 1 s of flushes."""
    period = 0.5
    bag = tmp_path / "bag"
    env = {k: v for k, v in os.environ.items() if k != "_ROS_WHEELS_BOOTSTRAP_COMPLETE"}
    env["PYTHONPATH"] = os.pathsep.join([str(REPO), env.get("PYTHONPATH", "")])
    proc = subprocess.Popen([sys.executable, "-c", CHILD, str(bag), str(period)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env, text=True)
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        assert line.strip() == "writing", proc.stderr.read() if proc.stderr else ""
        time.sleep(1.5)
        killed_at = time.monotonic_ns()  # CLOCK_MONOTONIC is shared by all processes
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait(timeout=10)
        for stream in (proc.stdout, proc.stderr):
            if stream is not None:
                stream.close()
    assert proc.returncode == -signal.SIGKILL

    contents = read_bag(bag)
    assert not contents.closed_cleanly
    assert any("bag_0.mcap: not closed properly" in m for m in contents.warnings)
    f = contents["/f"]
    np.testing.assert_array_equal(f.value, np.arange(len(f)))  # a gapless prefix
    assert (f.t_ns[-1] - f.t_ns[0]) / 1e9 > 1.0  # more than a second was recovered
    lost_s = (killed_at - f.t_ns[-1]) / 1e9
    assert 0 < lost_s <= 1.0, f"lost the last {lost_s:.3f} s"
    assert abs(len(contents["/p"]) - len(f)) <= 1

    stream_msgs, _ = mcap_messages((bag / "bag_0.mcap").read_bytes())
    f_values = [TS.deserialize_cdr(d, s).data for topic, s, _, d in stream_msgs if topic == "/f"]
    assert f_values == list(f.value)
    meta = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert meta["relative_file_paths"] == ["bag_0.mcap"]  # the provisional metadata is there


# --- reader errors ---------------------------------------------------------------------------


def test_nonexistent_path(tmp_path: Path) -> None:
    with pytest.raises(BagError, match=r"does not exist; expected a rosbag2 directory"):
        read_bag(tmp_path / "nope")


def test_text_file_is_not_a_bag(tmp_path: Path) -> None:
    path = tmp_path / "notes.txt"
    path.write_text("hello, this is not a bag\n")
    with pytest.raises(BagError, match=r"is not an MCAP file .*or a single \.mcap file"):
        read_bag(path)


def test_empty_directory_and_empty_file(tmp_path: Path) -> None:
    with pytest.raises(BagError, match=r"is not a bag: it contains no readable \.mcap file "
                                       r"and no metadata\.yaml"):
        read_bag(tmp_path)
    (tmp_path / "x.mcap").write_bytes(b"")
    with pytest.raises(BagError, match=r"is empty \(0 bytes\)"):
        read_bag(tmp_path / "x.mcap")


def test_bad_metadata_yaml(tmp_path: Path) -> None:
    (tmp_path / "metadata.yaml").write_text("a: [unclosed\n")
    with pytest.raises(BagError, match=r"is not valid YAML"):
        read_bag(tmp_path)
    (tmp_path / "metadata.yaml").write_text("something: else\n")
    with pytest.raises(BagError, match=r"no 'rosbag2_bagfile_information' mapping"):
        read_bag(tmp_path)


def test_foreign_message_type(tmp_path: Path) -> None:
    bag = tmp_path / "bag"
    with BagWriter(bag, topics={"/diagnostics": DIAG, "/f": FLOAT64}) as w:
        w.write("/diagnostics", T0, diag_dict(T0))
        w.write_float64("/f", T0, 1.0)
    with pytest.raises(BagError, match=r"cannot decode /diagnostics is "
                                       r"'diagnostic_msgs/msg/DiagnosticArray'; decodable types: "
                                       r"std_msgs/msg/Float64, sensor_msgs/msg/FluidPressure"):
        read_bag(bag, topics=["/diagnostics", "/f"])
    only_diag = tmp_path / "diag"
    with BagWriter(only_diag, topics={"/diagnostics": DIAG}) as w:
        w.write("/diagnostics", T0, diag_dict(T0))
    with pytest.raises(BagError, match=r"no topic of .* can be decoded: /diagnostics is"):
        read_bag(only_diag)


def test_missing_topic_names_the_existing_ones(tmp_path: Path) -> None:
    bag = write_sample(tmp_path / "bag", n=3)
    with pytest.raises(BagError, match=r"topic\(s\) \['/pcv/valve'\] not in bag .*topics in the "
                                       r"bag: /diagnostics \(diagnostic_msgs/msg/Diagnostic"
                                       r"Array\), /pcv/command \(std_msgs/msg/Float64\)"):
        read_bag(bag, topics=["/pcv/command", "/pcv/valve"])


def test_metadata_disagreeing_with_the_files_is_reported(tmp_path: Path) -> None:
    bag = write_sample(tmp_path / "bag", n=20)
    meta_path = bag / "metadata.yaml"
    meta = yaml.safe_load(meta_path.read_text())
    meta["rosbag2_bagfile_information"]["topics_with_message_count"][0]["message_count"] = 25
    meta_path.write_text(yaml.safe_dump(meta))
    contents = read_bag(bag)
    assert "/pcv/command: metadata.yaml says 25 messages, the files hold 20" in contents.warnings
    meta_path.unlink()
    contents = read_bag(bag)
    assert not contents.closed_cleanly and len(contents["/pcv/command"]) == 20
    assert any(w.startswith("no metadata.yaml") for w in contents.warnings)


def test_declared_topic_without_messages_is_empty(tmp_path: Path) -> None:
    with BagWriter(tmp_path / "bag", topics={"/f": FLOAT64, "/p": FLUID_PRESSURE}) as w:
        w.write_float64("/f", T0, 1.0)
    contents = read_bag(tmp_path / "bag", topics="/p")
    assert len(contents["/p"]) == 0 and contents["/p"].stamp_ns is not None


def chunked_bag(tmp_path: Path, n: int = 4000) -> Path:
    with BagWriter(tmp_path / "bag", topics={"/f": FLOAT64}, chunk_size=2048) as w:
        for i in range(n):
            w.write_float64("/f", T0 + i, float(i))
    return tmp_path / "bag" / "bag_0.mcap"


def test_file_cut_in_the_data_section_gives_back_its_complete_chunks(tmp_path: Path) -> None:
    path = chunked_bag(tmp_path)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    for target in (path, path.parent):
        contents = read_bag(target)
        assert not contents.closed_cleanly
        got = contents["/f"].value
        assert 1000 < len(got) < 4000
        np.testing.assert_array_equal(got, np.arange(len(got)))
        [warning] = [w for w in contents.warnings if "not closed properly" in w]
        assert "is cut off" in warning and f"read {len(got)} messages" in warning


def chunk_offsets(data: bytes) -> list[int]:
    """Byte offsets of the Chunk records, found by walking the record framing."""
    offsets, pos = [], 8
    while True:
        opcode, length = struct.unpack_from("<BQ", data, pos)
        if opcode == 0x06:
            offsets.append(pos)
        if opcode == 0x02:  # footer
            return offsets
        pos += 9 + length


def test_damaged_chunk_is_reported_not_skipped_silently(tmp_path: Path) -> None:
    path = chunked_bag(tmp_path)
    data = bytearray(path.read_bytes())
    offsets = chunk_offsets(bytes(data))
    assert len(offsets) > 3
    # Chunk record: opcode, length, 3 x uint64, crc, "zstd" (4 + 4), uint64, compressed data.
    inside = offsets[1] + 9 + 28 + 8 + 8 + 20
    data[inside: inside + 16] = b"\xff" * 16
    path.write_bytes(bytes(data))
    contents = read_bag(path)
    assert not contents.closed_cleanly
    [warning] = [w for w in contents.warnings if "damaged chunk" in w]
    assert f"chunk at byte {offsets[1]}" in warning
    got = contents["/f"].value
    assert 0 < len(got) < 4000


def test_file_cut_inside_the_header_is_an_error(tmp_path: Path) -> None:
    path = chunked_bag(tmp_path, n=10)
    data = path.read_bytes()
    path.write_bytes(data[:14])
    with pytest.raises(BagError, match=r"truncated inside its MCAP Header record \(14 bytes\)"):
        read_bag(path)
    path.write_bytes(data[:5])
    with pytest.raises(BagError, match=r"truncated inside the MCAP magic \(5 bytes\)"):
        read_bag(path.parent)


# --- writer errors ---------------------------------------------------------------------------


def test_writer_refuses_bad_arguments(tmp_path: Path) -> None:
    (tmp_path / "exists").mkdir()
    with pytest.raises(BagError, match=r"exists already; BagWriter only creates new bags"):
        BagWriter(tmp_path / "exists", topics={"/f": FLOAT64})
    with pytest.raises(BagError, match=r"unknown ROS type 'std_msgs/msg/Float65'"):
        BagWriter(tmp_path / "a", topics={"/f": "std_msgs/msg/Float65"})
    with pytest.raises(BagError, match=r"topic names must be absolute"):
        BagWriter(tmp_path / "b", topics={"f": FLOAT64})
    with pytest.raises(BagError, match=r"flush_period_s must be a positive finite"):
        BagWriter(tmp_path / "c", topics={"/f": FLOAT64}, flush_period_s=0)
    with pytest.raises(BagError, match=r"compression must be 'zstd' or 'none'"):
        BagWriter(tmp_path / "d", topics={"/f": FLOAT64},
                  compression="lz4")  # type: ignore[arg-type]
    with pytest.raises(BagError, match=r"topics must map at least one topic to a type"):
        BagWriter(tmp_path / "e", topics={})


def test_writer_refuses_bad_messages(tmp_path: Path) -> None:
    w = BagWriter(tmp_path / "bag", topics={"/f": FLOAT64, "/p": FLUID_PRESSURE})
    with pytest.raises(BagError, match=r"'/p' is declared as 'sensor_msgs/msg/FluidPressure', "
                                       r"not 'std_msgs/msg/Float64'; use write\(\)"):
        w.write_float64("/p", T0, 1.0)
    with pytest.raises(BagError, match=r"'/x' was not declared; declared topics: \['/f', '/p'\]"):
        w.write_fluid_pressure("/x", T0, 1.0, 0.0)
    with pytest.raises(BagError, match=r"timestamps are integer nanoseconds, got 1.5 \(float\)"):
        w.write_float64("/f", 1.5, 1.0)  # type: ignore[arg-type]
    with pytest.raises(BagError, match=r"outside the MCAP range"):
        w.write_float64("/f", -1, 1.0)
    with pytest.raises(BagError, match=r"does not fit a builtin_interfaces/Time stamp"):
        w.write_fluid_pressure("/p", 2**31 * 10**9, 1.0, 0.0)
    with pytest.raises(BagError, match=r"must be a real number"):
        w.write_float64("/f", T0, "1.0")  # type: ignore[arg-type]
    w.write_float64("/f", np.int64(T0), np.float64(2.0))  # numpy scalars are fine
    w.close()
    w.close()  # idempotent
    with pytest.raises(BagError, match=r"is closed"):
        w.write_float64("/f", T0, 1.0)
    contents = read_bag(tmp_path / "bag")
    assert contents.closed_cleanly and list(contents["/f"].value) == [2.0]


def test_provisional_metadata_exists_at_open(tmp_path: Path) -> None:
    w = BagWriter(tmp_path / "bag", topics={"/f": FLOAT64}, flush_thread=False)
    try:
        meta = yaml.safe_load((tmp_path / "bag" / "metadata.yaml").read_text())
        info = meta["rosbag2_bagfile_information"]
        assert info["relative_file_paths"] == ["bag_0.mcap"]
        assert info["topics_with_message_count"][0]["topic_metadata"]["name"] == "/f"
        assert (tmp_path / "bag" / "bag_0.mcap").read_bytes().startswith(MAGIC)
        contents = read_bag(tmp_path / "bag")  # header only, nothing flushed yet
        assert not contents.closed_cleanly and len(contents["/f"]) == 0
    finally:
        w.close()


def test_module_imports_no_ros_packages() -> None:
    code = ("import sys, pcv_sim.io\n"
            "roots = {m.split('.')[0] for m in sys.modules}\n"
            "print(sorted(roots & {'rclpy', 'std_msgs', 'sensor_msgs', 'diagnostic_msgs'}))")
    env = {k: v for k, v in os.environ.items() if k != "_ROS_WHEELS_BOOTSTRAP_COMPLETE"}
    env["PYTHONPATH"] = str(REPO)
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                         timeout=60, check=True)
    assert out.stdout.strip().splitlines()[-1] == "[]"
