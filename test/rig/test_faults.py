"""Faults: each physical fault's effect on the physics, clearing, and the sensor faults on what
the controller sees (the physics untouched)."""

import math

import numpy as np
import pytest

from pcv_sim.rig import FaultError, parse_fault, run_lockstep

BAR = 1e5


def fault(rig, kind, target="left", **values):
    return parse_fault(kind, target, values, valves=rig.valve_names, signals=rig.signals)


def hold(left, right=0.5):
    return lambda t, m: {"left": left, "right": right}


def step_up(t, m):
    return {"left": 0.7 if t >= 0.05 else 0.5, "right": 0.5}


def rise_time(run):
    """Time from the duty step at t = 0.05 s until the left pressure is 90 % of the way (s)."""
    p = run.signal("left.pressure")
    k0 = int(np.argmax(run.times >= 0.05 - 1e-12))
    hi = p[k0] + 0.9 * (p[-1] - p[k0])
    return run.times[np.argmax(p >= hi)] - run.times[k0]


def test_coil_open_current_decays_with_the_coil_time_constant_and_pressure_falls(rig):
    rig.set_duty("left", 0.7)
    run_lockstep(rig, None, 0.2)
    lam0, i0, p0 = rig.sim.x[0], rig.sample()[1], rig.sample()[0]
    rig.inject(fault(rig, "coil_open"))
    run = run_lockstep(rig, hold(0.9), 0.25)         # the driver commands 0.9: nothing reaches the coil
    i, t = run.signal("left.current"), run.times - run.times[0]
    # The flux decays through the coil resistance: d(lambda)/dt = -R i. Its time constant is
    # L/R with the coil's (flux-dependent) inductance; the secant one at the start, lambda0 / i0:
    tau = lam0 / i0 / rig.params.valve("left").params.solenoid.coil_resistance
    t_e = t[np.argmax(i <= i0 / math.e)]
    assert 0.8 * tau < t_e < 1.5 * tau
    assert np.all(np.diff(i[1:]) <= 0.0)
    assert i[-1] < 0.01 * i0
    assert run.signal("left.pressure")[-1] < 0.5 * p0
    # Cleared: the coil is driven again and the current returns to V D / R.
    rig.clear("left", "coil_open")
    run = run_lockstep(rig, hold(0.7), 0.3)
    s = rig.params.valve("left").params.solenoid
    assert run.signal("left.current")[-1] == pytest.approx(s.supply_voltage * 0.7 / s.coil_resistance, rel=3e-3)


def test_coil_partial_short_raises_current_and_pressure(rig):
    base = run_lockstep(rig, hold(0.7), 0.3)
    rig.reset()
    rig.inject(fault(rig, "coil_short", resistance_factor=0.8))
    run = run_lockstep(rig, hold(0.7), 0.3)
    s = rig.params.valve("left").params.solenoid
    # At rest d(lambda)/dt = V D - R i = 0: i = V D / (0.8 R).
    assert run.signal("left.current")[-1] == pytest.approx(s.supply_voltage * 0.7 / (0.8 * s.coil_resistance), rel=2e-3)
    assert run.signal("left.pressure")[-1] > base.signal("left.pressure")[-1] + 20 * BAR


@pytest.mark.parametrize(("kind", "values", "bound"), [
    ("supply_drop", {"pressure": 50 * BAR}, 50 * BAR),
    ("supply_loss", {}, 0.0),
])
def test_supply_drop_and_loss_cap_the_pressure(rig, kind, values, bound):
    rig.schedule(0.1, lambda: rig.inject(fault(rig, kind, **values)))
    run = run_lockstep(rig, hold(0.7), 0.3)
    p = run.signal("left.pressure")
    assert p[99] > 100 * BAR
    # A reducing valve cannot hold more than its supply; 2 bar: the flow the moving piston
    # pushes back through the pump edge (no check valve).
    assert abs(p[-1] - bound) < 2 * BAR


def test_stuck_spool_stops_regulating(rig):
    rig.inject(fault(rig, "spool_stuck"))
    x0 = rig.sim.x[1]
    run = run_lockstep(rig, step_up, 0.3)
    assert np.all(run.signal("left.spool_position") == x0)
    assert run.signal("left.current")[-1] > 1.45                # the coil still follows the command
    rig.reset()
    base = run_lockstep(rig, step_up, 0.3)
    assert abs(run.signal("left.pressure")[-1] - base.signal("left.pressure")[-1]) > 5 * BAR


