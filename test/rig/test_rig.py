"""The rig: valves and cylinder composed at 0.1 ms, its inputs, watchdog and lockstep runner."""

import dataclasses

import numpy as np
import pytest

from pcv_sim.errors import CommandError
from pcv_sim.rig import ControllerError, Rig, run_lockstep
from pcv_sim.rig.lockstep import lockstep_periods
from pcv_sim.simulation.reference import VALVE_ATOL, integrate_reference

BAR = 1e5
#: s, the watchdog's timeout of this module's rig: short, so that the runs past it stay short (the
#: shipped rig has every device's default, 2 s).
WATCHDOG = 0.5


@pytest.fixture(scope="module")
def _watchdog_rig(rig_params):
    return Rig(dataclasses.replace(rig_params, timing=dataclasses.replace(rig_params.timing, watchdog_timeout=WATCHDOG)))


@pytest.fixture
def rig(_watchdog_rig):
    """The shipped rig with its watchdog at WATCHDOG, reset (as test/rig/conftest.py's)."""
    _watchdog_rig.on_input = None
    _watchdog_rig.reset()
    return _watchdog_rig


def step_controller(t, m):
    return {"left": 0.7 if t >= 0.01 else 0.5, "right": 0.5}


def test_lockstep_run_repeats_bit_for_bit(rig):
    a = run_lockstep(rig, step_controller, 0.2)
    rig.reset()
    b = run_lockstep(rig, step_controller, 0.2)
    assert np.array_equal(a.true, b.true) and np.array_equal(a.duties, b.duties)
    assert a.signal("cylinder.position")[-1] > 1e-3          # it did move


def test_rig_agrees_with_radau_on_a_duty_step(rig):
    """The composed rig at 0.1 ms (Heun) against scipy's Radau on the same composite right-hand side,
    from rest at 0.5/0.5 with the left duty stepped to 0.7 at t = 0 for 0.2 s."""
    x0, w0 = rig.sim.x.copy(), rig.sim.W.copy()
    rig.set_duty("left", 0.7)
    u = rig.sim.u.copy()
    run = run_lockstep(rig, None, 0.2)
    atol = np.array(list(VALVE_ATOL[:4]) * 2 + [1e-9, 1e-9])
    _xs, ys = integrate_reference(rig.plant, x0, lambda t: u, [], run.times, atol=atol, workspace=w0)
    for name in ("left.pressure", "right.pressure"):
        ref = ys[rig.plant.index("output", name)]
        # 0.05 bar: the core's composition test's bound for Heun at 0.1 ms against Radau.
        assert np.max(np.abs(run.signal(name) - ref)) < 0.05 * BAR, name
    ref_x = ys[rig.plant.index("output", "cylinder.position")]
    assert ref_x[-1] > 5e-3
    # 0.2 % of the travel: Heun's error on the 60 Hz hydraulic-mass mode over 0.2 s.
    assert np.max(np.abs(run.signal("cylinder.position") - ref_x)) < 2e-3 * ref_x[-1]


def test_equal_duties_hold_a_double_rod_piston(rig):
    run = run_lockstep(rig, lambda t, m: {"left": 0.5, "right": 0.5}, 0.3)
    assert np.max(np.abs(run.signal("cylinder.position"))) < 1e-9


def test_pressure_difference_moves_the_piston_toward_the_lower_pressure_side(rig):
    run = run_lockstep(rig, lambda t, m: {"left": 0.5, "right": 0.7}, 0.3)
    assert run.signal("right.pressure")[-1] > run.signal("left.pressure")[-1] + 20 * BAR
    assert run.signal("cylinder.position")[-1] < -5e-3                    # toward chamber a (lower)
    assert run.signal("cylinder.effort")[-1] < 0.0


def test_differential_cylinder_settles_where_forces_balance(rig_params):
    """Equal duties on a cylinder with A_b < A_a: the area difference times the pressure pushes
    it out until the load spring holds it, k x = A_a p_a - A_b p_b, with both valves back near
    their set pressure p: x -> (A_a - A_b) p / k. It creeps the last part (the valves pass little
    flow near their set point, Coulomb friction holds part of the imbalance)."""
    params = dataclasses.replace(rig_params, cylinder=dataclasses.replace(rig_params.cylinder, area_b=5e-4))
    rig = Rig(params)
    run = run_lockstep(rig, lambda t, m: {"left": 0.5, "right": 0.5}, 2.0)
    c = params.cylinder
    x = run.signal("cylinder.position")[-1]
    pa, pb = run.signal("left.pressure")[-1], run.signal("right.pressure")[-1]
    # Within the Coulomb friction, which can hold up to F_c of imbalance at (almost) rest.
    assert abs(c.load_stiffness * x - (c.area_a * pa - c.area_b * pb)) < c.coulomb_friction
    p_set = run.signal("left.pressure")[0]             # both valves' rest pressure at duty 0.5
    assert x == pytest.approx((c.area_a - c.area_b) * p_set / c.load_stiffness, rel=0.1)


