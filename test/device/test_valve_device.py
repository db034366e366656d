"""ValveDevice (the emulator: a device of one valve) and the node's parameter handling, without ROS: inputs, watchdog, fault, samples."""
import math
import re

import numpy as np
import pytest
from offline_valve import advance, at_rest, now, put

from pcv_sim.device.settings import (
    NodeSettings,
    check_node_value,
    model_parameters,
    params_with,
    settings_with,
)
from pcv_sim.device.valve import ValveDevice, WatchdogState
from pcv_sim.errors import ParameterError
from pcv_sim.params import load_params, params_to_mapping

PARAMS = load_params()


def device(**kw):
    kw.setdefault('safe_duty', 0.3)
    return ValveDevice(PARAMS, **kw)


# --- inputs ----------------------------------------------------------------------------------

def test_duty_takes_effect_at_the_given_step_like_a_duty_set_at_that_step():
    dev = device(watchdog_timeout=0.0)
    assert dev.submit('duty_cycle', 0.7, at_step=37) is None
    samples = dev.run(200)
    ref = at_rest(PARAMS, 0.3)
    now(ref)                     # the device reads the current at step 0 (as a published sample)
    expected = []
    for k in range(1, 201):
        if k - 1 == 37:
            put(ref, "duty_cycle", 0.7)
        advance(ref, 1)
        if k % 10 == 0:
            expected.append((k, float(ref.sim.x[3]), now(ref).current, float(ref.sim.x[1])))
    got = [(s.step, s.pressure, s.current, s.spool_position) for s in samples]
    assert [g[0] for g in got] == [e[0] for e in expected]
    for g, e in zip(got, expected):
        # Same arithmetic in a different grouping of advance() calls: agreement to rounding.
        assert g[1] == pytest.approx(e[1], rel=1e-12, abs=1e-6)
        assert g[3] == pytest.approx(e[3], rel=1e-12, abs=1e-15)
    assert dev.duty_applied_step == 37
    assert samples[-1].command == 0.7


def test_an_input_for_a_past_step_takes_effect_at_the_first_step_not_yet_shown():
    dev = device()
    dev.run(50)                                 # the sample of step 50 is out: it showed duty 0.3
    dev.submit('duty_cycle', 0.6, at_step=10)
    dev.run(1)
    assert dev.duty_applied_step == 51


def test_a_sample_shows_the_inputs_in_force_at_its_step():
    """Right-continuous: an input due at a sample's step acts on that sample (as replay computes it)."""
    dev = device(watchdog_timeout=0.0)
    dev.submit('duty_cycle', 0.7, at_step=40)
    samples = {s.step: s for s in dev.run(50)}
    assert samples[30].duty == 0.3 and samples[40].duty == 0.7
    ref = at_rest(PARAMS, 0.3)
    advance(ref, 40)
    before = now(ref).current
    put(ref, "duty_cycle", 0.7)
    # The coil current is algebraic in the coil voltage (Eqs. 1-2): it jumps at the step itself.
    assert samples[40].current == pytest.approx(now(ref).current, rel=1e-12)
    assert samples[40].current - before > 0.05


