"""The one device interface (pcv_sim.device.device.Device) on both devices: the emulator's valve
and the rig (valves on a cylinder) take inputs, fault commands, watchdog settings the same way."""
import numpy as np
import pytest

from pcv_sim.device.inputs import WatchdogState
from pcv_sim.device.valve import ValveDevice
from pcv_sim.errors import CommandError
from pcv_sim.params import load_params
from pcv_sim.rig import Rig, load_rig
from pcv_sim.rig.rig import EXTERNAL_FORCE


@pytest.fixture(scope="module")
def _shared_rig():
    return Rig(load_rig())


@pytest.fixture
def rig(_shared_rig):
    _shared_rig.on_input = None
    _shared_rig.reset()
    return _shared_rig


def _valve():
    return ValveDevice(load_params(), safe_duty=0.3, watchdog_timeout=0.01)


def _advance(dev, step):
    """Run the device to `step`: the rig's advance_to, the valve's run."""
    if isinstance(dev, Rig):
        dev.advance_to(step)
    else:
        dev.run(step - dev.steps)


@pytest.fixture(params=["valve", "rig"])
def dev(request):
    return _valve() if request.param == "valve" else request.getfixturevalue("rig")


def _duty_input(dev):
    return "duty_cycle" if isinstance(dev, ValveDevice) else f"{dev.valve_names[0]}.duty_cycle"


# --- inputs ----------------------------------------------------------------------------------

def test_an_input_acts_from_its_step_and_is_counted(dev):
    name, valve = _duty_input(dev), dev.valve_names[0]
    assert dev.submit(name, 0.6, at_step=20) is None
    _advance(dev, 19)
    assert dev.commands[valve] != 0.6 and dev.counts.accepted[name] == 0
    _advance(dev, 20)
    assert dev.commands[valve] == dev.duties[valve] == 0.6 and dev.counts.accepted[name] == 1
    assert dev.watchdogs[valve].state == WatchdogState.OK and dev.watchdogs[valve].command_step == 20


def test_a_bad_input_is_refused_with_its_reason_counted_and_the_last_value_stays(dev):
    name, valve = _duty_input(dev), dev.valve_names[0]
    before = dev.commands[valve]
    reason = dev.submit(name, 70.0)
    assert reason is not None and "fraction" in reason
    assert dev.counts.rejected[name] == 1 and dev.counts.last_rejection == f"{name}: {reason}"
    _advance(dev, dev.steps + 5)
    assert dev.commands[valve] == before and dev.counts.accepted[name] == 0


def test_an_unknown_input_names_the_accepted_ones(dev):
    with pytest.raises(ValueError, match=f"unknown input 'nosuch'; accepted are {_duty_input(dev)}"):
        dev.submit("nosuch", 1.0)


def test_the_rig_takes_the_external_force_as_an_input(rig):
    assert rig.submit(EXTERNAL_FORCE, 1.0e7) is not None          # beyond any steering load
    assert rig.submit(EXTERNAL_FORCE, 500.0, at_step=3) is None
    rig.advance_to(3)
    assert rig.input_values()[EXTERNAL_FORCE] == 500.0
    assert rig.counts.accepted[EXTERNAL_FORCE] == 1 and rig.counts.rejected[EXTERNAL_FORCE] == 1


def test_a_submitted_duty_gives_the_same_numbers_as_set_duty_at_that_step(rig):
    rig.submit("left.duty_cycle", 0.7, at_step=50)
    rig.advance_to(200)
    submitted = rig.sample()
    rig.reset()
    rig.advance_to(50)
    rig.set_duty("left", 0.7)
    rig.advance_to(200)
    assert np.array_equal(submitted, rig.sample())


# --- watchdogs -------------------------------------------------------------------------------

def test_a_watchdog_waits_for_a_first_command_then_fires_and_a_command_resumes(dev):
    valve = dev.valve_names[0]
    dev.set_watchdog_timeout(0.01)              # 100 steps
    waiting = dev.duties[valve]
    _advance(dev, 500)
    assert dev.watchdogs[valve].state == WatchdogState.WAITING and dev.duties[valve] == waiting
    dev.submit(_duty_input(dev), 0.6, at_step=501)
    _advance(dev, 600)
    assert dev.duties[valve] == 0.6
    _advance(dev, 601)
    assert dev.watchdogs[valve].state == WatchdogState.FIRED and dev.duties[valve] == dev.safe_duty
    assert any(f"{valve}: watchdog fired" in text for _, text in dev.log)
    dev.submit(_duty_input(dev), 0.55, at_step=650)
    _advance(dev, 650)
    assert dev.watchdogs[valve].state == WatchdogState.OK and dev.duties[valve] == 0.55


