"""The reference bags read back with two independent readers: rosbags' AnyReader and the mcap
package's reader (with the ros2 decoder-free raw API), and agree with pcv_sim's read_bag."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from pcv_sim.io.bag import read_bag
from pcv_sim.io.topics import BAG_TOPICS
from pcv_sim.replay.reference_bags import PROTOCOLS

BAGS = Path(__file__).resolve().parents[3] / "bags"
REFERENCE_BAGS = tuple(PROTOCOLS)



@pytest.mark.parametrize("name", REFERENCE_BAGS)
def test_rosbags_anyreader(name):
    ours = read_bag(BAGS / name)
    assert ours.closed_cleanly and not ours.warnings
    with AnyReader([BAGS / name], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        assert {c.topic: c.msgtype for c in reader.connections} == BAG_TOPICS
        pressure = [c for c in reader.connections if c.topic == "/pressure"]
        values, stamps, times = [], [], []
        for conn, t, raw in reader.messages(connections=pressure):
            msg = reader.deserialize(raw, conn.msgtype)
            values.append(msg.fluid_pressure)
            stamps.append(msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec)
            times.append(t)
    np.testing.assert_array_equal(values, ours["/pressure"].value)
    np.testing.assert_array_equal(times, ours["/pressure"].t_ns)
    np.testing.assert_array_equal(stamps, times)  # header stamp = sample time = log time
    assert np.all(np.diff(times) == 1_000_000)


@pytest.mark.parametrize("name", REFERENCE_BAGS)
def test_mcap_reader(name):
    ours = read_bag(BAGS / name)
    (path,) = (BAGS / name).glob("*.mcap")
    with open(path, "rb") as f:
        reader = make_reader(f)
        header = reader.get_header()
        assert header.profile == "ros2"
        summary = reader.get_summary()
        assert summary is not None
        assert {c.topic for c in summary.channels.values()} == set(BAG_TOPICS)
        assert {s.name for s in summary.schemas.values()} == set(BAG_TOPICS.values())
        assert all(c.compression == "zstd" for c in summary.chunk_indexes)
        duty = [(m.log_time, np.frombuffer(m.data[4:], "<f8")[0])
                for _, c, m in reader.iter_messages(topics=["/duty_cycle"])]
    assert [t for t, _ in duty] == ours["/duty_cycle"].t_ns.tolist()
    assert [v for _, v in duty] == ours["/duty_cycle"].value.tolist()
    counts = {t: len(s) for t, s in ours.topics.items()}
    assert summary.statistics.message_count == sum(counts.values())