def test_external_force_pushes_the_piston(rig):
    rig.set_external_force(2000.0)
    run = run_lockstep(rig, lambda t, m: {"left": 0.5, "right": 0.5}, 0.3)
    assert run.signal("cylinder.position")[-1] > 1e-3
    with pytest.raises(CommandError, match=r"external force 'x': accepted is a finite number of N"):
        rig.set_external_force("x")


def test_commands_are_validated_and_the_last_valid_one_stays(rig):
    with pytest.raises(CommandError, match=r"not percent"):
        rig.set_duty("left", 70)
    assert rig.commands["left"] == 0.5
    run = run_lockstep(rig, lambda t, m: {"left": float("nan"), "right": 0.5}, 0.01)
    assert len(run.rejected) >= 10 and "not finite" in run.rejected[-1][1]
    assert np.all(run.duties[:, 0] == 0.5)


def test_controller_returning_nonsense_is_named(rig):
    with pytest.raises(ControllerError, match=r"returned list .* accepted is a mapping valve -> duty"):
        run_lockstep(rig, lambda t, m: [0.5, 0.5], 0.01)
    with pytest.raises(ControllerError, match=r"commanded 'middle'"):
        run_lockstep(rig, lambda t, m: {"middle": 0.5}, 0.01)


def test_commands_act_from_the_next_step_and_measurements_are_that_periods(rig):
    seen = []

    def ctrl(t, m):
        seen.append((t, m["left.current"]))
        return {"left": 0.9 if t >= 0.005 else 0.5, "right": 0.5}

    run = run_lockstep(rig, ctrl, 0.01)
    k = int(np.argmax(run.times >= 0.005 - 1e-12))
    assert run.duties[k - 1, 0] == 0.5 and run.duties[k, 0] == 0.9
    # The sample the controller got at t_k is the one before its own command (right-continuous
    # after); one period later the current has risen.
    assert seen[k][1] == run.true[k, 1]
    assert run.true[k + 1, 1] > run.true[k, 1]


def test_watchdog_falls_to_safe_duty_and_a_valid_command_resumes(rig):
    t_wd = rig.params.timing.watchdog_timeout
    calls = []

    def ctrl(t, m):
        calls.append(t)
        return {"left": 0.6, "right": 0.6} if t < 0.05 or t >= t_wd + 0.2 else {}

    run = run_lockstep(rig, ctrl, t_wd + 0.3)
    d = run.duties[:, 0]
    times = run.times
    fired = times[np.argmax(d == rig.params.timing.safe_duty)]
    # Last command at t = 0.049 s: fires watchdog_timeout later (to the step).
    assert fired == pytest.approx(0.049 + t_wd, abs=1e-9)
    assert d[-1] == 0.6
    assert any("watchdog fired" in text for _, text in run.log)
    status = rig.status()
    assert status.watchdogs == {"left": "ok", "right": "ok"} and status.duties["left"] == 0.6
    assert status.fault is None and status.watchdog_fired["left"] >= 1


def test_the_watchdog_waits_for_a_first_command_and_a_reset_waits_again(rig):
    """As the emulator's: no controller yet is no lost controller; the valves stay at their initial duty."""
    t_wd = rig.params.timing.watchdog_timeout
    run = run_lockstep(rig, lambda t, m: {"left": 0.7} if t_wd + 0.1 <= t < t_wd + 0.15 else {}, 2 * t_wd + 0.3)
    right, left = run.duties[:, 1], run.duties[:, 0]
    assert np.all(right == rig.params.valves[1].initial_duty)          # never commanded: never fired
    assert left[-1] == rig.params.timing.safe_duty                       # commanded once: fired after t_wd
    assert [text for _, text in run.log if "watchdog" in text] == [f"left: watchdog fired, duty -> "
                                                                    f"{rig.params.timing.safe_duty:g}"]
    rig.reset(keep_time=True)
    assert rig.watchdogs["left"].state == "waiting" and not any(rig.watchdog_fired.values())
    rig.advance_to(rig.steps + round(2 * t_wd / rig.dt))
    assert not any(rig.watchdog_fired.values()) and rig.duties["left"] == rig.params.valves[0].initial_duty