def test_watchdog_settings_change_at_run_time_on_every_device(dev):
    valve = dev.valve_names[0]
    dev.set_watchdog_timeout(0.01)
    dev.submit(_duty_input(dev), 0.6, at_step=1)
    _advance(dev, 101)
    assert dev.duties[valve] == dev.safe_duty
    dev.set_safe_duty(0.1)
    assert dev.safe_duty == dev.duties[valve] == dev.duty_held(valve) == 0.1
    dev.set_watchdog_timeout(0.0)               # off: the controller's command is back at once
    assert dev.duties[valve] == 0.6 and dev.watchdogs[valve].state == WatchdogState.OFF
    for bad in (-1.0, 61.0, float("nan"), True):     # the one declaration's range (every device's, every node's)
        with pytest.raises(ValueError, match=r"watchdog_timeout: got .*; accepted is a"):
            dev.set_watchdog_timeout(bad)
    assert dev.watchdogs[valve].state == WatchdogState.OFF      # a refusal changes nothing
    with pytest.raises(CommandError):
        dev.set_safe_duty(1.5)
    assert dev.safe_duty == 0.1


# --- fault commands ----------------------------------------------------------------------------

def test_a_fault_command_acts_at_its_step_and_clearing_one_not_active_is_refused_when_due(dev):
    valve = dev.valve_names[0]
    target = "" if isinstance(dev, ValveDevice) else f", valve: {valve}"
    assert dev.submit_fault(f"{{fault: coil_open{target}}}", at_step=10) is None
    _advance(dev, 9)
    assert (valve, "coil_open") not in dev.faults
    _advance(dev, 10)
    assert (valve, "coil_open") in dev.faults and dev.counts.accepted["faults"] == 1
    dev.submit_fault(f"{{clear: coil_open{target}}}", at_step=20)
    dev.submit_fault(f"{{clear: coil_open{target}}}", at_step=21)
    _advance(dev, 21)
    assert not dev.faults and dev.counts.accepted["faults"] == 2 and dev.counts.rejected["faults"] == 1
    assert f"no active fault coil_open on {valve}" in dev.counts.last_rejection


def test_cylinder_faults_only_on_a_device_with_a_cylinder(rig):
    valve = _valve()
    reason = valve.submit_fault("{fault: cylinder_jam, target: cylinder}")
    assert reason is not None and "this device has no cylinder" in reason
    assert rig.submit_fault("{fault: cylinder_jam, target: cylinder}", at_step=5) is None
    rig.advance_to(5)
    assert ("cylinder", "cylinder_jam") in rig.faults


def test_a_sensor_fault_names_the_devices_signals(dev):
    reason = dev.submit_fault("{fault: freeze, signal: nosuch}")
    assert reason is not None and all(s in reason for s in dev.sensors.signals)
    assert dev.submit_fault(f"{{fault: freeze, signal: {dev.sensors.signals[0]}}}") is None


def test_an_input_acts_from_the_first_step_not_shown(rig):
    """The emulator has shown its present step (its `run` made the sample): an input acts from the
    next; the rig's caller takes the samples, so an input without a step acts from the present
    one, as `set_duty` does."""
    valve = _valve()
    valve.run(10)
    valve.submit("duty_cycle", 0.6, at_step=3)
    valve.run(1)
    assert valve.duty_applied_step == 11
    rig.advance_to(10)
    rig.submit("left.duty_cycle", 0.6)
    rig.advance_to(10)
    assert rig.watchdogs["left"].command_step == 10 and rig.duties["left"] == 0.6


# --- the node-facing interface: stepping, samples, restarts, status -----------------------------

def _fresh(dev):
    """A device of `dev`'s kind at its start (the rig: `dev` itself, reset)."""
    if isinstance(dev, Rig):
        dev.reset()
        return dev
    return _valve()


def _reference(dev, step):
    """The sample at `step` by each device's own stepping call (the rig's advance_to + sample, the
    valve's run)."""
    if isinstance(dev, Rig):
        dev.advance_to(step)
        return dev.sample()
    s = dev.run(step - dev.steps)[-1]
    return np.array((s.pressure, s.current, s.spool_position, *s.options))


