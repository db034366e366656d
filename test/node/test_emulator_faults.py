"""The emulator's fault topic over real DDS: off unless faults.enabled; a sensor fault changes what
is published, a physical fault the valve; each command is logged with its publisher's node name."""
import pytest

from pcv_sim.io.topics import CURRENT, PRESSURE

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