def test_a_valve_on_its_own_volume_runs_exactly_as_the_emulators_device(rig_params, tmp_path):
    """A third valve with chamber: none sits on its own dead-ended load volume: the same
    arithmetic as the emulator's device, so the same numbers bit for bit."""
    import yaml
    from offline_valve import advance, at_rest, put

    from pcv_sim.rig.params import DEFAULT_RIG, rig_from_mapping

    data = yaml.safe_load(DEFAULT_RIG.read_text())
    data["valves"]["pilot"] = {"config": "valve.yaml", "chamber": "none", "initial_duty": 0.5}
    rig = Rig(rig_from_mapping(data, base=DEFAULT_RIG.parent))
    assert rig.valve_names == ("left", "right", "pilot")
    run = run_lockstep(rig, lambda t, m: {"pilot": 0.7 if t >= 0.01 else 0.5, "left": 0.6}, 0.1)
    st = at_rest(rig.params.valve("pilot").params, 0.5)
    pressures = []
    for k in range(len(run.times)):
        pressures.append(float(st.sim.x[3]))
        if k == 10:          # the command answered at t = 0.01 s acts from the step after it
            advance(st, 1)
            put(st, "duty_cycle", 0.7)
            advance(st, 9)
        else:
            advance(st, 10)
    assert np.array_equal(run.signal("pilot.pressure"), np.array(pressures))
    assert run.signal("pilot.pressure")[-1] > 110 * BAR


def test_a_valve_with_a_fall_rate_limit_ramps_its_duty_as_the_emulators_device(tmp_path):
    """The fall-rate limiter is every device's (Sec. 3.2): a rig valve whose YAML sets
    command.duty_fall_rate_limit falls at that rate, step by step, the same numbers bit for bit as
    the emulator's device with the limiter; a rise passes at once."""
    import yaml
    from offline_valve import advance, at_rest, put

    from pcv_sim.params import DEFAULT_CONFIG
    from pcv_sim.rig.params import DEFAULT_RIG, rig_from_mapping

    limited = tmp_path / "limited.yaml"
    limited.write_text(DEFAULT_CONFIG.read_text().replace("duty_fall_rate_limit: null", "duty_fall_rate_limit: 2.0"))
    data = yaml.safe_load(DEFAULT_RIG.read_text())
    data["valves"]["pilot"] = {"config": str(limited), "chamber": "none", "initial_duty": 0.5}
    rig = Rig(rig_from_mapping(data, base=DEFAULT_RIG.parent))
    # Every valve commanded (every watchdog armed): the lockstep takes its fast paths where it can,
    # and the ramp's steps stop them.
    run = run_lockstep(rig, lambda t, m: {"pilot": 0.9 if t < 0.02 else 0.3, "left": 0.6, "right": 0.55}, 0.3)
    pilot = run.duties[:, 2]
    assert pilot[19] == 0.9 and pilot[21] == 0.3        # the duty in force: the command
    st = at_rest(rig.params.valve("pilot").params, 0.5)
    pressures = []
    for k in range(len(run.times)):
        pressures.append(float(st.sim.x[3]))
        advance(st, 1)
        put(st, "duty_cycle", 0.9 if k < 20 else 0.3)
        advance(st, 9)
    assert np.array_equal(run.signal("pilot.pressure"), np.array(pressures))
    # 0.9 -> 0.3 at 2 /s takes 0.3 s: the valve's model input is still falling at the end
    assert rig.input_values()["pilot.duty_cycle"] == pytest.approx(0.9 - 2.0 * (0.3 - 0.0201), abs=2e-4)


def test_reset_keeping_time_is_a_fresh_start_shifted_in_time_and_inputs_reach_the_hook(rig):
    """The rig node's reset service: state, duties, faults back to the start; t goes on. Every
    input change reaches `on_input` with the step it acts from (the node's recorder)."""
    from pcv_sim.device.faults import parse_fault

    fresh = run_lockstep(rig, lambda t, m: step_controller(t + 5e-4, m), 0.05)
    seen = []
    rig.on_input = lambda step, name, value: seen.append((step, name, value))
    rig.set_duty("left", 0.8)
    rig.inject(parse_fault("supply_drop", "right", {"pressure": 8e6}, valves=rig.valve_names,
                           signals=rig.signals))
    rig.set_external_force(500.0)
    rig.advance_to(rig.steps + 100)
    assert seen == [(500, "left.duty_cycle", 0.8), (500, "right.supply_pressure", 8e6),
                    (500, "cylinder.external_force", 500.0)]
    seen.clear()
    rig.reset(keep_time=True)
    assert rig.steps == 600 and rig.faults == {} and rig.commands == {"left": 0.5, "right": 0.5}
    assert {(n, v) for s, n, v in seen if s == 600} >= {("left.duty_cycle", 0.5), ("right.supply_pressure", 20e6),
                                                         ("cylinder.external_force", 0.0)}
    assert "reset" in rig.log[-1][1]
    rig.on_input = None
    again = run_lockstep(rig, lambda t, m: step_controller(t - 0.06 + 5e-4, m), 0.05)
    assert np.array_equal(again.true, fresh.true)          # the same run, 60 ms later


