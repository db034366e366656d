"""The node publishes the device diagnostics over DDS (pcv_sim.device.diagnostics builds them)."""


from pcv_sim.device.diagnostics import CONCERNS, OK
from pcv_sim.params import load_params

PARAMS = load_params()
START = 60.0
NAME = '/left/emulator'


def test_the_node_publishes_one_status_per_concern_and_a_quiet_run_is_ok(ros):
    # Thresholds relaxed for this shared test machine: the point is the split and OK when nothing is
    # wrong; the thresholds themselves are checked above on a fake clock.
    ros.start(params={'safe_duty': 0.3, 'watchdog_timeout': 0.0, 'diagnostics_period': 0.2,
                      'diagnostics.late_fraction': 0.5, 'diagnostics.max_lag': 0.5})
    c = ros.client()
    assert c.wait_for_emulator(START)
    c.send_duty(0.5)
    assert c.wait_for_diagnostics(lambda d: d['accepted.duty_cycle'] == '1', 10)
    c.spin_for(0.5)
    last = c.diagnostic_statuses[-1]
    assert set(last) == set(CONCERNS)
    assert {k: level for k, (level, _) in last.items()} == dict.fromkeys(CONCERNS, OK), last
