"""A device's offline run (replay's): the start at rest at given inputs (`ValveDevice.start_at_rest`),
a fed duty (`feed`), and the signals at given steps (`sample_at`), against the device's own
stepping (`run_to`) with the same inputs submitted at the same steps."""
import numpy as np
import pytest

from pcv_sim.device.spec import ModelFault
from pcv_sim.device.valve import ValveDevice, WatchdogState
from pcv_sim.errors import CommandError
from pcv_sim.params import load_params, replace_param
from pcv_sim.simulation.rest import rest_state

PARAMS = load_params()
#: A timeline of changes: (step, duty, load flow m^3/s); a step at 0 and one per 0.1 ms step apart.
TIMELINE = [(0, 0.5, 0.0), (37, 0.7, 0.0), (38, 0.72, 0.0), (120, 0.72, 2e-6), (300, 0.45, 2e-6), (301, 0.44, 0.0)]


def _submitted(params=PARAMS, timeout=0.0, timeline=TIMELINE):
    """run_to's samples of every step 0 .. 500 with the timeline's inputs submitted at their steps."""
    dev = ValveDevice(params, safe_duty=0.5, watchdog_timeout=timeout, sample_every=1)
    for k, duty, flow in timeline:
        dev.submit('duty_cycle', duty, k)
        dev.submit('load_flow', flow, k)
    first = dev.present_sample().values     # the inputs due at step 0 act before it
    rows = np.array([first, *(s.values for s in dev.run_to(500))])
    return dev, rows


def _fed(params=PARAMS, timeout=0.0, timeline=TIMELINE, steps=range(501)):
    dev = ValveDevice(params, safe_duty=0.5, watchdog_timeout=timeout)
    k, duty, flow = (np.array(c) for c in zip(*timeline))
    dev.feed('duty_cycle', k, duty)
    dev.feed('load_flow', k, flow)
    return dev, dev.sample_at(np.array(list(steps)))


def test_a_fed_timeline_sampled_at_steps_is_run_tos_bit_for_bit():
    """One compiled call for the whole timeline: the same numbers as the device's own stepping,
    samples at the steps of a change showing it (right-continuous)."""
    ref_dev, ref = _submitted()
    dev, got = _fed()
    assert np.array_equal(got, ref)
    assert dev.steps == 500 and dev.commands == ref_dev.commands and dev.load_flow == ref_dev.load_flow == 0.0
    assert dev.duty_applied_step == ref_dev.duty_applied_step == 301
    assert got[37, 1] != got[36, 1]             # the coil current jumps with the duty at its step


def test_samples_at_some_steps_are_those_of_every_step():
    _, every = _fed()
    some = [0, 36, 37, 120, 121, 299, 300, 301, 499]
    dev, got = _fed(steps=some)
    assert np.array_equal(got, every[some])
    assert dev.steps == 499


def test_a_fed_duty_is_a_command_the_watchdog_hears():
    """Commands 60 steps apart, the watchdog at 5 ms (50 steps): it fires between them and each
    command clears it, as with submitted commands."""
    timeline = [(0, 0.5, 0.0), (100, 0.7, 0.0), (160, 0.6, 0.0), (240, 0.8, 0.0)]
    ref_dev, ref = _submitted(timeout=0.005, timeline=timeline)
    dev, got = _fed(timeout=0.005, timeline=timeline)
    assert np.array_equal(got, ref)
    assert dev.watchdog_fired == ref_dev.watchdog_fired == 4
    assert dev.log == ref_dev.log
    assert dev.watchdog_state == WatchdogState.FIRED


def test_a_limited_duty_is_submitted_and_ramps_as_run_to_steps_it():
    limited = replace_param(PARAMS, 'command.duty_fall_rate_limit', 20.0)
    dev = ValveDevice(limited, safe_duty=0.5, watchdog_timeout=0.0)
    with pytest.raises(CommandError, match="feed 'duty_cycle': accepted is load_flow"):
        dev.feed('duty_cycle', [10], [0.4])
    ref_dev, ref = _submitted(limited)
    for k, duty, _ in TIMELINE:
        dev.submit('duty_cycle', duty, k)
    dev.feed('load_flow', [k for k, _, _ in TIMELINE], [f for _, _, f in TIMELINE])
    got = dev.sample_at(np.arange(501))
    assert np.array_equal(got, ref)
    assert dev.record_values() == ref_dev.record_values()
    sparse = ValveDevice(limited, safe_duty=0.5, watchdog_timeout=0.0)   # stretches without a sample
    for k, duty, _ in TIMELINE:
        sparse.submit('duty_cycle', duty, k)
    sparse.feed('load_flow', [k for k, _, _ in TIMELINE], [f for _, _, f in TIMELINE])
    assert np.array_equal(sparse.sample_at([0, 500]), ref[[0, 500]])


def test_the_start_at_rest_at_given_inputs():
    dev = ValveDevice(PARAMS, safe_duty=0.3, watchdog_timeout=0.0)
    dev.submit('duty_cycle', 0.9, 5)
    dev.run_to(40)
    dev.start_at_rest(0.6, 3e-6, 1.5e7)
    rest = rest_state(PARAMS, 'simplified', 0.6, 3e-6, 1.5e7, integrator=dev.sim.integrator)
    assert dev.steps == 0 and np.array_equal(dev.sim.x, rest.state)
    assert (dev.command, dev.load_flow, dev.supply_pressure) == (0.6, 3e-6, 1.5e7)
    assert dev.watchdog_state == WatchdogState.OFF and dev.duty_applied_step == 0
    rows = dev.sample_at(np.arange(0, 1001, 100))       # at rest: it stays there
    assert np.ptp(rows[:, 0]) < 1.0 and np.ptp(rows[:, 2]) < 1e-9
    assert rows[0, 0] == pytest.approx(rest.state[3], abs=1e-9)


def test_the_start_at_rest_refuses_what_submit_refuses_and_changes_nothing():
    dev = ValveDevice(PARAMS, safe_duty=0.3, watchdog_timeout=0.0)
    dev.run_to(20)
    x = dev.sim.x.copy()
    with pytest.raises(CommandError, match="supply pressure 200 Pa"):
        dev.start_at_rest(0.6, 0.0, 200.0)
    with pytest.raises(CommandError, match="out of range"):
        dev.start_at_rest(1.2)
    assert dev.steps == 20 and np.array_equal(dev.sim.x, x)


def test_sample_at_refuses_steps_it_cannot_show():
    dev = ValveDevice(PARAMS, safe_duty=0.5, watchdog_timeout=0.0)
    dev.run_to(10)
    for steps in ([5, 20], [20, 20], [30, 20]):
        with pytest.raises(ValueError, match=r"increasing from the present one \(10\) on"):
            dev.sample_at(steps)
    dev.set_fault("the model state ran away (non-finite)")
    with pytest.raises(ModelFault, match="ran away"):
        dev.sample_at([20])
