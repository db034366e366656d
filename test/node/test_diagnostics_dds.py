"""The node publishes the device diagnostics over DDS (pcv_sim.device.diagnostics builds them)."""

import re

from pcv_sim.device.diagnostics import CONCERNS, OK, WARN
from pcv_sim.params import load_params

PARAMS = load_params()
START = 60.0
NAME = '/left/emulator'


def test_the_node_publishes_one_status_per_concern_and_a_run_without_trouble_is_ok(ros):
    """Inputs, model and recording are OK when nothing is wrong with them. Timing is OK, or, on a
    loaded machine where the node fell behind wall time, WARN saying by how much, from the
    figures it publishes beside (the thresholds themselves are checked on a fake clock in
    test/device/test_diagnostics.py): never WARN within its thresholds."""
    ros.start(params={'safe_duty': 0.3, 'watchdog_timeout': 0.0, 'diagnostics_period': 0.2,
                      'diagnostics.late_fraction': 0.5, 'diagnostics.max_lag': 0.5})
    c = ros.client()
    assert c.wait_for_emulator(START)
    c.send_duty(0.5)
    assert c.wait_for_diagnostics(lambda d: d['accepted.duty_cycle'] == '1', 10)
    c.spin_for(0.5)
    last, values = c.diagnostic_statuses[-1], c.diagnostics[-1]
    assert set(last) == set(CONCERNS)
    assert {k: level for k, (level, _) in last.items() if k != 'timing'} == \
        dict.fromkeys(set(CONCERNS) - {'timing'}, OK), last
    level, message = last['timing']
    late = float(values['period_late_fraction']) > 0.5
    lag = float(values['period_max_lag_ms']) > 500.0
    skipped = re.search(r'(\d+) steps skipped', message)
    assert level == (WARN if late or lag or skipped else OK), (last, values)
    assert ('steps late' in message) == late and ('behind wall time' in message) == lag, message
