"""The node's endpoints offer the QoS of the interface registry (pcv_sim.io.topics): every publisher
and subscription of the emulator and of the rig (the lockstep channel, faults and /clock included)
is made with the profile the registry gives its topic, and follows the registry when it changes.
In this process: the endpoints as the node made them (rclpy's own, /rosout and /parameter_events,
aside)."""

import dataclasses

import pytest
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, qos_profile_sensor_data

from pcv_sim.io import topics
from pcv_sim.io.bag import COMMAND_QOS, SENSOR_DATA_QOS, Qos
from pcv_sim.node.qos_events import ros_qos, topic_qos

ROS_OWN = ('/rosout', '/parameter_events')
SIMULATED = {'time_mode': 'simulated', 'lockstep': True, 'faults.enabled': True}


def test_the_registrys_qos_as_rclpy_profiles():
    assert ros_qos(SENSOR_DATA_QOS) == qos_profile_sensor_data
    assert ros_qos(COMMAND_QOS) == QoSProfile(depth=10)
    assert ros_qos(topics.FLAGS_QOS) == QoSProfile(depth=100)
    kept = ros_qos(Qos('reliable', 1, 'keep_all', 'transient_local'))
    assert (kept.history, kept.durability) == (HistoryPolicy.KEEP_ALL, DurabilityPolicy.TRANSIENT_LOCAL)
    assert topic_qos('left/pressure') == topic_qos(topics.PRESSURE) == qos_profile_sensor_data   # a valve's by its role
    with pytest.raises(ValueError, match="topic 'nosuch' is not in the interface registry"):
        topic_qos('nosuch')


def _node(ros, executable, params):
    from pcv_sim.node.emulator import emulator_node
    from pcv_sim.node.rig import rig_node

    make = {'emulator': emulator_node, 'rig': rig_node}[executable]
    return make(argv=[executable], context=ros.context, namespace=ros.ns(executable),
                parameter_overrides=[Parameter(k, value=v) for k, v in params.items()])


def _endpoints(node):
    """relative topic -> the profiles of the node's endpoints on it."""
    ns = node.get_namespace().rstrip('/') + '/'
    out = {}
    for e in (*node.publishers, *node.subscriptions):
        name = e.topic_name
        if name in ROS_OWN:
            continue
        out.setdefault(name.removeprefix(ns) if name.startswith(ns) else name, []).append(e.qos_profile)
    return out


#: Topics whose QoS the test changes in the registry (a deeper queue): the node must offer the changed one.
CHANGED = (topics.PRESSURE, topics.DUTY_CYCLE, topics.DIAGNOSTICS, topics.FAULTS,
           topics.cylinder_topic(topics.JOINT_STATES))


@pytest.mark.parametrize(('executable', 'expected', 'changed'), [
    ('emulator', {'duty_cycle', 'load_flow', 'supply_pressure', 'pressure', 'current', 'spool_position', 'faults',
                  '/diagnostics', '/clock', 'lockstep/sample', 'lockstep/command'},
     {'pressure', 'duty_cycle', '/diagnostics', 'faults'}),
    ('rig', {'left/duty_cycle', 'right/pressure', 'cylinder/joint_states', 'cylinder/pressure_a',
             'cylinder/external_force', 'faults', '/diagnostics', '/clock', 'lockstep/sample', 'lockstep/command'},
     {'left/pressure', 'right/duty_cycle', '/diagnostics', 'faults', 'cylinder/joint_states'}),
])
def test_every_endpoint_of_the_node_has_the_registrys_qos_and_follows_it(ros, monkeypatch, executable, expected,
                                                                         changed):
    for t in CHANGED:
        q = topics.qos_of(t)
        monkeypatch.setitem(topics._QOS, t, dataclasses.replace(q, depth=q.depth + 7))
    node = _node(ros, executable, SIMULATED)
    try:
        endpoints = _endpoints(node)
    finally:
        node.destroy_node()
    assert expected | changed <= set(endpoints), sorted(endpoints)
    wrong = {t: p for t, profiles in endpoints.items() for p in profiles if p != topic_qos(t)}
    assert wrong == {}
    unchanged = {QoSProfile(depth=10).depth, qos_profile_sensor_data.depth, topics.FLAGS_QOS.depth}
    assert all(p.depth not in unchanged for t in changed for p in endpoints[t]), {t: endpoints[t] for t in changed}
