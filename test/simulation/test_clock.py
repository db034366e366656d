"""RealTimeSchedule / SimulatedSchedule with an injected fake clock: no ROS, no wall-clock timing."""
import math

import pytest

from pcv_sim.simulation.clock import RealTimeSchedule, SimulatedSchedule, steps_per

DT = 1e-4
P = 1e-3


class FakeClock:
    def __init__(self, t=100.0):
        self.t = t

    def __call__(self):
        return self.t


def schedule(**kw):
    clock = FakeClock()
    s = RealTimeSchedule(DT, clock=clock, **kw)
    s.start()
    return s, clock


def test_steps_due_follow_wall_time_and_never_run_ahead():
    s, clock = schedule()
    assert s.plan().steps == 0                      # nothing has ended at t0
    clock.t += 0.00099                              # 9.9 steps of wall time: 9 have ended
    p = s.plan()
    assert (p.first, p.steps, p.late, p.skipped) == (0, 9, 0, 0)
    clock.t = s.t0 + 0.001                          # exactly on a boundary: step 9 is due
    assert s.plan().steps == 1
    assert s.model_time == pytest.approx(0.001)


def test_model_time_does_not_drift_over_a_million_wakes():
    s, clock = schedule()
    for m in range(1, 1_000_001):
        clock.t = s.t0 + m * P + 3e-5               # every wake 30 us late (OS wake-up latency)
        s.plan()
    assert s.slot == 10_000_000                     # 1000 s of model time = 1e7 steps exactly
    assert s.late_steps == 0 and s.skipped_steps == 0
    assert s.model_time == pytest.approx(1000.0, abs=1e-9)


def test_next_wake_is_the_grid_point_after_now():
    s, clock = schedule()
    assert s.next_wake() == pytest.approx(s.t0 + P)
    clock.t = s.t0 + 0.00105                        # woke late: the next wake stays on the grid
    assert s.next_wake() == pytest.approx(s.t0 + 2 * P)
    clock.t = s.t0 + 0.0037                         # a long batch: skip the missed grid points
    assert s.next_wake() == pytest.approx(s.t0 + 4 * P)


def test_on_time_wakes_have_no_late_steps_even_with_jitter_below_the_threshold():
    s, clock = schedule(late_threshold=1e-3)
    for m in range(1, 101):
        clock.t = s.t0 + m * P + 0.0009              # 0.9 ms late, threshold 1 ms
        assert s.plan().late == 0
    assert s.late_steps == 0


def test_a_late_wake_counts_exactly_the_steps_scheduled_before_now_minus_threshold():
    s, clock = schedule(late_threshold=1e-3)
    clock.t = s.t0 + P
    assert s.plan().steps == 10
    # The next wakes (2, 3, 4 ms) are missed; the loop comes back at 4.25 ms.
    clock.t = s.t0 + 0.00425
    p = s.plan()
    assert p.first == 10 and p.steps == 32        # steps 10..41 have ended by 4.25 ms
    # Steps 10-19 were scheduled for the 2 ms wake, 20-29 for 3 ms: both > 1 ms before 4.25 ms.
    # Steps 30-39 (4 ms wake) and 40, 41 (5 ms wake) are within the threshold.
    assert p.late == 20
    assert p.lag == pytest.approx(0.00325)
    assert s.late_steps == 20 and s.max_lag == pytest.approx(0.00325)


def test_late_steps_are_counted_once():
    s, clock = schedule(late_threshold=0.5e-3)
    clock.t = s.t0 + 0.0031                         # first wake 2.1 ms late
    first = s.plan()
    assert first.late == 20                         # steps scheduled for 1 ms and 2 ms
    clock.t = s.t0 + 0.0041
    assert s.plan().late == 0                       # back on time: the next 10 steps are not late
    assert s.late_steps == 20


def test_zero_threshold_counts_every_step_of_a_late_wake():
    s, clock = schedule(late_threshold=0.0)
    clock.t = s.t0 + P + 1e-6
    assert s.plan().late == 10