def test_run_to_hands_back_the_samples_due_in_the_order_of_signals(dev):
    per = dev.sample_every
    assert dev.submit(_duty_input(dev), 0.6, at_step=per // 2) is None
    samples = dev.run_to(3 * per + per // 2)
    assert [s.step for s in samples] == [per, 2 * per, 3 * per] and dev.steps == 3 * per + per // 2
    assert all(len(s.values) == len(dev.signals) for s in samples)
    assert dev.run_to(dev.steps) == [] and dev.shown == 3 * per and dev.last_sample is samples[-1]
    last = samples[-1]
    ref = _fresh(dev)
    ref.submit(_duty_input(ref), 0.6, at_step=per // 2)        # the same inputs on a fresh device
    assert np.array_equal(_reference(ref, 3 * per), last.values)
    pressure = next(s for s in dev.signals if s.endswith("pressure"))
    assert last.values[dev.signals.index(pressure)] > 1e5       # Pa: the valve at 0.6 holds some bar


def test_an_input_taken_now_acts_after_the_last_sample_shown(dev):
    dev.run_to(2 * dev.sample_every + 3)
    shown = dev.present_sample()
    assert shown.step == dev.steps and dev.first_open_step() == dev.steps + 1
    dev.submit(_duty_input(dev), 0.6)
    dev.run_to(dev.steps + 1)
    assert dev.watchdogs[dev.valve_names[0]].command_step == shown.step + 1


def test_measure_shows_the_sensor_faults_and_leaves_the_true_sample(dev):
    first = dev.sensors.signals[0]
    assert dev.submit_fault(f"{{fault: bias, signal: {first}, value: 2.0}}", at_step=1) is None
    s = dev.run_to(dev.sample_every)[-1]
    before = s.values.copy()
    measured = dev.measure(s)
    j = dev.signals.index(first)
    assert measured[j] == before[j] + 2.0 and np.array_equal(s.values, before)
    others = [k for k in range(len(before)) if k != j]
    assert np.array_equal(measured[others], before[others])


def test_a_model_that_runs_away_sets_the_fault_and_run_to_hands_back_nothing_after_it(dev):
    dev.run_to(dev.sample_every)
    dev.sim.x[0] = np.nan
    assert dev.run_to(5 * dev.sample_every) == []                 # no exception: the fault state
    assert dev.fault is not None and dev.steps == 5 * dev.sample_every
    dev.submit(_duty_input(dev), 0.6, at_step=dev.steps + 2)       # inputs still act at their steps
    assert dev.run_to(7 * dev.sample_every) == []
    assert dev.commands[dev.valve_names[0]] == 0.6
    what = dev.install(dev.prepare())
    assert dev.fault is None and "cleared fault" in what and dev.steps == 7 * dev.sample_every
    assert [s.step for s in dev.run_to(8 * dev.sample_every)] == [8 * dev.sample_every]


def test_new_valve_parameters_at_run_time_restart_the_rig_as_a_fresh_one(rig):
    """The rig restarts at its start (initial duties, piston at rest at its initial position) with
    the new parameters, model time going on: from there the same numbers as a rig built with them."""
    heavier = load_rig(valve_changes={"left": {("spool", "mass"): 0.05}})
    rig.submit("left.duty_cycle", 0.7, at_step=1)
    rig.run_to(500)
    original = rig.params
    rig.install(rig.prepare(heavier))
    try:
        _same_as_a_fresh_rig(rig, heavier)
    finally:
        rig.install(rig.prepare(original))          # the module's rig, as the other tests know it
    assert rig.valve_specs[0].params.spool.mass == original.valves[0].params.spool.mass


def _same_as_a_fresh_rig(rig, heavier):
    import dataclasses

    from pcv_sim.errors import ParameterError

    assert rig.steps == 500 and rig.params is heavier and rig.valve_specs[0].params.spool.mass == 0.05
    fresh = Rig(heavier)
    for dev in (rig, fresh):
        dev.submit("right.duty_cycle", 0.6, at_step=dev.steps + 3)
    got = rig.run_to(rig.steps + 300)
    want = fresh.run_to(300)
    assert [s.step - 500 for s in got] == [s.step for s in want]
    assert all(np.array_equal(a.values, b.values) for a, b in zip(got, want, strict=True))
    bigger = dataclasses.replace(heavier, cylinder=dataclasses.replace(heavier.cylinder, mass=2 * heavier.cylinder.mass))
    with pytest.raises(ParameterError, match="only its valves' parameters may change"):
        rig.prepare(bigger)


def test_status_is_the_same_view_on_every_device(dev):
    valve, name = dev.valve_names[0], _duty_input(dev)
    dev.set_watchdog_timeout(0.01)
    dev.submit(name, 0.6, at_step=1)
    dev.submit(name, 7.0)
    dev.submit_fault(f"{{fault: bias, signal: {dev.sensors.signals[0]}, value: 1.0}}", at_step=1)
    dev.run_to(200)
    st = dev.status()
    assert st.time == pytest.approx(200 * dev.dt) and st.commands[valve] == 0.6 and st.duties[valve] == dev.safe_duty
    assert st.watchdogs[valve] == WatchdogState.FIRED and st.watchdog_fired[valve] >= 1
    assert st.faults == (f"bias@{dev.sensors.signals[0]}",) and st.fault is None
    assert st.accepted[name] == 1 and st.rejected[name] == 1 and st.last_rejection.startswith(name)
    assert name in dev.input_names and "faults" not in dev.input_names


# --- what only one device had, every device has -------------------------------------------------

def _diverging(dev_kind):
    """A device whose first valve (spool mass 0.01 kg: m / B = 33 us < dt) diverges at duty 0.7."""
    if dev_kind == "valve":
        from pcv_sim.params import replace_param

        return ValveDevice(replace_param(load_params(), "spool.mass", 0.01), safe_duty=0.3, watchdog_timeout=0.0)
    return Rig(load_rig(valve_changes={"left": {("spool", "mass"): 0.01}}))


@pytest.mark.parametrize("kind", ["valve", "rig"])
def test_no_sample_a_valve_cannot_show_leaves_any_device(kind):
    dev = _diverging(kind)
    dev.submit(_duty_input(dev), 0.7)
    samples = dev.run_to(2000)
    assert dev.fault is not None and ("diverged" in dev.fault or "non-finite" in dev.fault
                                      or "model step failed" in dev.fault), dev.fault
    valve = dev.valve_names[0]
    limits = dev.limits[valve]
    jp, ji = (dev.signals.index(f"{'' if kind == 'valve' else valve + '.'}{s}") for s in ("pressure", "current"))
    assert samples and all(limits.problem(s.values[jp], s.values[ji]) is None for s in samples)
    assert dev.run_to(2100) == [] and dev.steps == 2100


class _Blocks:
    """A recorder that takes stretches of steps (`record_block`) and single steps (`__call__`)."""

    def __init__(self):
        self.steps = []
        self.rows = []

    def __call__(self, t_ns, values):
        self.steps.append(t_ns)

    def record_block(self, t0_ns, dt_ns, rows):
        self.steps += [t0_ns + k * dt_ns for k in range(len(rows))]
        self.rows.append(rows)


def test_a_recorder_of_every_step_gets_traced_blocks_on_every_device(dev):
    rec = _Blocks()
    dev.recorder, dev.record_every = rec, 1
    dev.origin_ns = 7_000
    dev.submit(_duty_input(dev), 0.6, at_step=25)
    samples = dev.run_to(100)
    assert rec.steps == [dev.stamp_ns(k) for k in range(1, 101)]          # every step once, in order
    assert rec.rows and all(r.shape[1] == len(dev.signals) for r in rec.rows)
    assert len(samples) == 100 // dev.sample_every
    dev.recorder = None


@pytest.mark.parametrize("kind", ["valve", "rig"])
def test_the_fall_rate_limiter_acts_on_every_device(kind, tmp_path):
    """Sec. 3.2: the duty a limited valve's model gets falls at most `duty_fall_rate_limit` per s."""
    from pcv_sim.params import replace_param

    params = replace_param(load_params(), "command.duty_fall_rate_limit", 2.0)
    if kind == "valve":
        dev = ValveDevice(params, safe_duty=0.3, watchdog_timeout=0.0)
        slot = "duty_cycle"
    else:
        dev = Rig(load_rig(valve_changes={"left": {("command", "duty_fall_rate_limit"): 2.0}}))
        slot = "left.duty_cycle"
    dev.submit(_duty_input(dev), 0.9, at_step=1)
    dev.run_to(100)
    assert dev.input_values()[slot] == 0.9                 # a rise passes at once
    dev.submit(_duty_input(dev), 0.4, at_step=101)
    dev.run_to(101)
    assert dev.input_values()[slot] == pytest.approx(0.9 - 2.0 * dev.dt)
    dev.run_to(1101)
    assert dev.input_values()[slot] == pytest.approx(0.9 - 2.0 * 1001 * dev.dt)
    assert dev.duties[dev.valve_names[0]] == 0.4           # the duty in force: the command
    dev.run_to(4000)
    assert dev.input_values()[slot] == 0.4