def test_an_array_the_compiled_sampling_would_misread_is_refused(rig):
    """The planned stretch's compiled call takes the sample's array as it is (no dispatch): a
    strided, integer or short one is refused before any step, with what is accepted."""
    n = len(rig.signals)
    for out in (np.empty(2 * n)[::2], np.empty(n, dtype=np.int64), np.empty(n - 1)):
        with pytest.raises(ValueError, match="accepted is a C-contiguous float64 array"):
            rig.advance_sample(10, 1, out)
    with pytest.raises(ValueError, match=r"rows: accepted is a \(11, \d+\) float64 array of contiguous rows"):
        next(lockstep_periods(rig, None, 0.01, rows=np.empty((n, 11)).T, batched=True))
    assert rig.steps == 0
    y = np.empty(n)
    assert rig.advance_sample(10, 1, y) is y and rig.steps == 11


def test_the_planned_stretch_gives_sample_planneds_numbers_also_after_a_restart(rig):
    """`planned_stretch` (what the lockstep calls every period of a stretch in which nothing falls
    due) gives `Rig.sample_planned`'s numbers bit for bit (the samples, the steps, the whole state),
    and after a restart with new valve parameters it steps the new model: a fresh rig's numbers."""
    from pcv_sim.rig.params import load_rig

    per = rig.params.steps_per_period
    n = len(rig.signals)

    def run(stretch, other, first, periods):
        mine, theirs = np.empty((periods, n)), np.empty((periods, n))
        for k in range(1, periods):
            stretch(first + k * per, mine[k], 1)
            other.sample_planned(k * per, theirs[k], 1)
            assert rig.steps == first + k * per + 1 and other.steps == k * per + 1
        assert np.array_equal(mine[1:], theirs[1:]) and np.array_equal(rig.sim.x, other.sim.x)
        assert len(np.unique(mine[1:, rig.signals.index("left.pressure")])) > periods // 2     # it moved

    other = Rig(rig.params)
    for dev in (rig, other):
        dev.submit("left.duty_cycle", 0.7, at_step=1)
        dev.advance_to(1)
    run(rig.planned_stretch(), other, 0, 30)
    heavier = dataclasses.replace(load_rig(valve_changes={"left": {("spool", "mass"): 0.05}}),
                                  timing=rig.params.timing)           # this module's watchdog (a restart keeps it)
    original = rig.params
    rig.install(rig.prepare(heavier))
    try:
        fresh = Rig(heavier)
        for dev in (rig, fresh):
            dev.submit("left.duty_cycle", 0.7, at_step=dev.steps + 1)
            dev.advance_to(dev.steps + 1)
        run(rig.planned_stretch(), fresh, rig.steps - 1, 30)
    finally:
        rig.install(rig.prepare(original))          # the module's rig, as the other tests know it


def test_advance_sample_gives_the_numbers_of_advance_to_and_sample(rig):
    """The lockstep's fused call (steps and sampling in one compiled call) against the plain path,
    bit for bit, with inputs scheduled on, between and just after sample instants, and the
    watchdog firing on one (those fall back to the plain path)."""
    per = rig.params.steps_per_period
    wd = round(rig.params.timing.watchdog_timeout / rig.dt)

    def schedule_inputs() -> None:
        rig.schedule(3 * per * rig.dt, lambda: rig.set_duty("left", 0.8))        # on a sample instant
        rig.schedule((5 * per + 3) * rig.dt, lambda: rig.set_duty("right", 0.4))  # between two
        rig.schedule((7 * per + 1) * rig.dt, lambda: rig.set_external_force(300.0))

    periods = (wd + 6 * per) // per + 3          # past the watchdog (no command after 0.8 / 0.4)
    schedule_inputs()
    fused = [rig.advance_sample(k * per) for k in range(periods)]
    fused_log = list(rig.log)
    rig.reset()
    schedule_inputs()
    plain = []
    for k in range(periods):
        rig.advance_to(k * per)
        plain.append(rig.sample())
    assert np.array_equal(np.array(fused), np.array(plain))
    assert fused_log == rig.log and any("watchdog fired" in text for _, text in rig.log)
    assert fused[-1][0] != fused[2][0]          # the inputs did act
    # With the step after each sample taken in the same call (the lockstep's answer path): the
    # same samples and the same state at the end; where an input falls due up to that step (the
    # left duty at 3 per and the force at 7 per + 1; not the right duty at 5 per + 3) it stops at
    # the sample and the plain path runs.
    ends = []
    for after in (1, 0):
        rig.reset()
        schedule_inputs()
        got, stopped = [], []
        for k in range(periods):
            if after:
                got.append(rig.advance_sample(k * per, 1))
                stopped.append(rig.steps == k * per)
            else:
                rig.advance_to(k * per)
                got.append(rig.sample())
                rig.advance_to(k * per + 1)
        ends.append((np.array(got), rig.sim.x.copy()))
        if after:
            assert stopped[3] and stopped[7] and not stopped[5] and not all(stopped)
    assert np.array_equal(ends[0][0], ends[1][0]) and np.array_equal(ends[0][1], ends[1][1])