def test_far_behind_skips_all_but_the_latest_wake_period():
    s, clock = schedule(max_catchup=0.05)
    clock.t = s.t0 + P
    s.plan()
    clock.t = s.t0 + 0.2005                         # stopped for ~200 ms
    p = s.plan()
    assert p.skipped + p.steps == 2005 - 10
    assert p.steps == 10                            # one wake period computed, the rest skipped
    assert p.first == 10
    assert s.skipped_steps == p.skipped == 1985 and s.skips == 1
    assert p.late == 0                              # the computed ones are the newest, scheduled now
    assert s.slot == 2005                           # model time jumps to wall time: no drift
    assert s.model_time == pytest.approx(0.2005)


def test_backlog_within_max_catchup_is_caught_up_and_counted_late():
    s, clock = schedule(max_catchup=0.05)
    clock.t = s.t0 + 0.0405                         # 40 ms stall: caught up in one batch
    p = s.plan()
    assert p.skipped == 0 and p.steps == 405
    assert p.late == 390                            # all scheduled for wakes <= 39 ms


def test_lag_after_a_batch_is_recorded():
    s, clock = schedule()
    clock.t = s.t0 + 0.00105
    s.plan()
    clock.t += 0.0002                               # the batch took 0.2 ms
    assert s.finish() == pytest.approx(0.00025)
    assert s.max_lag_after == pytest.approx(0.00025)
    assert s.take_period_max() == pytest.approx((0.00105, 0.00025))
    assert s.take_period_max() == (0.0, 0.0)            # a new period


def test_plan_before_start_is_an_error():
    with pytest.raises(RuntimeError, match='before start'):
        RealTimeSchedule(DT).plan(0.0)


@pytest.mark.parametrize('kw, match', [
    (dict(wake_period=0.00025), 'not a whole multiple'),
    (dict(wake_period=0.0), 'wake_period'),
    (dict(late_threshold=-1.0), 'late_threshold'),
    (dict(max_catchup=1e-4), 'max_catchup'),
])
def test_invalid_schedule_settings_are_refused(kw, match):
    with pytest.raises(ValueError, match=match):
        RealTimeSchedule(DT, **kw)


def test_steps_per():
    assert steps_per(1e-3, 1e-4) == 10
    assert steps_per(1 / 1000, 1e-4) == 10
    with pytest.raises(ValueError, match='not a whole multiple'):
        steps_per(1 / 3, 1e-4)
    with pytest.raises(ValueError, match='> 0'):
        steps_per(math.inf, 1e-4)


# --- simulated time ------------------------------------------------------------------------------

def test_simulated_free_running_is_always_ready():
    for factor in (0.0, math.inf):
        sim = SimulatedSchedule(DT, factor=factor, clock=FakeClock())
        sim.start()
        assert sim.free and sim.ready_at(10) == -math.inf


def test_simulated_pacing_at_a_real_time_factor():
    clock = FakeClock(5.0)
    sim = SimulatedSchedule(DT, factor=2.0, clock=clock)
    sim.start()
    # A 1 ms chunk at factor 2 is due when 0.5 ms of wall time has passed.
    assert sim.ready_at(10) == pytest.approx(5.0005)
    sim.advance(10)
    assert sim.ready_at(10) == pytest.approx(5.001)
    assert sim.model_time == pytest.approx(1e-3)
    clock.t = 7.0
    sim.set_factor(0.5)                             # re-anchored: no burst to catch up
    assert sim.ready_at(10) == pytest.approx(7.002)


def test_simulated_factor_is_validated():
    with pytest.raises(ValueError, match='real_time_factor'):
        SimulatedSchedule(DT, factor=-1.0)
    with pytest.raises(ValueError, match='real_time_factor'):
        SimulatedSchedule(DT, factor=math.nan)