def test_sticking_spool_and_contamination_slow_the_step_response(rig):
    base = rise_time(run_lockstep(rig, step_up, 0.4))
    for f in (fault(rig, "spool_sticking", friction=5.0), fault(rig, "contamination", area_factor=0.2)):
        rig.reset()
        rig.inject(f)
        slow = rise_time(run_lockstep(rig, step_up, 0.4))
        assert slow > base + 3e-3, (f.kind, base, slow)


def test_internal_leakage_opens_the_spool_and_lowers_the_pressure(rig):
    base = run_lockstep(rig, hold(0.7), 0.3)
    rig.reset()
    rig.inject(fault(rig, "internal_leakage", conductance=1e-11))
    run = run_lockstep(rig, hold(0.7), 0.3)
    # The valve feeds the leak G p (~1 L/min at 100 bar) through a wider pump edge, at a lower pressure
    # (its static characteristic falls with load flow).
    assert run.signal("left.spool_position")[-1] > base.signal("left.spool_position")[-1] + 5e-5
    assert run.signal("left.pressure")[-1] < base.signal("left.pressure")[-1] - 3 * BAR


def test_a_cleared_fault_returns_to_normal(rig):
    base = run_lockstep(rig, hold(0.7), 0.6)
    rig.reset()
    rig.inject(fault(rig, "contamination", area_factor=0.1))
    rig.inject(fault(rig, "internal_leakage", conductance=1e-11))
    rig.schedule(0.1, lambda: rig.clear("left", "contamination"))
    rig.schedule(0.1, lambda: rig.clear("left", "internal_leakage"))
    fresh = {}
    rig.schedule(0.2, lambda: fresh.update(p=rig.sim.P.copy(), u=rig.sim.u.copy()))
    assert rig.status().faults == ("contamination@left", "internal_leakage@left")
    run = run_lockstep(rig, hold(0.7), 0.6)
    assert not rig.faults and rig.status().faults == ()
    # The device is the healthy one again: the same parameters and inputs, bit for bit ...
    rig.reset()
    supplies = [rig.plant.index("input", f"{v}.supply_pressure") for v in rig.valve_names]
    assert np.array_equal(rig.sim.P, fresh["p"]) and np.array_equal(rig.sim.u[supplies], fresh["u"][supplies])
    # ... and its pressure is back at the healthy one's (the piston, slower, still creeps).
    assert abs(run.signal("left.pressure")[-1] - base.signal("left.pressure")[-1]) < 0.5 * BAR
    with pytest.raises(FaultError, match=r"no active fault coil_open on left; active: none"):
        rig.clear("left", "coil_open")


@pytest.mark.parametrize(("kind", "target", "values", "match"), [
    ("coil_melt", "left", {}, r"kind 'coil_melt'; accepted are supply_drop"),
    ("coil_open", "middle", {}, r"target 'middle' for coil_open; accepted are left, right"),
    ("coil_short", "left", {}, r"coil_short\.resistance_factor: missing; accepted is the factor on the coil resistance"),
    ("coil_short", "left", {"resistance_factor": 0.0}, r"coil_short\.resistance_factor: got 0\.0; accepted is a factor > 0 and <= 1"),
    ("coil_short", "left", {"resistance_factor": "150 %"}, r"got '150 %'; accepted is a factor > 0 and <= 1"),
    ("coil_short", "left", {"resistance_factor": 1.5}, r"1\.5 is 1\.5 \(a fraction\), above any resistance factor; did you mean 1\.5 %\?"),
    ("supply_drop", "left", {"pressure": "80 mm"}, r"supply_drop\.pressure: unit 'mm' in '80 mm' \(mm is a unit of length\); accepted for a pressure are Pa"),
    ("bias", "left.pressure", {"value": 1e5, "offset": 1}, r"bias: unknown key 'offset'; accepted: value"),
    ("bias", "left", {"value": 1.0}, r"target 'left' for bias; accepted are left\.pressure"),
    ("cylinder_jam", "left", {}, r"target 'left' for cylinder_jam; accepted are cylinder"),
    ("cylinder_friction", "cylinder", {"friction": -5.0}, r"cylinder_friction\.friction: got -5\.0; accepted is a friction force in 0 \.\. 100000 \(N\)"),
])
def test_bad_faults_are_refused_naming_what_is_accepted(rig, kind, target, values, match):
    with pytest.raises(FaultError, match=match):
        fault(rig, kind, target, **values)


