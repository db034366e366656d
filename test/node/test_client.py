"""The one client of any device node (`pcv_sim.node.client.DeviceClient`): its endpoints follow from
the device's names through the interface registry (io/topics.py), for the emulator's bare names and
the rig's named valves alike; it keeps the statuses of its own device node only. The DDS runs with a
node are test_emulator_*.py, test_rig_*.py and test_emulator_lockstep.py."""

import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

from pcv_sim.io.topics import input_topics


def endpoints(client):
    """(relative topic, message type name) of the client's publishers in its namespace, faults aside."""
    ns = client.node.get_namespace().rstrip('/') + '/'
    return {(p.topic_name.removeprefix(ns), p.msg_type.__name__) for p in client.node.publishers
            if p.topic_name.startswith(ns) and not p.topic_name.endswith('/faults')}


def test_the_emulators_client_publishes_its_inputs_under_their_bare_names(ros):
    from pcv_sim.node.client import DeviceClient

    c = DeviceClient(ros.ns('valve'), context=ros.context, node_name='names_0')
    ros.clients.append(c)
    assert endpoints(c) == {('duty_cycle', 'Float64'), ('load_flow', 'Float64'), ('supply_pressure', 'FluidPressure')}
    assert c.device_name == f"{ros.ns('valve')}/emulator"
    with pytest.raises(ValueError, match='lockstep=True'):
        c.run(lambda t, m: {}, 1)


def test_the_rigs_client_publishes_each_valves_inputs_and_the_cylinders_from_the_registry(ros):
    from pcv_sim.node.client import DeviceClient

    c = DeviceClient(ros.ns('rig'), ('left', 'right'), context=ros.context, node_name='names_1', device_node='rig',
                     lockstep=True)
    ros.clients.append(c)
    assert endpoints(c) == {('left/duty_cycle', 'Float64'), ('right/duty_cycle', 'Float64'),
                            ('cylinder/external_force', 'Float64')}
    c.send('right.supply_pressure', 150e5)                         # made at its first use, typed by its role
    [entry] = input_topics(('right.supply_pressure',), ('left', 'right'))
    assert (entry.topic, 'FluidPressure') in endpoints(c)
    subscribed = {s.topic_name.rpartition(ros.ns('rig') + '/')[2] for s in c.node.subscriptions}
    assert {'left/pressure', 'right/pressure', 'cylinder/joint_states'} <= subscribed
    assert not any(t.endswith('current') for t in subscribed)      # currents=False


def test_the_client_keeps_its_own_device_nodes_statuses_by_name_and_merged(ros):
    from pcv_sim.node.client import DeviceClient

    c = DeviceClient(ros.ns('rig'), ('left', 'right'), context=ros.context, node_name='names_2', device_node='rig')
    ros.clients.append(c)
    me, other = c.device_name, f"{ros.ns('other')}/rig"

    def status(name, level, message, **values):
        return DiagnosticStatus(level=bytes([level]), name=name, message=message,
                                values=[KeyValue(key=k, value=v) for k, v in values.items()])

    c._diagnostic(DiagnosticArray(status=[status(f'{other}: inputs', 2, 'not mine', faults_active='x')]))
    assert c.statuses == [] and c.diagnostics == []
    c._diagnostic(DiagnosticArray(status=[status(f'{me}: inputs', 1, 'faults active: coil_open@left',
                                                 faults_active='coil_open@left'),
                                          status(f'{me}: left', 0, 'commands arriving', chamber='a'),
                                          status(f'{other}: inputs', 2, 'not mine', faults_active='x')]))
    assert c.statuses == [{f'{me}: inputs': (1, 'faults active: coil_open@left', {'faults_active': 'coil_open@left'}),
                           f'{me}: left': (0, 'commands arriving', {'chamber': 'a'})}]
    assert c.diagnostics == [{'faults_active': 'coil_open@left', 'chamber': 'a'}]
    assert c.diagnostic_levels == [1] and c.diagnostic_statuses[0]['left'] == (0, 'commands arriving')
