"""Diagnostics: one status per concern; a quiet run is OK; each cause raises its own status."""
import dataclasses

import pytest

from pcv_sim.device.diagnostics import CONCERNS, ERROR, OK, WARN, DiagnosticsBuilder, Shown
from pcv_sim.device.settings import NodeSettings
from pcv_sim.device.valve import ValveDevice
from pcv_sim.io.recorder import RecorderStatus
from pcv_sim.params import load_params
from pcv_sim.simulation.clock import RealTimeSchedule

PARAMS = load_params()
START = 60.0
NAME = '/left/emulator'


PARAMS = load_params()
START = 60.0
NAME = '/left/emulator'


class Rig:
    """A device, a schedule on a fake clock and the builder, advanced one wake period at a time."""

    def __init__(self, **settings):
        self.settings = NodeSettings(watchdog_timeout=0.05, safe_duty=0.3, **settings)
        self.device = ValveDevice(PARAMS, safe_duty=0.3, watchdog_timeout=0.05)
        self.now = 0.0
        self.schedule = RealTimeSchedule(1e-4, max_catchup=self.settings.catchup_bound, clock=lambda: self.now)
        self.schedule.start(0.0)
        self.builder = DiagnosticsBuilder(NAME, 0.0)
        self.recorder = None

    def run(self, seconds, *, late_by=0.0):
        """Wake every 1 ms for `seconds`; with late_by, each wake comes that much late."""
        end = self.now + seconds
        while self.now < end - 1e-9:
            self.now = round(self.now + 1e-3, 9)
            plan = self.schedule.plan(self.now + late_by)
            self.device.skip(plan.skipped)
            self.device.run(plan.steps)
            self.schedule.finish(self.now + late_by)

    def statuses(self):
        out = self.builder.build(self.now, device=self.device, settings=self.settings, schedule=self.schedule,
                                 recorder=self.recorder, shown=Shown(self.settings.time_mode, 0, 0))
        assert [s.name for s in out] == [f'{NAME}: {c}' for c in CONCERNS]
        assert {s.hardware_id for s in out} == {NAME}
        return {s.name.split(': ')[1]: s for s in out}

    def levels(self):
        return {k: s.level for k, s in self.statuses().items()}


def keep_fed(rig, seconds):
    for _ in range(int(seconds / 0.01)):
        rig.device.submit('duty_cycle', 0.5)
        rig.run(0.01)


def test_a_quiet_run_is_ok_in_every_concern():
    rig = Rig()
    keep_fed(rig, 0.5)
    st = rig.statuses()
    assert {k: s.level for k, s in st.items()} == dict.fromkeys(CONCERNS, OK), {k: s.message for k, s in st.items()}
    assert st['timing'].values['late_steps'] == '0' and st['inputs'].values['watchdog'] == 'ok'


def test_a_few_late_steps_stay_ok_a_late_fraction_above_the_threshold_warns_timing_only():
    rig = Rig()
    keep_fed(rig, 0.5)
    rig.statuses()
    rig.device.submit('duty_cycle', 0.5)
    rig.run(0.002, late_by=0.003)                       # 2 late wakes of 1000 in a 1 s period: 0.2 %
    keep_fed(rig, 0.5)
    assert rig.levels() == dict.fromkeys(CONCERNS, OK)
    rig.run(0.02, late_by=0.003)                         # 20 ms late each wake: 100 % of the period's steps
    st = rig.statuses()
    assert st['timing'].level == WARN and 'steps late' in st['timing'].message
    assert 'samples up to 3.0 ms behind' not in st['timing'].message    # 3 ms < max_lag 10 ms
    assert st['model'].level == OK and st['recording'].level == OK