def test_a_fed_force_gives_the_numbers_of_the_same_values_scheduled(rig):
    """`Rig.feed` (a profile's values put into the model inside the lockstep's compiled call)
    against the same values scheduled one by one (`Rig.schedule`, the plain path), bit for bit,
    with a controller answering every period: values on sample instants, one between two, one
    on the step after a sample (where the answer acts); the hook hears the same (step, value)."""
    from pcv_sim.rig.rig import EXTERNAL_FORCE

    per = rig.params.steps_per_period
    steps = [3 * per, 4 * per, 5 * per, 5 * per + 3, 9 * per + 1, 12 * per]
    values = [100.0, 250.0, -400.0, 80.0, 0.0, 1500.0]
    runs, heard = [], []
    for how in ("none", "scheduled", "fed"):
        rig.on_input = None
        rig.reset()
        seen = []
        rig.on_input = lambda step, name, value, seen=seen: seen.append((step, value)) if name == EXTERNAL_FORCE \
            else None
        if how == "fed":
            rig.feed(EXTERNAL_FORCE, steps, values)
        elif how == "scheduled":
            for st, v in zip(steps, values):
                rig.schedule(st * rig.dt, lambda v=v: rig.set_external_force(v))
        runs.append(run_lockstep(rig, step_controller, 0.02))
        heard.append(seen)
    rig.on_input = None
    none, scheduled, fed = runs
    assert np.array_equal(scheduled.true, fed.true) and np.array_equal(scheduled.duties, fed.duties)
    assert heard[1] == heard[2] == list(zip(steps, values))
    assert not np.array_equal(none.true, fed.true)               # the force did act


def test_the_lockstep_fast_path_gives_the_numbers_of_the_rigs_own_path(rig):
    """The lockstep writes a valid command straight into the model and tells the watchdog later
    while nothing else falls due; with a no-op scheduled on every step after a sample every
    period goes through the rig's own path (advance_to, sample, set_duty at that step). Bit for
    bit the same run: a fed force, a refused command, one valve left without commands until its
    watchdog fires and a command resumes it; the same log, refusals, hook and watchdogs."""
    from pcv_sim.rig.rig import EXTERNAL_FORCE

    per = rig.params.steps_per_period
    t_wd = rig.params.timing.watchdog_timeout
    safe = rig.params.timing.safe_duty

    def ctrl(t, m):
        left = 0.5 + 10.0 * m["cylinder.position"] + (0.2 if t >= 0.01 else 0.0)
        out: dict[str, object] = {"right": 1.5 if abs(t - 0.03) < 1e-9 else 0.55,   # one refused
                                  "flags": {"position": m["cylinder.position"]}}
        if t < 0.05 or t >= t_wd + 0.1:
            out["left"] = min(1.0, left)
        return out

    duration = t_wd + 0.15
    runs, heard, ends = [], [], []
    for forced in (False, True):
        rig.on_input = None
        rig.reset()
        seen: list[tuple[int, str, float]] = []
        rig.on_input = lambda step, name, value, seen=seen: seen.append((step, name, value))
        rig.feed(EXTERNAL_FORCE, [4 * per, 20 * per, 20 * per + 3], [150.0, -300.0, 80.0])
        if forced:
            for k in range(round(duration / rig.params.timing.control_period) + 1):
                rig.schedule_step(k * per + 1, lambda: None)
        runs.append(run_lockstep(rig, ctrl, duration))
        heard.append(seen)
        ends.append((rig.sim.x.copy(), {v: (w.state, w.command_step) for v, w in rig.watchdogs.items()}))
    rig.on_input = None
    fast, own = runs
    assert np.array_equal(fast.true, own.true) and np.array_equal(fast.duties, own.duties)
    assert np.array_equal(fast.flags["controller.position"], own.flags["controller.position"], equal_nan=True)
    assert fast.log == own.log and fast.rejected == own.rejected and heard[0] == heard[1]
    assert np.array_equal(ends[0][0], ends[1][0]) and ends[0][1] == ends[1][1]
    # What the run went through: the left watchdog fired and was cleared, one command refused.
    assert [text for _, text in fast.log if "watchdog" in text] == [
        f"left: watchdog fired, duty -> {safe:g}", "left: watchdog cleared by a valid command"]
    assert len(fast.rejected) == 1 and "right" in fast.rejected[0][1]
    assert ends[0][1]["right"][1] == round(duration / rig.dt) - per + 1     # told of the last command


def test_feed_refuses_what_the_rig_would_refuse(rig):
    from pcv_sim.rig.rig import EXTERNAL_FORCE

    with pytest.raises(CommandError, match=r"external force 2000000\.0"):
        rig.feed(EXTERNAL_FORCE, [10, 20], [0.0, 2e6])
    with pytest.raises(CommandError, match="steps increasing"):
        rig.feed(EXTERNAL_FORCE, [20, 10], [0.0, 1.0])
    with pytest.raises(CommandError, match=r"accepted are cylinder\.external_force, left\.duty_cycle, "):
        rig.feed("left.supply_pressure", [10], [2e7])     # a supply: a fault holds over it (submit it)
    with pytest.raises(CommandError, match=r"duty cycle 1\.5 is out of range"):
        rig.feed("left.duty_cycle", [10], [1.5])
    rig.feed(EXTERNAL_FORCE, [0, 30], [5.0, 7.0])           # a second feed of it replaces the first
    rig.feed(EXTERNAL_FORCE, [20], [6.0])
    rig.advance_to(40)
    assert rig.input_values()[EXTERNAL_FORCE] == 6.0


