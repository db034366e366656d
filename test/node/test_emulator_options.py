"""The valve options' signals over real DDS (docs/model.md R33-R35, io.topics.OPTION_INTERFACE):
with an option on, its outputs are published with each sample and its inputs taken as topics, and
both are in the diagnostics; with the options off (the paper's valve) there are no such topics."""
from std_msgs.msg import Float64

from pcv_sim.io.topics import COIL_RESISTANCE, COIL_TEMPERATURE, CORE_POSITION, OIL_TEMPERATURE, OPTION_INTERFACE
from pcv_sim.node.client import sample_qos
from pcv_sim.params import load_params
from pcv_sim.units import kelvin

START = 30.0                      # s: node start-up and discovery on a busy 2-core machine
PARAMS = load_params()
OPTIONS = {'model.solenoid.coil_temperature': 'lumped', 'model.fluid.temperature': 'input',
           'model.spool.core': 'separate'}


def test_the_options_signals_are_topics_and_diagnostics(ros):
    emu = ros.start('opt', params={'safe_duty': 0.9, 'watchdog_timeout': 0.0, 'diagnostics_period': 0.2, **OPTIONS})
    c = ros.client('opt')
    got = {name: [] for name in (COIL_TEMPERATURE, COIL_RESISTANCE, CORE_POSITION)}
    for name, values in got.items():
        c.node.create_subscription(Float64, name, lambda m, v=values: v.append(m.data), sample_qos(1000))
    oil = c.node.create_publisher(Float64, OIL_TEMPERATURE, 10)
    assert c.wait_for_emulator(START), emu.output()
    assert c.spin_until(lambda: all(len(v) > 50 for v in got.values()), 10), {k: len(v) for k, v in got.items()}
    ambient = kelvin(PARAMS.solenoid.ambient_temperature_c)
    assert all(ambient - 1.0 < t < ambient + 50.0 for t in got[COIL_TEMPERATURE])
    assert all(0.5 * PARAMS.solenoid.coil_resistance < r < 2.0 * PARAMS.solenoid.coil_resistance
               for r in got[COIL_RESISTANCE])
    assert all(-0.01 < x < 0.01 for x in got[CORE_POSITION])         # m, within the stroke
    assert c.spin_until(lambda: oil.get_subscription_count() > 0, 10)
    oil.publish(Float64(data=kelvin(50.0)))
    diag = c.wait_for_diagnostics(lambda d: d.get('oil_temperature_k') == f'{kelvin(50.0):.2f}', timeout=10)
    assert diag is not None, c.diagnostics[-1:]
    assert diag['accepted.oil_temperature'] == '1'
    assert float(diag['coil_temperature_k']) > ambient - 1.0 and float(diag['coil_resistance_ohm']) > 0
    assert 'core_position_m' in diag and 'ambient_temperature_k' in diag
    oil.publish(Float64(data=50.0))                                   # degC by mistake: refused with the hint
    diag = c.wait_for_diagnostics(lambda d: d['rejected.oil_temperature'] == '1', timeout=10)
    assert diag is not None and 'the unit is K, not degC' in diag['last_rejection']


def test_without_the_options_there_are_no_option_topics(ros):
    emu = ros.start('plain', params={'safe_duty': 0.3})
    c = ros.client('plain')
    assert c.wait_for_emulator(START), emu.output()
    c.spin_for(0.5)
    ns = ros.ns('plain')
    for e in OPTION_INTERFACE:
        counted = c.node.count_publishers if e.direction == 'out' else c.node.count_subscribers
        assert counted(f'{ns}/{e.name}') == 0, e.name
    diag = c.wait_for_diagnostics(timeout=10)
    assert not any(k.startswith(e.name) for k in diag for e in OPTION_INTERFACE)


def test_the_options_signals_are_recorded_and_read_back_by_independent_readers(ros):
    import signal

    from mcap.reader import make_reader
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    emu = ros.start('rec', params={
        'safe_duty': 0.9, 'watchdog_timeout': 0.0, 'time_mode': 'simulated', 'lockstep': False,
        'real_time_factor': 0.0, 'record.enabled': True, 'record.name': 'run',
        'record.directory': str(ros.tmp_path / 'bags'), **OPTIONS})
    c = ros.client('rec')
    oil = c.node.create_publisher(Float64, OIL_TEMPERATURE, 10)
    assert c.wait_for_emulator(START), emu.output()
    assert c.spin_until(lambda: oil.get_subscription_count() > 0, 10)
    oil.publish(Float64(data=kelvin(50.0)))
    c.spin_for(1.0)
    assert emu.stop(signal.SIGINT) == 0
    out = emu.output()
    assert 'recording finished' in out and 'dropped' not in out, out

    ns = ros.ns('rec')
    bag_path = ros.tmp_path / 'bags' / 'run'
    with AnyReader([bag_path], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        types = {x.topic: x.msgtype for x in reader.connections}
        got = {t: [] for t in types}
        for conn, t, raw in reader.messages():
            got[conn.topic].append((t, reader.deserialize(raw, conn.msgtype).data
                                    if conn.msgtype == 'std_msgs/msg/Float64' else None))
    for e in OPTION_INTERFACE:
        assert types[f'{ns}/{e.name}'] == 'std_msgs/msg/Float64', e.name
    n = len(got[f'{ns}/pressure'])
    assert n > 100
    # The outputs with each recorded sample, at its stamp; the inputs on change (the oil from its step).
    for name in (COIL_TEMPERATURE, COIL_RESISTANCE, CORE_POSITION):
        assert [t for t, _ in got[f'{ns}/{name}']] == [t for t, _ in got[f'{ns}/pressure']], name
    ambient = kelvin(PARAMS.solenoid.ambient_temperature_c)
    temps = [v for _, v in got[f'{ns}/{COIL_TEMPERATURE}']]
    assert temps[0] == ambient and temps[-1] > ambient                    # the coil warms at 90 %
    oils = [v for _, v in got[f'{ns}/{OIL_TEMPERATURE}']]
    assert oils[-1] == kelvin(50.0) and len(oils) == 2                    # configured, then the one sent
    assert [v for _, v in got[f'{ns}/ambient_temperature']] == [ambient]
    [mcap_file] = bag_path.glob('*.mcap')
    with open(mcap_file, 'rb') as f:
        counts = {}
        for _, channel, _ in make_reader(f).iter_messages():
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
    assert counts == {t: len(v) for t, v in got.items()}