@pytest.mark.parametrize('name, value, match', [
    ('duty_cycle', 70.0, 'fraction 0..1, not percent'),
    ('duty_cycle', math.nan, 'not finite'),
    ('duty_cycle', math.inf, 'not finite'),
    ('duty_cycle', -0.1, 'out of range'),
    ('duty_cycle', 1.5, 'fraction'),
    ('load_flow', math.nan, 'finite number in m\\^3/s'),
    ('load_flow', 5.0, 'not L/min'),
    ('supply_pressure', -1.0, r'supply pressure -1 Pa: accepted is'),
    ('supply_pressure', 200.0e6, r'accepted is 1e\+05 \.\. 4e\+07 Pa \(1 \.\. 400 bar\)$'),
    ('supply_pressure', math.nan, 'supply pressure nan'),
])
def test_bad_inputs_are_refused_counted_and_the_last_valid_value_stays(name, value, match):
    dev, twin = device(watchdog_timeout=0.0), device(watchdog_timeout=0.0)
    for d in (dev, twin):
        d.submit('duty_cycle', 0.5)
        d.run(100)
    reason = dev.submit(name, value)
    assert reason is not None and re.search(match, reason), reason
    assert dev.counts.rejected[name] == 1
    assert dev.counts.last_rejection.startswith(f'{name}: ')
    samples = dev.run(100)                             # the device keeps running ...
    assert len(samples) == 10
    assert dev.command == 0.5 and dev.load_flow == 0.0 and dev.supply_pressure == PARAMS.circuit.supply_pressure
    assert samples == twin.run(100)                    # ... exactly as if the input never came


def test_valid_inputs_are_counted_by_topic():
    dev = device()
    dev.submit('duty_cycle', 0.5)
    dev.submit('load_flow', 1e-5)
    dev.submit('supply_pressure', 150e5)
    dev.run(1)
    assert dev.counts.accepted == {'duty_cycle': 1, 'load_flow': 1, 'supply_pressure': 1, 'faults': 0}
    assert dev.input_values()['supply_pressure'] == 150e5 and dev.load_flow == dev.record_values()['load_flow'] == 1e-5


def test_unknown_input_is_an_error():
    with pytest.raises(ValueError, match='unknown input'):
        device().submit('flow', 1.0)


# --- watchdog --------------------------------------------------------------------------------

def test_watchdog_fires_after_the_timeout_in_model_time_and_resumes():
    dev = device(safe_duty=0.3, watchdog_timeout=0.01)       # 100 steps
    assert dev.watchdog_state == WatchdogState.WAITING
    dev.submit('duty_cycle', 0.7, at_step=5)
    dev.run(104)
    assert dev.watchdog_state == WatchdogState.OK and dev.duties['valve'] == 0.7
    dev.run(1)                                                # step 105 = 5 + 100
    assert dev.watchdog_state == WatchdogState.FIRED
    assert dev.watchdog_fired_step == 105 and dev.watchdog_fired == 1
    assert dev.duties['valve'] == 0.3 and dev.duty_command_in_force == 0.3
    assert dev.command == 0.7                                 # the last command is remembered
    dev.submit('duty_cycle', 0.6)
    dev.run(1)
    assert dev.watchdog_state == WatchdogState.OK and dev.duties['valve'] == 0.6


def test_a_rejected_command_does_not_feed_the_watchdog():
    dev = device(watchdog_timeout=0.01)
    dev.submit('duty_cycle', 0.7)
    for _ in range(20):
        dev.run(10)
        dev.submit('duty_cycle', 70.0)
    assert dev.watchdog_state == WatchdogState.FIRED


def test_watchdog_off_and_runtime_changes():
    dev = device(watchdog_timeout=0.0)
    dev.submit('duty_cycle', 0.7)
    dev.run(100_000)
    assert dev.watchdog_state == WatchdogState.OFF and dev.duties['valve'] == 0.7
    dev.set_watchdog_timeout(0.01)                   # armed from the last command: fires at once
    dev.run(1)
    assert dev.watchdog_state == WatchdogState.FIRED and dev.duties['valve'] == 0.3
    dev.set_safe_duty(0.4)                           # a new safe duty applies while fired
    assert dev.duties['valve'] == 0.4
    dev.set_watchdog_timeout(0.0)                    # switched off: the last command again
    assert dev.duties['valve'] == 0.7
    with pytest.raises(ValueError, match='watchdog_timeout'):
        dev.set_watchdog_timeout(-1.0)


# --- fault -----------------------------------------------------------------------------------