def test_external_clock_is_followed_reanchored_when_it_goes_back_and_held_over_a_long_jump():
    """use_sim_time, the emulator's and the rig node's: one rule (pcv_sim.simulation.clock.ExternalClock)."""
    from pcv_sim.simulation.clock import ClockPlan, ExternalClock

    ext = ExternalClock(100_000, max_jump=1.0)
    assert ext.plan(0) == ClockPlan()                         # no clock yet: nothing to do
    ext.take(1_000_000_000)
    assert ext.start(0) == 1_000_000_000                      # model time 0 = the first clock
    ext.take(1_000_250_000)
    assert ext.plan(0) == ClockPlan(run=2)                    # 0.25 ms later: two whole steps due
    ext.take(500_000_000)
    assert ext.plan(2) == ClockPlan(reanchored=True) and ext.origin_ns == 500_000_000 - 200_000
    assert "went back to 0.5000 s" in ext.went_back()
    ext.take(500_000_000 + 3_000_000_000)
    plan = ext.plan(2)
    assert plan.skip == 20_000 and "jumped 2.000 s ahead" in ext.jumped(plan.skip)
    assert ext.plan(2 + plan.skip) == ClockPlan(run=10_000)


def test_the_longest_wake_gap_is_kept_with_what_filled_it():
    """`note_wake`: the gap from one wake's start to the next's, with the wake before it; its
    cause is the largest share: the loop's work, a collection, time off the CPU inside the wake,
    or a sleep the OS ended late."""
    from pcv_sim.simulation.clock import WakeRecord

    def gap_after(busy, cpu, gc=0.0, late=0.0):
        s, _ = schedule()
        asked = max(P - busy, 0.0)
        s.note_wake(WakeRecord(0.0, 1e-5, busy - 2e-5, 1e-5, busy, cpu, gc, 10, asked))
        s.note_wake(WakeRecord(busy + asked + late, 1e-5, 1e-4, 0.0, busy + asked + late + 1e-4, 1e-4, 0.0, 10,
                               P - 1e-4))
        gap, _, collecting = s.take_period_wakes()
        assert gap is not None and s.max_wake_gap == gap.gap and collecting == gc
        return round(gap.gap * 1e3, 1), gap.cause

    assert gap_after(5e-3, 5e-3) == (5.0, "work")              # the loop's own work ran long
    assert gap_after(2.2e-2, 2e-3) == (22.0, "off_cpu")        # 20 ms of it another process ran
    assert gap_after(8.3e-3, 8.2e-3, gc=8e-3) == (8.3, "gc")   # a collection
    assert gap_after(2e-4, 2e-4, late=3e-2) == (31.0, "late_wake")     # asleep 30 ms beyond what was asked


def test_a_period_of_wakes_gives_its_longest_gap_and_mean_cpu_then_starts_anew():
    from pcv_sim.simulation.clock import WakeRecord

    s, _ = schedule()
    for k, cpu in enumerate((1e-4, 3e-4, 2e-4)):
        start = k * P + (4e-3 if k == 2 else 0.0)
        s.note_wake(WakeRecord(start, 0.0, cpu, 0.0, start + cpu, cpu, 0.0, 10, P - cpu))
    gap, mean, _ = s.take_period_wakes()
    assert gap is not None and gap.gap == pytest.approx(5e-3) and gap.wake.cpu == 3e-4
    assert gap.cause == "late_wake" and mean == pytest.approx(2e-4)
    assert gap.describe().startswith("5.00 ms: a wake of 0.30 ms (CPU 0.30 ms; inputs 0.00, 10 steps and their "
                                     "samples 0.30, diagnostics 0.00, garbage collection 0.00 ms), then asleep "
                                     "4.70 ms (0.70 asked)")
    assert s.take_period_wakes() == (None, 0.0, 0.0)
    s.note_wake(WakeRecord(3 * P + 4e-3, 0.0, 1e-4, 0.0, 3 * P + 4.1e-3, 1e-4, 0.0, 10, 9e-4))
    gap, mean, _ = s.take_period_wakes()    # the gap from the last wake of the period before
    assert gap is not None and gap.gap == pytest.approx(P) and mean == pytest.approx(1e-4)
    assert s.max_wake_gap == pytest.approx(5e-3)
