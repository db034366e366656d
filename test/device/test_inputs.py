"""The devices' one timing rule (InputQueue, InputTiming) and their watchdog, without a model."""
from pcv_sim.device.inputs import NEVER, InputQueue, InputTiming, Watchdog, WatchdogState

DT_NS = 100_000          # 0.1 ms


def test_the_queue_gives_items_by_step_then_by_arrival():
    q: InputQueue[str] = InputQueue()
    for step, item in [(5, "a"), (3, "b"), (5, "c"), (3, "d")]:
        q.push(step, item)
    assert q.next_step == 3
    assert q.pop_due(2) is None
    assert [q.pop_due(4), q.pop_due(4), q.pop_due(4)] == ["b", "d", None]
    assert [q.pop_due(9), q.pop_due(9), q.pop_due(9)] == ["a", "c", None]
    assert q.next_step == NEVER and len(q) == 0


def test_without_a_wall_clock_an_input_acts_from_the_first_step_not_shown():
    timing = InputTiming(DT_NS)
    assert timing.step("duty_cycle", 51) == 51


def test_an_input_acts_from_the_first_step_stamped_at_or_after_its_reception():
    timing = InputTiming(DT_NS)
    origin = 1_000_000_000
    # received 0.25 ms after step 0's stamp, taken 1 ms later: step 3 (stamped 0.3 ms), not step 13
    assert timing.step("duty_cycle", 1, received_ns=origin + 250_000, origin_ns=origin, elapsed=1.25e-3) == 3
    # exactly on a step's stamp: that step
    assert timing.step("duty_cycle", 1, received_ns=origin + 300_000, origin_ns=origin, elapsed=1.25e-3) == 3


def test_an_input_never_acts_at_a_step_already_shown():
    timing = InputTiming(DT_NS)
    origin = 0
    # received at step 3's time, but the samples up to step 9 have left: step 10
    assert timing.step("duty_cycle", 10, received_ns=250_000, origin_ns=origin, elapsed=1.25e-3) == 10


def test_a_system_clock_stepped_forward_cannot_delay_an_input():
    timing = InputTiming(DT_NS)
    # a reception stamp 1 s ahead of the monotonic clock: the step reached when it was taken (13)
    assert timing.step("duty_cycle", 1, received_ns=1_000_250_000, origin_ns=0, elapsed=1.25e-3) == 13
    # no reception time (DDS gave none): the step reached when it was taken
    assert timing.step("duty_cycle", 1, elapsed=1.25e-3) == 13


def test_two_inputs_of_one_name_never_act_at_one_step_and_names_are_apart():
    timing = InputTiming(DT_NS)
    at = timing.step("duty_cycle", 5)
    timing.took("duty_cycle", at)
    assert timing.step("duty_cycle", 5) == 6
    assert timing.step("load_flow", 5) == 5          # another input is not delayed by it
    timing.took("duty_cycle", 6)
    assert timing.step("duty_cycle", 2, received_ns=100_000, origin_ns=0, elapsed=2e-4) == 7


def test_a_refused_input_delays_nothing():
    timing = InputTiming(DT_NS)
    timing.step("duty_cycle", 5)          # asked, not taken (refused by the device)
    assert timing.step("duty_cycle", 5) == 5


def test_the_watchdog_waits_for_a_first_command_fires_and_resumes():
    wd = Watchdog(10)
    assert wd.state == WatchdogState.WAITING and wd.holds and wd.deadline == NEVER
    assert not wd.check(1_000)                        # no controller yet: it never fires
    assert wd.command(20) is False
    assert wd.state == WatchdogState.OK and not wd.holds and wd.deadline == 30
    assert not wd.check(29)
    assert wd.check(30) and wd.state == WatchdogState.FIRED and wd.holds and wd.fired == 1
    assert wd.fired_step == 30 and wd.deadline == NEVER
    assert wd.command(35) is True and wd.state == WatchdogState.OK
    wd.restart()
    assert wd.state == WatchdogState.WAITING and wd.command_step is None


def test_a_zero_timeout_turns_the_watchdog_off_and_ends_a_firing():
    wd = Watchdog(10)
    wd.command(0)
    wd.check(10)
    assert wd.set_timeout(0) is True and wd.state == WatchdogState.OFF and not wd.holds
    assert not wd.check(10**6)
    assert wd.set_timeout(5) is False and wd.state == WatchdogState.OK and wd.deadline == 5