#: A plausible spool mass (bounds 1e-3 .. 1 kg) that the 0.1 ms explicit step cannot integrate at
#: duty 0.7 (m / B = 33 us < dt): the model diverges within ~40 steps; at duty 0.3 the spool sits
#: on its end stop and the model runs.
LIGHT = {'model.spool.mass': 0.01}


def test_a_diverging_model_is_a_fault_until_reset_or_new_parameters():
    dev = ValveDevice(params_with(PARAMS, LIGHT), safe_duty=0.3, watchdog_timeout=0.0)
    dev.submit('duty_cycle', 0.7)
    samples = dev.run(2000)
    assert dev.fault is not None and ('diverged' in dev.fault or 'model step failed' in dev.fault), dev.fault
    limits = dev.physical_limits
    assert all(limits.problem(s.pressure, s.current) is None for s in samples)   # no runaway sample escapes
    steps = dev.steps
    assert dev.run(100) == [] and dev.steps == steps + 100   # time goes on, no samples
    assert math.isfinite(dev.last_good.pressure)
    # reset with the same parameters: the model would fault again at once -> refused, still faulted
    with pytest.raises(ValueError, match=r'the model faults again at once at rest at duty 0\.7'):
        dev.prepare()
    assert dev.fault is not None and dev.run(100) == []
    # good parameters while faulted: the model restarts (as the node's log says), fault cleared
    message = dev.install(dev.prepare(PARAMS))
    assert 'cleared fault' in message and dev.fault is None
    assert len(dev.run(100)) == 10
    assert dev.install(dev.prepare()).startswith('model at rest at duty 0.7')


def test_a_finite_runaway_is_a_fault_before_any_sample_shows_it():
    """load_volume 1e-12 m^3 (refused by the parameter bounds; built here around them) made the
    node publish 4 samples at ~1e282 bar before the state went non-finite. Now the state check
    runs before a sample or recorder call leaves the device."""
    import dataclasses

    tiny = dataclasses.replace(PARAMS, circuit=dataclasses.replace(PARAMS.circuit, load_volume=1e-12))
    recorded = []
    dev = ValveDevice(tiny, safe_duty=0.3, watchdog_timeout=0.0, sample_every=1,
                      recorder=lambda t, sig: recorded.append(dict(sig)))
    dev.submit('duty_cycle', 0.7)
    samples = dev.run(200)
    assert dev.fault is not None, 'the runaway was not declared a fault'
    assert all(-1e5 <= s.pressure <= 800e5 for s in samples), [s.pressure for s in samples]
    assert all(-1e5 <= r['pressure'] <= 800e5 and abs(r['current']) < 5.0 for r in recorded)


def test_a_model_exception_is_a_fault_not_a_crash(monkeypatch):
    dev = device()

    def broken(n):
        raise ArithmeticError('no coil current solves Eq. 2')

    monkeypatch.setattr(dev.sim, 'advance', broken)   # the device's stepping calls
    monkeypatch.setattr(dev.sim, 'advance_sample', lambda n, *args, **kwargs: broken(n))
    assert dev.run(20) == []
    assert dev.fault.startswith('model step failed (ArithmeticError: no coil current solves Eq. 2) before t = 0 s')
    assert dev.steps == 20


def test_injected_fault():
    dev = device()
    dev.set_fault('injected')
    assert dev.run(20) == [] and dev.fault == 'injected'
    assert dev.install(dev.prepare()).endswith('(cleared fault: injected)')


# --- recorder hook ---------------------------------------------------------------------------

def test_recorder_gets_every_nth_step_with_its_stamp():
    got = []
    dev = device(recorder=lambda t_ns, sig: got.append((t_ns, dict(sig))), record_every=1)
    dev.origin_ns = 1_000_000_000
    dev.submit('duty_cycle', 0.5, at_step=3)
    dev.run(25)
    assert [t for t, _ in got] == [1_000_000_000 + k * 100_000 for k in range(1, 26)]
    assert set(got[0][1]) == {'duty_command', 'duty', 'load_flow', 'supply_pressure', 'pressure', 'current',
                              'spool_position'}
    # got[k - 1] is the call for step k: the duty due at step 3 shows from that call on.
    assert got[1][1]['duty_command'] == 0.3 and got[2][1]['duty_command'] == 0.5
    dev.record_every = 10
    got.clear()
    dev.run(30)
    assert len(got) == 3


