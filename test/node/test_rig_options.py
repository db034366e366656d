"""The valve options' signals of a rig's valves over real DDS, as the emulator serves its own
(docs/model.md R33, R34; io.topics.OPTION_INTERFACE): a valve with a lumped coil and an oil
temperature input publishes its coil temperature and resistance with each sample under its name,
takes the temperatures as topics (checked as the emulator checks them: a degC value is refused with
the hint), reports both in its diagnostics status and records them (record.enabled); the paper's
valves beside it have no such topics. The rig node is a separate process; a lockstep controller
answers every control period."""
import signal
import struct

from sensor_msgs.msg import FluidPressure
from std_msgs.msg import Float64

from pcv_sim.node.client import sample_qos
from pcv_sim.units import kelvin

from .conftest import wait_until
from .test_rig_node import _rig_status, start_rig

START = 90.0        # s: start-up (a composite with the options), discovery on a busy 2-core machine
VALVES = ('left', 'right', 'probe')


def test_a_rig_valves_options_are_topics_diagnostics_and_in_its_bag(ros, options_rig):
    from mcap.reader import make_reader

    bags = ros.tmp_path / 'bags'
    rig = start_rig(ros, params={'rig_config': str(options_rig), 'diagnostics_period': 0.2,
                                 'record.enabled': True, 'record.directory': str(bags), 'record.name': 'run'})
    client = _client(ros)
    node = client.node
    got = {name: [] for name in ('coil_temperature', 'coil_resistance')}
    for name, values in got.items():
        client.add_input(node.create_subscription(Float64, f'probe/{name}', lambda _m: None, sample_qos(1000)),
                         lambda m, _i, v=values: v.append(m.data))
    right = []                        # a valve after the probe in the rig's signals (options between): its own
    client.add_input(node.create_subscription(FluidPressure, 'right/pressure', lambda _m: None, sample_qos(1000)),
                     lambda m, _i: right.append((m.header.stamp.sec * 10**9 + m.header.stamp.nanosec, m.fluid_pressure)))
    oil = node.create_publisher(Float64, 'probe/oil_temperature', 10)
    assert client.wait_for_rig(START), rig.output()
    assert wait_until(lambda: oil.get_subscription_count() > 0, 10)

    def heat(t, m):                     # the probe's coil warms at 90 %
        return {'left': 0.5, 'right': 0.5, 'probe': 0.9}

    client.run(heat, 300, timeout=120)
    assert len(got['coil_temperature']) > 100, {k: len(v) for k, v in got.items()}
    temps = got['coil_temperature']
    assert temps[-1] > temps[0] > kelvin(-60.0)                                # K: it warmed at 90 %
    assert all(0.5 < r < 200.0 for r in got['coil_resistance'])               # ohm
    # The client reads these very topics, so the check is physical: a pressure of tens of bar, not
    # the probe's coil temperature (~313 K) or resistance that stand before it in the rig's signals.
    assert len(right) > 100 and all(10e5 < p < 300e5 for _, p in right), right[-3:]

    oil.publish(Float64(data=kelvin(50.0)))
    client.run(heat, 100, timeout=60)
    ns = ros.ns('rig')
    diag = _rig_status(client, lambda d: d.get(f'{ns}/rig: probe', (0, '', {}))[2].get('oil_temperature_k')
                       == f'{kelvin(50.0):.2f}', timeout=10)
    assert diag is not None, (client.statuses[-1:], rig.output())
    probe = diag[f'{ns}/rig: probe'][2]
    assert probe['accepted.oil_temperature'] == '1' and probe['rejected.oil_temperature'] == '0'
    assert float(probe['coil_temperature_k']) > temps[0] and float(probe['coil_resistance_ohm']) > 0.5
    assert 'ambient_temperature_k' in probe
    assert not any(k.startswith(('coil_', 'oil_', 'ambient_')) for k in diag[f'{ns}/rig: left'][2])
    oil.publish(Float64(data=50.0))                                           # degC by mistake
    client.run(heat, 100, timeout=60)
    diag = _rig_status(client, lambda d: d.get(f'{ns}/rig: probe', (0, '', {}))[2].get('rejected.oil_temperature')
                       == '1', timeout=10)
    assert diag is not None, (client.statuses[-1:], rig.output())
    assert 'the unit is K, not degC' in diag[f'{ns}/rig: inputs'][2]['last_rejection']
    for valve in ('left', 'right'):
        for e in ('coil_temperature', 'coil_resistance', 'core_position'):
            assert node.count_publishers(f'{ns}/{valve}/{e}') == 0, (valve, e)
        for e in ('ambient_temperature', 'oil_temperature'):
            assert node.count_subscribers(f'{ns}/{valve}/{e}') == 0, (valve, e)
    assert rig.stop(signal.SIGINT) == 0
    out = rig.output()
    assert 'recording finished' in out and 'dropped' not in out and 'Traceback' not in out, out
    assert 'rejected probe/oil_temperature: oil temperature 50 K' in out

    [mcap_file] = (bags / 'run').glob('*.mcap')
    rec: dict[str, list[tuple[int, float]]] = {}
    with open(mcap_file, 'rb') as f:
        for schema, channel, message in make_reader(f).iter_messages():
            if channel.topic.startswith(f'{ns}/probe/') and schema.name == 'std_msgs/msg/Float64':
                rec.setdefault(channel.topic, []).append((message.log_time, struct.unpack_from('<d', message.data, 4)[0]))
            else:
                rec.setdefault(channel.topic, []).append((message.log_time, 0.0))
    assert [t for t, _ in rec[f'{ns}/probe/coil_temperature']] == [t for t, _ in rec[f'{ns}/probe/pressure']]
    assert [t for t, _ in rec[f'{ns}/probe/coil_resistance']] == [t for t, _ in rec[f'{ns}/probe/pressure']]
    assert rec[f'{ns}/probe/coil_temperature'][-1][1] > rec[f'{ns}/probe/coil_temperature'][0][1]
    oils = [v for _, v in rec[f'{ns}/probe/oil_temperature']]
    assert oils[-1] == kelvin(50.0) and len(oils) == 2                 # configured, then the one sent
    assert len(rec[f'{ns}/probe/ambient_temperature']) == 1
    assert f'{ns}/left/coil_temperature' not in rec


def _client(ros):
    from pcv_sim.node.client import RigClient

    client = RigClient(ros.ns('rig'), VALVES, context=ros.context, node_name=f'rig_ctl_{len(ros.clients)}')
    ros.clients.append(client)
    return client

