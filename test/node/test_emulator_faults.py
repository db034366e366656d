"""The emulator's fault topic over real DDS: off unless faults.enabled; a sensor fault changes what
is published, a physical fault the valve; each command is logged with its publisher's node name."""
import pytest

from pcv_sim.io.topics import CURRENT, FAULTS, PRESSURE

START = 30.0                      # s: node start-up and discovery on a busy 2-core machine


def test_the_fault_topic_is_off_unless_enabled(ros):
    emu = ros.start('off', params={'safe_duty': 0.3})
    c = ros.client('off')
    assert c.wait_for_emulator(START), emu.output()
    c.spin_for(1.0)
    assert c.fault_pub.get_subscription_count() == 0
    assert 'fault topic off (faults.enabled: false)' in emu.output()


def test_faults_change_what_is_published_and_are_logged_with_their_publisher(ros):
    emu = ros.start('on', params={'safe_duty': 0.7, 'watchdog_timeout': 0.0, 'faults.enabled': True,
                                  'diagnostics_period': 0.2})
    c = ros.client('on', outputs=(PRESSURE, CURRENT))
    assert c.wait_for_emulator(START), emu.output()
    assert c.spin_until(lambda: c.fault_pub.get_subscription_count() > 0, 10)
    c.spin_for(0.5)
    before = c.samples[-1].pressure
    current = c.outputs[CURRENT][-1][1]
    assert current > 0.3

    c.send_fault('{fault: bias, signal: pressure, value: 1.0e+5}')
    assert c.spin_until(lambda: c.samples[-1].pressure == pytest.approx(before + 1e5, abs=100.0), 10), \
        (before, c.samples[-1].pressure)
    diag = c.wait_for_diagnostics(lambda d: d['faults_active'] == 'bias@pressure', timeout=10)
    assert diag is not None and diag['accepted.faults'] == '1'
    assert 'faults active: bias@pressure' in c.diagnostic_statuses[-1]['inputs'][1]

    c.send_fault('{fault: coil_open}')               # the one valve: no target needed
    assert c.spin_until(lambda: abs(c.outputs[CURRENT][-1][1]) < 0.01 * current, 10)

    c.send_fault('{fault: nosuch}')
    diag = c.wait_for_diagnostics(lambda d: d['rejected.faults'] == '1', timeout=10)
    assert diag is not None and "kind 'nosuch'" in diag['last_rejection']

    c.send_fault('{clear: bias, signal: pressure}')
    c.send_fault('{clear: coil_open}')
    assert c.spin_until(lambda: abs(c.outputs[CURRENT][-1][1] - current) < 0.01 * current, 10)
    diag = c.wait_for_diagnostics(lambda d: d['faults_active'] == '', timeout=10)
    assert diag is not None

    out = emu.output()
    who = f'from node {ros.ns("on")}/test_client_0'
    assert f"fault command '{{fault: bias, signal: pressure, value: 1.0e+5}}' {who}" in out, out
    assert "rejected faults: fault: kind 'nosuch'" in out and 'nothing changed' in out, out
    assert 'fault topic on (faults.enabled)' in out


def test_fault_commands_are_recorded_at_the_step_they_acted_as_in_the_rigs_bag(ros):
    """record.enabled with faults.enabled: the bag's `faults` topic (std_msgs/String) holds each fault
    command that acted, as given, stamped at its step; one refused when due (clearing a fault that is
    not active) is not in it. Read back with the mcap reader (CDR decoded here)."""
    import signal
    import struct

    from mcap.reader import make_reader

    bags = ros.tmp_path / 'bags'
    emu = ros.start('rec', params={'safe_duty': 0.7, 'watchdog_timeout': 0.0, 'faults.enabled': True,
                                   'diagnostics_period': 0.2, 'record.enabled': True,
                                   'record.directory': str(bags), 'record.name': 'run'})
    c = ros.client('rec')
    assert c.wait_for_emulator(START), emu.output()
    assert c.spin_until(lambda: c.fault_pub.get_subscription_count() > 0, 10)
    c.send_fault('{fault: coil_open}')
    c.send_fault('{clear: bias, signal: pressure}')       # not active when due: refused then
    c.spin_for(0.3)
    c.send_fault('{clear: coil_open}')
    diag = c.wait_for_diagnostics(lambda d: d['rejected.faults'] == '1' and d['accepted.faults'] == '2', timeout=10)
    assert diag is not None, c.diagnostics[-1:]
    c.spin_for(0.3)
    assert emu.stop(signal.SIGINT) == 0
    out = emu.output()
    assert 'recording finished' in out and 'dropped' not in out, out

    ns = ros.ns('rec')
    [mcap_file] = (bags / 'run').glob('*.mcap')
    texts, pressure = [], []
    with open(mcap_file, 'rb') as f:
        for schema, channel, message in make_reader(f).iter_messages():
            if channel.topic == f'{ns}/{FAULTS}':
                assert schema.name == 'std_msgs/msg/String'
                (n,) = struct.unpack_from('<I', message.data, 4)
                texts.append((message.log_time, message.data[8:8 + n - 1].decode()))
            elif channel.topic == f'{ns}/{PRESSURE}':
                pressure.append(message.log_time)
    assert [text for _, text in texts] == ['{fault: coil_open}', '{clear: coil_open}'], texts
    t_open, t_clear = (t for t, _ in texts)
    assert pressure[0] < t_open < t_clear < pressure[-1]
    assert (t_open - pressure[0]) % 100_000 == 0              # at a model step (stamps on the 0.1 ms grid)