# --- rest state ------------------------------------------------------------------------------

def test_rest_below_the_equilibrium_range_is_reached_by_settling():
    """Below ~0.3 duty there is no static equilibrium (the spool on its end stop): the rest is settled."""
    dev = device(safe_duty=0.0, watchdog_timeout=0.0)
    p, x = dev.valve_sample().pressure, dev.valve_sample().spool_position
    s = dev.run(1000)[-1]
    assert s.pressure == pytest.approx(p, abs=1.0) and s.spool_position == pytest.approx(x, abs=1e-9)
    assert x == pytest.approx(PARAMS.spool.stroke_min_mm * 1e-3)


def test_parameter_change_restarts_at_the_present_operating_point():
    dev = device(watchdog_timeout=0.0)
    dev.submit('duty_cycle', 0.6)
    dev.run(3000)
    steps = dev.steps
    heavier = params_with(PARAMS, {'model.spool.mass': 0.05})
    dev.install(dev.prepare(heavier))
    assert dev.steps == steps and dev.params.spool.mass == 0.05
    ref = at_rest(heavier, 0.6)
    assert dev.valve_sample().pressure == pytest.approx(float(ref.sim.x[3]))


# --- settings --------------------------------------------------------------------------------

def test_model_parameters_cover_the_scalar_and_vector_keys():
    names = {p.name for p in model_parameters(PARAMS)}
    assert {'model.spool.mass', 'model.orifice.hole_count', 'model.calibration.net_area',
            'model.simulation.integrator', 'model.solenoid.restoring_f1'} <= names
    assert 'model.solenoid.force' not in names                 # matrix: set in the valve YAML
    mapping = params_to_mapping(PARAMS)
    assert len(names) == sum(1 for s in mapping.values() for v in s.values()
                             if not (isinstance(v, list) and v and isinstance(v[0], list)))


@pytest.mark.parametrize('changes, match', [
    ({'model.spool.mass': -1.0}, r'^model\.spool\.mass: got -1\.0; accepted is a plausible value 0\.001 \.\. 1 \(kg\)'),
    ({'model.spool.mass': 'heavy'}, r'model\.spool\.mass'),
    ({'model.orifice.hole_count': 12.5}, r'model\.orifice\.hole_count: .*integer'),
    ({'model.spool.chamber_area': 7e-5}, r'net area'),
    ({'model.spool.mas': 1.0}, r'unknown model parameter'),
    ({'model.simulation.integrator': 'rk45'}, r"one of 'auto', 'euler', 'rk2', 'rk4', 'erk2'"),
        ({'model.simulation.model': 'full', 'model.simulation.integrator': 'rk2'}, r'explicit method diverge'),
])
def test_invalid_model_parameters_are_refused_with_the_reason(changes, match):
    with pytest.raises(ParameterError, match=match):
        params_with(PARAMS, changes)


def test_null_and_array_model_values():
    p = params_with(PARAMS, {'model.calibration.net_area': 'null', 'model.command.duty_range': [0, 1]})
    assert p.calibration.net_area is None and p.command.duty_range == (0.0, 1.0)


def test_time_step_is_fixed_at_runtime():
    with pytest.raises(ParameterError, match='fixed while the node runs'):
        params_with(PARAMS, {'model.simulation.time_step': 5e-5}, runtime=True)
    assert params_with(PARAMS, {'model.simulation.time_step': 5e-5}).simulation.time_step == 5e-5


