"""Who sent a message, for the log: by the publisher GID where rclpy gives it (Kilted), by the
topic's publishers where it does not (Jazzy). Real endpoints from the ROS graph of this domain."""

from __future__ import annotations

import time

import rclpy
from std_msgs.msg import String

from pcv_sim.node.inputs import publisher_name


def _graph(ros, names, topic='faults'):
    """One node per name, each publishing on `topic`; a listener node that sees them all."""
    nodes = [rclpy.create_node(n, namespace=ros.prefix, context=ros.context) for n in names]
    pubs = [n.create_publisher(String, f'{ros.prefix}/{topic}', 10) for n in nodes]
    listener = rclpy.create_node('listener', namespace=ros.prefix, context=ros.context)
    end = time.monotonic() + 10
    while len(listener.get_publishers_info_by_topic(f'{ros.prefix}/{topic}')) < len(names):
        assert time.monotonic() < end, 'the publishers never showed in the graph'
        time.sleep(0.05)
    return nodes, pubs, listener, listener.get_publishers_info_by_topic(f'{ros.prefix}/{topic}')


def test_the_gid_names_the_publisher_among_several(ros):
    nodes, _, listener, endpoints = _graph(ros, ['ctl_a', 'ctl_b'])
    try:
        b = next(e for e in endpoints if e.node_name == 'ctl_b')
        info = {'publisher_gid': {'implementation_identifier': 'rmw_fastrtps_cpp', 'data': bytes(b.endpoint_gid)}}
        assert publisher_name(endpoints, info) == f'node {ros.prefix}/ctl_b'
        other = {'publisher_gid': {'data': bytes([9] * 16)}}       # a publisher gone from the graph
        assert publisher_name(endpoints, other) == 'a publisher DDS did not name'
    finally:
        for n in [*nodes, listener]:
            n.destroy_node()


def test_without_a_gid_the_only_publisher_is_named_and_several_are_listed(ros):
    nodes, _, listener, endpoints = _graph(ros, ['ctl_a'])
    try:
        info = {'source_timestamp': 1, 'received_timestamp': 2}       # Jazzy's MessageInfo: no GID
        assert publisher_name(endpoints, info) == \
            f"node {ros.prefix}/ctl_a (the topic's only publisher; DDS gave no publisher GID)"
    finally:
        for n in [*nodes, listener]:
            n.destroy_node()
    nodes, _, listener, endpoints = _graph(ros, ['ctl_b', 'ctl_c'], topic='other')
    try:
        assert publisher_name(endpoints, {}) == \
            f'one of the nodes {ros.prefix}/ctl_b, {ros.prefix}/ctl_c (DDS gave no publisher GID)'
        assert publisher_name([], {}) == 'a publisher DDS did not name'
    finally:
        for n in [*nodes, listener]:
            n.destroy_node()