def test_the_late_steps_of_a_shared_machine_stay_ok_a_struggling_loop_warns():
    """Scattered wakes 1.5 ms late, ~1-3 % of the period's steps late (what a loop shows on a machine
    shared with other jobs, nothing wrong with the node): OK with the defaults. A loop late at a
    fifth of its wakes (sustained, though each stays below max_lag): WARN."""
    rig = Rig()
    keep_fed(rig, 0.5)
    rig.statuses()
    for _ in range(25):                                  # one late wake every 40 ms, for 1 s
        rig.device.submit('duty_cycle', 0.5)
        rig.run(0.001, late_by=0.0015)
        rig.run(0.039)
    st = rig.statuses()['timing']
    assert 0.01 < float(st.values['period_late_fraction']) < 0.03, st.values
    assert st.level == OK, st.message
    for _ in range(200):                                 # every fifth wake late, for 1 s
        rig.device.submit('duty_cycle', 0.5)
        rig.run(0.001, late_by=0.0015)
        rig.run(0.004)
    st = rig.statuses()['timing']
    assert float(st.values['period_late_fraction']) > 0.05, st.values
    assert st.level == WARN and 'steps late' in st.message, st.message


def test_lag_and_skipped_steps_warn_timing():
    rig = Rig(**{'diagnostics_late_fraction': 1.0})
    keep_fed(rig, 0.1)
    rig.statuses()
    rig.run(0.003, late_by=0.02)                         # 20 ms behind, caught up (max_catchup 50 ms)
    st = rig.statuses()['timing']
    assert st.level == WARN and 'ms behind wall time (> 10 ms)' in st.message, st.message
    rig.run(0.001, late_by=0.2)                          # 200 ms: beyond max_catchup -> skipped
    st = rig.statuses()['timing']
    assert st.level == WARN and 'steps skipped' in st.message, st.message


def test_the_watchdog_and_rejected_inputs_warn_inputs_only():
    rig = Rig()
    keep_fed(rig, 0.1)
    rig.statuses()
    rig.run(0.1)                                         # no command for 0.1 s > 0.05 s
    st = rig.statuses()
    assert st['inputs'].level == WARN and 'watchdog' in st['inputs'].message
    assert st['timing'].level == OK and st['model'].level == OK
    rig.device.submit('duty_cycle', 70.0)
    keep_fed(rig, 0.05)
    st = rig.statuses()
    assert st['inputs'].level == WARN and 'rejected inputs: duty_cycle 1' in st['inputs'].message
    keep_fed(rig, 0.05)
    assert rig.levels()['inputs'] == OK                   # counted per period


def test_a_fault_is_error_in_model_only():
    rig = Rig()
    keep_fed(rig, 0.05)
    rig.device.set_fault('injected')
    keep_fed(rig, 0.05)
    st = rig.statuses()
    assert st['model'].level == ERROR and 'model fault: injected' in st['model'].message
    assert st['inputs'].level == OK and st['timing'].level == OK


@pytest.mark.parametrize(('dropped', 'error', 'level'), [(0, '', OK), (5, '', WARN), (0, 'disk full', ERROR)])
def test_recording_problems_raise_the_recording_status(tmp_path, dropped, error, level):
    rig = Rig()
    keep_fed(rig, 0.05)
    rig.recorder = RecorderStatus(state='recording', path=tmp_path, messages=10, bytes=100, files=1, queued=0,
                                  dropped=dropped, error=error)
    st = rig.statuses()
    assert st['recording'].level == level and st['timing'].level == OK and st['model'].level == OK


def test_recorder_status_fields_match():
    # The test above builds RecorderStatus by keyword: keep it in step with the recorder.
    assert {f.name for f in dataclasses.fields(RecorderStatus)} >= {'state', 'path', 'messages', 'bytes', 'files',
                                                                     'queued', 'dropped', 'error'}