@pytest.mark.parametrize('name, value, match', [
    ('publish_rate', 0.0, 'publish_rate: .*> 0'),
    ('publish_rate', 'fast', 'publish_rate'),
    ('time_mode', 'wall', "one of 'real', 'simulated'"),
    ('watchdog_timeout', -1.0, 'watchdog_timeout'),
    ('safe_duty', 70.0, 'safe_duty: .*fraction'),
    ('real_time_factor', -2.0, 'real_time_factor'),
    ('lockstep', 1, 'true or false'),
    ('nonsense', 1, 'unknown parameter'),
])
def test_invalid_node_parameters(name, value, match):
    with pytest.raises(ParameterError, match=match):
        check_node_value(name, value)


def test_node_settings_cross_checks():
    ok = NodeSettings()
    assert ok.check(PARAMS) is ok and ok.sample_every(1e-4) == 10
    with pytest.raises(ParameterError, match='not a whole multiple'):
        settings_with(ok, {'publish_rate': 3.0}).check(PARAMS)
    with pytest.raises(ParameterError, match='max_catchup'):
        settings_with(ok, {'max_catchup': 1e-4}).check(PARAMS)
    assert settings_with(ok, {'publish_rate': 1000}).publish_rate == 1000.0


def test_the_options_signals_are_among_the_devices_signals():
    """docs/model.md R33-R35: a valve with its options on gives their inputs and outputs as signals
    (the registry's OPTION_INTERFACE names), the model's values; the paper's valve has none."""
    from pcv_sim.device.valve import OPTION_SIGNALS
    from pcv_sim.io.topics import OPTION_INTERFACE
    from pcv_sim.params import replace_param
    from pcv_sim.units import kelvin

    assert {e.name for e in OPTION_INTERFACE} == set(OPTION_SIGNALS)
    assert not set(OPTION_SIGNALS) & set(device().record_values())
    params = PARAMS
    for key, value in (("solenoid.coil_temperature", "lumped"), ("fluid.temperature", "input"),
                       ("spool.core", "separate")):
        params = replace_param(params, key, value)
    dev = ValveDevice(params, safe_duty=0.9, watchdog_timeout=0.0)
    dev.set_temperature("valve", "oil_temperature", kelvin(50.0))
    dev.advance_to(10_000)                          # 1 s at 90 %: the coil warms
    signals = dev.record_values()
    y = dict(zip(dev.signals, dev.sample(), strict=True))
    assert signals["oil_temperature"] == kelvin(50.0)
    assert signals["ambient_temperature"] == kelvin(params.solenoid.ambient_temperature_c)
    assert signals["coil_temperature"] == y["coil_temperature"] > kelvin(40.0)
    assert signals["coil_resistance"] == y["coil_resistance"] > params.solenoid.coil_resistance
    assert signals["core_position"] == y["core_position"] == y["spool_position"]


# --- faults ----------------------------------------------------------------------------------

def test_a_sensor_fault_changes_what_is_measured_not_the_model():
    dev = device(watchdog_timeout=0.0)
    healthy = device(watchdog_timeout=0.0)
    assert dev.submit_fault('{fault: bias, signal: pressure, value: 1.0e+5}', at_step=5) is None
    assert dev.submit_fault('{fault: dropout, signal: current}', at_step=5) is None
    for a, b in zip(dev.run_to(50), healthy.run_to(50), strict=True):
        assert a.step == b.step and np.array_equal(a.values, b.values)     # the physics is untouched
        p, i, x = dev.measure(a)
        assert p == a.values[0] + 1e5 and math.isnan(i) and x == a.values[2]
    assert set(dev.faults) == {('pressure', 'bias'), ('current', 'dropout')}
    assert dev.counts.accepted['faults'] == 2
    dev.submit_fault('{clear: bias, signal: pressure}')
    s = dev.run_to(dev.steps + 10)[-1]
    assert dev.measure(s)[0] == s.values[0]