def test_sensor_faults_change_what_the_controller_sees_not_the_physics(rig):
    base = run_lockstep(rig, step_up, 0.1)
    rig.reset()
    seen = []

    def ctrl(t, m):
        seen.append(dict(m))
        return step_up(t, m)

    sig = {s: rig.signals.index(s) for s in rig.signals}
    rig.schedule(0.02, lambda: rig.inject(fault(rig, "bias", "left.pressure", value=5 * BAR)))
    rig.schedule(0.02, lambda: rig.inject(fault(rig, "drift", "right.pressure", rate=10 * BAR)))
    rig.schedule(0.02, lambda: rig.inject(fault(rig, "freeze", "left.current")))
    rig.schedule(0.02, lambda: rig.inject(fault(rig, "noise", "cylinder.position", std=1e-4)))
    rig.schedule(0.02, lambda: rig.inject(fault(rig, "dropout", "right.current")))
    rig.schedule(0.02, lambda: rig.inject(fault(rig, "delay", "left.spool_position", delay=2.5e-3)))
    run = run_lockstep(rig, ctrl, 0.1)
    assert np.array_equal(run.true, base.true)                     # the physics did not notice
    k = int(np.argmax(run.times >= 0.02 - 1e-12))
    after = slice(k, None)
    m, tr, t = run.measured, run.true, run.times
    assert np.allclose(m[after, sig["left.pressure"]] - tr[after, sig["left.pressure"]], 5 * BAR, rtol=0, atol=1e-6)
    assert np.allclose(m[after, sig["right.pressure"]] - tr[after, sig["right.pressure"]],
                       10 * BAR * (t[after] - t[k]), rtol=0, atol=1e-6)
    assert np.all(m[after, sig["left.current"]] == tr[k - 1, sig["left.current"]])
    noise = m[after, sig["cylinder.position"]] - tr[after, sig["cylinder.position"]]
    assert 0.7e-4 < np.std(noise) < 1.3e-4
    assert np.all(np.isnan(m[after, sig["right.current"]]))
    assert "right.current" not in seen[k] and "right.current" in seen[k - 1]
    # 2.5 ms at a 1 ms period: 3 periods (rounded up, never early).
    j = sig["left.spool_position"]
    assert np.array_equal(m[k + 3:, j], tr[k:-3, j])
    assert all(math.isfinite(v) for s in seen for v in s.values())


def test_a_sensor_frozen_before_the_first_sample_holds_the_first_sample(rig):
    rig.inject(fault(rig, "freeze", "cylinder.position"))
    run = run_lockstep(rig, lambda t, m: {"left": 0.7, "right": 0.5}, 0.2)
    j = rig.signals.index("cylinder.position")
    assert run.true[-1, j] > 1e-3
    assert np.all(run.measured[:, j] == run.true[0, j])


def test_cylinder_jam_holds_the_piston_and_the_valves_hold_pressure_against_it(rig):
    """A seized linkage: the piston stops where it is although the controller drives it; the
    chambers no longer move, so each valve settles at its own set pressure; cleared, it moves."""
    run_lockstep(rig, hold(0.7, 0.5), 0.05)                      # moving toward +x
    rig.inject(fault(rig, "cylinder_jam", "cylinder"))
    x_jam = rig.sample()[rig.signals.index("cylinder.position")]
    run = run_lockstep(rig, hold(0.9, 0.3), 0.3)
    x = run.signal("cylinder.position")
    assert np.all(x == x_jam) and np.all(run.signal("cylinder.velocity") == 0.0)
    assert run.signal("left.pressure")[-1] - run.signal("right.pressure")[-1] > 50 * BAR   # each at its set point
    assert rig.status().faults == ("cylinder_jam@cylinder",)
    rig.clear("cylinder", "cylinder_jam")
    run = run_lockstep(rig, hold(0.9, 0.3), 0.05)
    assert run.signal("cylinder.position")[-1] > x_jam + 1e-4


def test_cylinder_friction_resists_a_small_pressure_difference(rig):
    """Worn, binding seals: a Coulomb friction well above the force a small duty difference makes
    slows the piston to a creep (the friction is smoothed over friction_velocity, so below it it
    acts as a steep viscous term); the healthy cylinder moves with the same commands."""
    healthy = run_lockstep(rig, hold(0.55, 0.5), 0.3)
    moved = abs(healthy.signal("cylinder.position")[-1])
    rig.reset()
    rig.inject(fault(rig, "cylinder_friction", "cylinder", friction=20000.0))
    binding = run_lockstep(rig, hold(0.55, 0.5), 0.3)
    assert moved > 1e-3
    assert abs(binding.signal("cylinder.position")[-1]) < 0.2 * moved