def test_a_rig_of_named_valves_gets_the_same_four_concerns_and_one_status_per_valve():
    """One builder over any device: the rig's statuses are the emulator's four concerns (the rig's
    watchdogs, faults and cylinder input summed up in `inputs`) and one per valve with that valve's
    inputs, chamber and last sample; each cause raises the status it belongs to."""
    from pcv_sim.rig import Rig as SteeringRig
    from pcv_sim.rig import load_rig
    from pcv_sim.rig.settings import RigNodeSettings

    dev = SteeringRig(load_rig(None))
    settings = RigNodeSettings(time_mode='simulated')
    builder = DiagnosticsBuilder(NAME, 0.0, {'left': 'a', 'right': 'b'})

    def statuses(now):
        out = builder.build(now, device=dev, settings=settings, schedule=None, recorder=None,
                            shown=Shown('simulated', 7, 1, ('right',)))
        assert {s.hardware_id for s in out} == {NAME}
        return {s.name.split(': ')[1]: s for s in out}

    for v in dev.valve_names:
        assert dev.submit(f'{v}.duty_cycle', 0.6) is None
    dev.run_to(100)
    st = statuses(1.0)
    assert list(st) == [*CONCERNS, 'left', 'right']
    assert {k: s.level for k, s in st.items()} == dict.fromkeys(st, OK), {k: s.message for k, s in st.items()}
    left = st['left'].values
    assert left['chamber'] == 'a' and left['duty_command'] == '0.6' and left['accepted.duty_cycle'] == '1'
    assert left['pressure_pa'] == f"{dev.last_sample.values[dev.signals.index('left.pressure')]:.1f}"
    assert st['timing'].values['waiting_for'] == 'right' and st['model'].values['resets'] == '1'
    assert 'pressure_pa' not in st['model'].values                  # a named valve's sample is its own

    assert dev.submit('cylinder.external_force', 5000.0) is None
    assert dev.submit('cylinder.external_force', float('nan')) is not None
    assert dev.submit_fault('{fault: coil_open, valve: left}') is None
    dev.run_to(200)
    st = statuses(2.0)
    inputs = st['inputs']
    assert inputs.level == WARN and 'coil_open@left' in inputs.message and 'external_force 1' in inputs.message
    assert inputs.values['external_force_n'] == '5000' and inputs.values['rejected.external_force'] == '1'
    assert st['left'].level == WARN and 'coil_open@left' in st['left'].message
    assert st['right'].level == OK and st['model'].level == OK and st['timing'].level == OK
    dev.set_fault('injected')
    assert statuses(3.0)['model'].level == ERROR


def test_timing_names_the_period_s_longest_wake_gap_and_what_filled_it():
    """The loop's wakes (`RealTimeSchedule.note_wake`): the period's longest wake-to-wake gap, its
    cause and parts, and the mean CPU time of a wake; a period without wakes leaves them empty."""
    from pcv_sim.simulation.clock import WakeRecord

    rig = Rig()
    sched = rig.schedule
    for k in range(5):
        start = k * 1e-3 + (0.075 if k == 4 else 0.0)          # the fourth wake: 75 ms off the CPU
        busy = 0.076 if k == 3 else 2e-4
        sched.note_wake(WakeRecord(start, 1e-5, busy - 2e-5, 1e-5, start + busy, 1.5e-4, 2e-5 if k == 1 else 0.0, 10,
                                   0.0))
    timing = rig.statuses()['timing'].values
    assert timing['period_max_wake_gap_ms'] == '76.000' and timing['max_wake_gap_ms'] == '76.000'
    assert timing['period_max_wake_gap_cause'] == 'off_cpu' and timing['period_mean_wake_cpu_ms'] == '0.1500'
    assert timing['period_gc_ms'] == '0.020'
    assert timing['period_max_wake_gap'].startswith('76.00 ms: a wake of 76.00 ms (CPU 0.15 ms; ')
    again = rig.statuses()['timing'].values
    assert (again['period_max_wake_gap_ms'], again['period_max_wake_gap_cause'], again['max_wake_gap_ms'],
            again['period_gc_ms']) == ('', '', '76.000', '0.000')