def test_a_physical_fault_acts_at_its_step_and_clearing_restores_the_valve():
    dev = device(watchdog_timeout=0.0)
    dev.submit('duty_cycle', 0.7, at_step=1)
    dev.run(3000)
    i0 = dev.valve_sample().current
    assert i0 > 0.3
    assert dev.submit_fault('{fault: coil_open}', at_step=dev.steps + 10) is None   # the one valve: no target
    dev.run(9)
    assert dev.valve_sample().current == pytest.approx(i0, rel=1e-3)     # not yet
    dev.run(3000)
    assert abs(dev.valve_sample().current) < 0.01 * i0                    # no drive: the current decays
    assert dev.faults == {('valve', 'coil_open'): dev.faults[('valve', 'coil_open')]}
    dev.submit_fault('{clear: coil_open, valve: valve}')
    dev.run(5000)
    assert dev.valve_sample().current == pytest.approx(i0, rel=1e-2)


def test_a_supply_fault_holds_over_a_supply_input_and_clearing_restores_the_input():
    dev = device(watchdog_timeout=0.0)
    dev.submit_fault('{fault: supply_drop, pressure: 5.0e+6}')
    dev.run(2)
    assert dev.input_values()['supply_pressure'] == 5e6
    dev.submit('supply_pressure', 150e5)
    dev.run(2)
    assert dev.input_values()['supply_pressure'] == 5e6 and dev.supply_pressure == 150e5
    dev.submit_fault('{clear: supply_drop}')
    dev.run(2)
    assert dev.input_values()['supply_pressure'] == 150e5


@pytest.mark.parametrize('text, match', [
    ('{fault: nosuch}', "kind 'nosuch'"),
    ('{fault: bias, signal: flow, value: 1.0}', "target 'flow' for bias; accepted are pressure, current, spool_position"),
    ('{fault: coil_open, valve: left}', "target 'left' for coil_open; accepted are valve"),
    ('{fault: cylinder_jam, target: cylinder}', 'cylinder_jam: this device has no cylinder; accepted are supply_drop'),
    ('not: [yaml', 'not YAML'),
])
def test_bad_fault_commands_are_refused_with_what_is_accepted_and_counted(text, match):
    dev = device()
    reason = dev.submit_fault(text)
    assert reason is not None and match in reason, reason
    assert dev.counts.rejected['faults'] == 1 and match in dev.counts.last_rejection
    assert not dev.faults


def test_clearing_a_fault_that_is_not_active_is_refused_when_due_and_a_reset_clears_all():
    dev = device()
    assert dev.submit_fault('{clear: coil_open}') is None
    dev.run(2)
    assert dev.counts.rejected['faults'] == 1 and 'no active fault coil_open on valve' in dev.counts.last_rejection
    dev.submit_fault('{fault: noise, signal: pressure, std: 1000.0}')
    dev.submit_fault('{fault: coil_short, resistance_factor: 0.5}')
    dev.run(2)
    assert len(dev.faults) == 2
    dev.reset()
    assert not dev.faults and not dev.sensors.active
    s = dev.run_to(dev.steps + 10)[-1]
    assert np.array_equal(dev.measure(s), s.values)


def test_inputs_taken_between_prepare_and_install_act_on_the_new_model():
    """`prepare` runs off the loop while inputs keep coming: those in force at `install` stay."""
    dev = device(watchdog_timeout=0.0)
    dev.submit('duty_cycle', 0.6)
    dev.run(100)
    prepared = dev.prepare(params_with(PARAMS, {'model.spool.mass': 0.05}))
    dev.submit('load_flow', 2e-6)
    dev.submit('supply_pressure', 150e5)
    dev.submit('duty_cycle', 0.7)
    dev.run(10)
    dev.install(prepared)
    assert dev.load_flow == dev.record_values()['load_flow'] == 2e-6
    assert dev.input_values() == {'duty_cycle': 0.7, 'supply_pressure': 150e5}
    assert dev.params.spool.mass == 0.05 and dev.fault is None
