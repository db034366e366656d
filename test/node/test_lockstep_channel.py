"""The lockstep channel's messages (`pcv_sim.node.lockstep_channel`): CDR written and read here,
checked against rclpy's own serialization of sensor_msgs/JointState (no DDS needed)."""
import math

import pytest
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import JointState
from std_msgs.msg import Header

from pcv_sim.errors import CommandError
from pcv_sim.node.lockstep_channel import NamedVector, decode, measurement, split_command

NAMES = [
    ['left.pressure', 'left.current', 'left.spool_position', 'cylinder.position', 'setpoint'],
    ['x'],
    [],
    ['yz', 'abcdefg', 'q', 'a.b'],
]


@pytest.mark.parametrize('names', NAMES)
@pytest.mark.parametrize('frame_id', ['', 'ab', 'frame'])
def test_what_is_written_is_the_joint_state_rclpy_reads(names, frame_id):
    writer = NamedVector(names, frame_id)
    for stamp, values in [(12_345_678_901, [1.5 * i - 3.0 for i in range(len(names))]),
                          (0, [math.pi * 1e7, -0.0, 5e-324, 1.7976931348623157e308, math.inf][:len(names)])]:
        msg = deserialize_message(writer.encode(stamp, values), JointState)
        assert list(msg.name) == names and msg.header.frame_id == frame_id
        assert msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec == stamp
        assert [v.hex() for v in msg.position] == [float(v).hex() for v in values]      # bit for bit
        assert len(msg.velocity) == 0 and len(msg.effort) == 0


@pytest.mark.parametrize('names', NAMES)
@pytest.mark.parametrize('velocity', [[], [2.0, 3.0]])
def test_what_rclpy_writes_is_read(names, velocity):
    values = [0.25 * i + 1e-9 for i in range(len(names))]
    msg = JointState(header=Header(frame_id='base'), name=names, position=values, velocity=velocity, effort=[4.0])
    msg.header.stamp.sec, msg.header.stamp.nanosec = 3, 999_999_999
    for _ in range(2):                       # the second time from the names kept
        assert decode(serialize_message(msg)) == (3_999_999_999, tuple(names), tuple(values))
    other = JointState(name=['other'], position=[7.0])   # other names after kept ones: read anew
    assert decode(serialize_message(other)) == (0, ('other',), (7.0,))


def test_a_nan_is_a_signal_not_measured():
    writer = NamedVector(['a', 'b', 'c'])
    _, names, values = decode(writer.encode(1_000_000, [1.0, math.nan, 3.0]))
    assert measurement(names, values) == {'a': 1.0, 'c': 3.0}


def test_a_malformed_message_is_refused_saying_what_is_accepted():
    good = serialize_message(JointState(name=['left.duty', 'right.duty'], position=[0.5, 0.4]))
    with pytest.raises(CommandError, match='not a little-endian CDR sensor_msgs/JointState'):
        decode(good[:10])
    with pytest.raises(CommandError, match='malformed sensor_msgs/JointState'):
        decode(good[:40])
    with pytest.raises(CommandError, match='2 names and 1 positions; accepted is one position per name'):
        decode(serialize_message(JointState(name=['left.duty', 'right.duty'], position=[0.5])))


def test_a_command_splits_into_duties_and_flags_and_refuses_other_names():
    duties, flags = split_command(['left.duty', 'controller.fault_detected', 'right.duty'], [0.5, 1.0, 0.25],
                                  ('left', 'right'))
    assert duties == {'left': 0.5, 'right': 0.25} and flags == {'fault_detected': 1.0}
    with pytest.raises(CommandError, match=r"'middle.duty' is not accepted; accepted are left.duty, right.duty and "
                                           r"controller.<flag>"):
        split_command(['left.duty', 'middle.duty'], [0.5, 0.5], ('left', 'right'))