def test_a_chamber_pulled_on_by_the_piston_cavitates_at_the_floor_and_recovers(rig):
    """Watchdog to duty 0 while the piston moves: the expanding chamber's valve relieves to tank
    and cannot feed it; the pressure stops at the oil's cavitation pressure (R32; it went to
    -54 bar without the floor) and rises again once the valves are commanded."""
    floor = rig.params.valves[1].params.fluid.cavitation_pressure
    t_wd = rig.params.timing.watchdog_timeout

    def ctrl(t, m):
        if t < 0.2:
            return {"left": 0.9, "right": 0.3}
        return {"left": 0.6, "right": 0.6} if t >= t_wd + 0.6 else {}

    run = run_lockstep(rig, ctrl, t_wd + 0.9)
    right = run.signal("right.pressure")
    assert right.min() == floor                                   # reached, never passed
    assert np.all(run.signal("left.pressure") >= floor)
    assert right[-1] > 10 * BAR                                   # back under control


def test_the_controller_gets_the_time_a_node_reads_from_the_stamp(rig):
    """t is the sample's stamp in integer ns x 1e-9, what a controller node computes from the
    message header: the same float to the last bit (steps x dt differs at some instants)."""
    seen = []
    run_lockstep(rig, lambda t, m: seen.append(t) or {}, 0.2)
    stamps_ns = [k * rig.params.steps_per_period * 100_000 for k in range(len(seen))]
    assert seen == [s * 1e-9 for s in stamps_ns]
    assert any(s * 1e-9 != k * rig.params.steps_per_period * rig.dt for k, s in enumerate(stamps_ns))


def test_a_state_that_runs_away_is_the_rigs_fault_state_until_a_reset(rig):
    """The rig is a device (pcv_sim.device.device): a state that runs away (here one the coil current
    cannot be solved for) raises RigError naming the time and is kept as `fault`; a reset that keeps the
    time clears it and the rig steps again."""
    from pcv_sim.rig import RigError

    rig.advance_to(100)
    assert rig.fault is None
    rig.sim.x[0] = np.nan
    with pytest.raises(RigError, match=r"model step failed \(ArithmeticError: no coil current solves Eq\. 2") as err:
        rig.advance_to(200)
    assert rig.fault == str(err.value) and rig.fault_step is not None
    rig.reset(keep_time=True)
    assert rig.fault is None and rig.fault_step is None and rig.steps >= 100
    rig.advance_to(rig.steps + 100)
    assert np.isfinite(rig.sample()).all()


def test_inputs_act_at_their_step_in_the_order_they_came(rig):
    """The rig's queue is the devices' one (pcv_sim.device.inputs.InputQueue): an input scheduled for a
    step acts there, two for one step act in their order, one for a past step at the present one."""
    rig.advance_to(10)
    rig.schedule_step(20, lambda: rig.set_duty("left", 0.6))
    rig.schedule_step(20, lambda: rig.set_duty("left", 0.7))
    assert rig.schedule_step(5, lambda: rig.set_duty("right", 0.4)) == 10
    rig.advance_to(19)
    assert rig.commands["left"] == 0.5 and rig.commands["right"] == 0.4
    rig.advance_to(20)
    assert rig.commands["left"] == 0.7 and rig.watchdogs["left"].command_step == 20


def test_a_controllers_array_form_gives_the_numbers_of_its_dict_form(rig):
    """The example controller in the lockstep's array form (no sensor fault active) and in its dict
    form (the same object behind a plain function), over a setpoint step and a dropout and a
    noise fault that come and go (the array form gives way to the dict form meanwhile): the same
    run to the last bit, flags and setpoint included."""
    from pcv_sim.control.steering import PositionController
    from pcv_sim.rig import parse_fault

    def faults():
        for t, kind, target, values in ((0.05, "dropout", "cylinder.position", {}),
                                        (0.12, "noise", "left.current", {"std": 0.05})):
            f = parse_fault(kind, target, values, valves=rig.valve_names, signals=rig.signals)
            rig.schedule(t, lambda f=f: rig.inject(f))
            rig.schedule(t + 0.03, lambda target=target, kind=kind: rig.clear(target, kind))

    class Counted(PositionController):
        def lockstep_arrays(self, signals, valves):
            step, commanded, flags = super().lockstep_arrays(signals, valves)

            def counted(t, y, out):
                self.array_calls += 1
                step(t, y, out)
            return counted, commanded, flags

    runs, calls = [], []
    for wrapped in (False, True):
        rig.reset()
        faults()
        law = Counted()
        law.array_calls = 0
        seen = []

        def by_dict(t, m, law=law, seen=seen):
            seen.append(t)
            return law(t, m)

        runs.append(run_lockstep(rig, by_dict if wrapped else law, 0.25, setpoint=lambda t: 0.01 if t >= 0.02 else 0.0))
        calls.append((seen, law.array_calls))
    arrays, dicts = runs
    for name in ("true", "measured", "duties", "setpoint"):
        assert np.array_equal(getattr(arrays, name), getattr(dicts, name), equal_nan=True), name
    assert arrays.flags.keys() == dicts.flags.keys() == {"controller.fault_detected"}
    assert np.array_equal(arrays.flags["controller.fault_detected"], dicts.flags["controller.fault_detected"],
                          equal_nan=True)
    assert arrays.log == dicts.log and np.isnan(arrays.measured).any()
    assert len(calls[1][0]) == 250 and calls[1][1] == 0
    assert calls[0][1] == 250 - 60 and len(calls[0][0]) == 0        # the dict form while a fault was on
    assert arrays.signal("cylinder.position")[-1] > 5e-3


class ArrayHold:
    """A controller with both forms: a duty per valve of `commanded` (right: one out of range at
    0.03 s) and a flag."""

    def __init__(self, commanded=("right", "left"), flags=("k",)):
        self.commanded, self.flags = commanded, flags
        self.array_calls = 0

    def duties(self, t):
        return tuple({"right": 1.5 if abs(t - 0.03) < 1e-9 else 0.55 + 0.1 * t, "left": 0.5 + t}.get(v, 0.5)
                     for v in self.commanded)

    def __call__(self, t, m):
        return {**dict(zip(self.commanded, self.duties(t))), "flags": {"k": t * 2}}

    def lockstep_arrays(self, signals, valves):
        def step(t, y, out):
            self.array_calls += 1
            assert len(y) == len(signals) and signals[-1] == "setpoint" and y[-1] != y[-1]
            out[:len(self.commanded)] = self.duties(t)
            out[len(self.commanded)] = t * 2
        return step, self.commanded, self.flags


def test_an_array_forms_duties_are_taken_as_the_dict_forms_are(rig):
    """A refused duty is counted and the last valid one kept, the valves in the order the array
    form names them, its flags recorded: the same run as the same controller's dict form."""
    hold = ArrayHold()
    a = run_lockstep(rig, hold, 0.06)
    assert hold.array_calls == 60
    rig.reset()
    same = ArrayHold()

    def by_dict(t, m):                  # a plain function: the dict form only
        return same(t, m)

    d = run_lockstep(rig, by_dict, 0.06)
    assert np.array_equal(a.true, d.true) and np.array_equal(a.duties, d.duties)
    assert np.array_equal(a.flags["controller.k"], d.flags["controller.k"], equal_nan=True)
    assert a.rejected == d.rejected and len(a.rejected) == 1 and "right" in a.rejected[0][1]
    right = a.duties[:, a.valves.index("right")]
    assert right[30] == right[29] < right[31] and a.flags["controller.k"][-1] != a.flags["controller.k"][-1]


@pytest.mark.parametrize(("commanded", "flags", "match"), [
    (("left", "middle"), ("k",), r"'middle'.*accepted is a callable step and each of the valves left, right"),
    (("left", "left"), ("k",), "at most once"),
    (("left",), (3,), r"flags \(3,\); accepted are distinct names"),
])
def test_a_wrong_array_form_is_refused_before_the_run(rig, commanded, flags, match):
    with pytest.raises(ControllerError, match=match):
        run_lockstep(rig, ArrayHold(commanded, flags), 0.01)
    assert rig.steps == 0


def test_the_array_forms_stretches_give_the_numbers_of_the_rigs_own_path(rig):
    """The lockstep runs an array-form controller's periods in stretches planned ahead (to the next
    fed input, queued input or watchdog deadline); with a no-op scheduled on every step after a
    sample every period goes through the rig's own path instead. Bit for bit the same run: fed
    forces, a refused duty, the left valve (commanded once before the run, never by the
    controller) left until its watchdog fires; the same log, refusals, watchdogs and flags."""
    from pcv_sim.rig.rig import EXTERNAL_FORCE

    per = rig.params.steps_per_period
    t_wd = rig.params.timing.watchdog_timeout
    duration = t_wd + 0.1
    runs, ends = [], []
    for forced in (False, True):
        rig.reset()
        rig.set_duty("left", 0.6)
        rig.feed(EXTERNAL_FORCE, [4 * per, 20 * per, 20 * per + 3, 90 * per + 5], [150.0, -300.0, 80.0, 10.0])
        if forced:
            for k in range(round(duration / rig.params.timing.control_period) + 1):
                rig.schedule_step(k * per + 1, lambda: None)
        ctrl = ArrayHold(("right",), ("k",))
        runs.append(run_lockstep(rig, ctrl, duration))
        assert ctrl.array_calls == round(duration / rig.params.timing.control_period)
        ends.append((rig.sim.x.copy(), {v: (w.state, w.command_step) for v, w in rig.watchdogs.items()}))
    planned, own = runs
    assert np.array_equal(planned.true, own.true) and np.array_equal(planned.duties, own.duties)
    assert np.array_equal(planned.flags["controller.k"], own.flags["controller.k"], equal_nan=True)
    assert planned.log == own.log and planned.rejected == own.rejected
    assert np.array_equal(ends[0][0], ends[1][0]) and ends[0][1] == ends[1][1]
    safe = rig.params.timing.safe_duty
    assert [text for _, text in planned.log if "watchdog" in text] == [f"left: watchdog fired, duty -> {safe:g}"]
    assert len(planned.rejected) == 1 and planned.duties[-1, planned.valves.index("left")] == safe


class _Holding:
    """A controller that holds each valve's duty (its array form: the lockstep's planned stretch);
    keeps what it was shown."""

    def __init__(self, duties):
        self.duties = duties
        self.seen = []

    def __call__(self, t, m):
        self.seen.append(dict(m))
        return dict(self.duties)

    def lockstep_arrays(self, signals, valves):
        names = list(signals)

        def step(t, samples, out):
            self.seen.append(dict(zip(names, samples)))
            out[:] = list(self.duties.values())
        return step, tuple(self.duties), ()


def _dict_form(controller):
    """`controller` without its array form (a plain function)."""
    def plain(t, m):
        return controller(t, m)
    return plain


@pytest.mark.parametrize("form", ["array", "dict"])
def test_a_model_diverging_on_the_lockstep_fast_path_stops_as_on_the_devices_own_path(form):
    """The lockstep's fast path is the rig's planned stretch (`Rig.sample_planned`), which checks
    each sample against the valves' physical limits as `run_to` does: a model driven beyond what a
    valve can show (3e5 N on the rod: a chamber pressure past 2 x 400 bar, finite) stops with the
    same error at the same sample, and no such sample reaches the controller."""
    from pcv_sim.rig import RigError
    from pcv_sim.rig.params import load_rig

    def pushed():
        rig = Rig(load_rig())
        rig.set_external_force(3e5)
        return rig

    own = pushed()
    for valve in ("left", "right"):
        own.submit(f"{valve}.duty_cycle", 0.5, at_step=1)      # as the controller's answer to the first sample
    own.run_to(own.params.steps_per_period * 1000)
    assert own.fault is not None and "outside the physical range" in own.fault, own.fault

    rig = pushed()
    controller = _Holding({"left": 0.5, "right": 0.5})
    with pytest.raises(RigError) as err:
        run_lockstep(rig, controller if form == "array" else _dict_form(controller), 1.0)
    assert str(err.value) == own.fault and rig.fault == own.fault
    assert len(controller.seen) >= 2 and all(
        rig.limits[v].problem(m[f"{v}.pressure"], m[f"{v}.current"]) is None for m in controller.seen for v in ("left", "right"))


def test_an_array_form_commanding_a_valve_with_a_fall_rate_limit_gives_its_dict_forms_numbers(tmp_path):
    """A valve with a fall-rate limiter is not among the rig's direct duties (`direct_duties`): its
    duty ramps step by step, so an array form that commands it takes no stretch of periods in one
    go, and the run is its dict form's to the last bit (the ramp's steps included)."""
    import yaml

    from pcv_sim.params import DEFAULT_CONFIG
    from pcv_sim.rig.params import DEFAULT_RIG, rig_from_mapping

    limited = tmp_path / "limited.yaml"
    limited.write_text(DEFAULT_CONFIG.read_text().replace("duty_fall_rate_limit: null", "duty_fall_rate_limit: 2.0"))
    data = yaml.safe_load(DEFAULT_RIG.read_text())
    data["valves"]["left"]["config"] = str(limited)
    params = rig_from_mapping(data, base=DEFAULT_RIG.parent)

    class Stepped(_Holding):
        def step(self, t):
            self.duties["left"] = 0.9 if t < 0.02 else 0.3
            return self.duties

        def __call__(self, t, m):
            return dict(self.step(t))

        def lockstep_arrays(self, signals, valves):
            def step(t, samples, out):
                out[:] = list(self.step(t).values())
            return step, tuple(self.duties), ()

    rig = Rig(params)
    assert set(rig.direct_duties()) == {"right"}
    array = run_lockstep(rig, Stepped({"left": 0.9, "right": 0.55}), 0.3)
    plain = run_lockstep(Rig(params), _dict_form(Stepped({"left": 0.9, "right": 0.55})), 0.3)
    assert np.array_equal(array.true, plain.true) and np.array_equal(array.duties, plain.duties)
    assert array.signal("left.duty")[-1] == 0.3 and rig.input_values()["left.duty_cycle"] > 0.33   # still ramping
