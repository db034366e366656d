"""A batch of rigs (pcv_sim.rig.batch): each copy's run bit for bit its run alone, with its own
parameters, faults at their own onsets, sensor faults, feed, seed and controller; a copy that runs
away or whose controller raises stops alone, the others go on."""
import dataclasses

import numpy as np
import pytest

from pcv_sim.control.steering import PositionController
from pcv_sim.plant import cylinder
from pcv_sim.rig import Rig, RigError, parse_fault, run_lockstep
from pcv_sim.rig.batch import BatchError, batchable, run_lockstep_batch

DURATION = 0.3


def setpoint(t):
    return 0.0 if t < 0.02 else 0.01


def preload(params, factor):
    """The rig with both valves' spring preload scaled (another variant of the same structure)."""
    valves = tuple(dataclasses.replace(v, params=dataclasses.replace(v.params, spool=dataclasses.replace(
        v.params.spool, spring_preload=v.params.spool.spring_preload * factor))) for v in params.valves)
    return dataclasses.replace(params, valves=valves)


def fault(rig, t, kind, target, values=None, until=None):
    f = parse_fault(kind, target, values or {}, valves=rig.valve_names, signals=rig.signals)
    rig.schedule(t, lambda: rig.inject(f))
    if until is not None:
        rig.schedule(until, lambda: rig.clear(target, kind))


def diverge(rig, t):
    """From t on the piston weighs 0.1 kg, too light for the explicit step: the state runs away
    within a few control periods (at 0.105 s: the coil current has no solution), while the batch
    steps it."""
    def act():
        p = rig.sim.P[rig.plant.offsets("p")[len(rig.valve_names)]:].copy()
        p[cylinder.MASS] = 0.1
        rig.sim.set_parameters(len(rig.valve_names), p)
    rig.schedule(t, act)


SETUPS = {
    # a physical fault at its own onset per copy, a sensor fault that comes and goes (the dict form
    # meanwhile), a fed external force, another seed and other valves
    0: lambda rig: fault(rig, 0.05, "coil_short", "left", {"resistance_factor": 0.5}),
    1: lambda rig: (fault(rig, 0.13, "supply_drop", "right", {"pressure": 1.0e7}),
                    fault(rig, 0.08, "noise", "left.current", {"std": 0.05}, until=0.1),
                    rig.feed("cylinder.external_force", [1000, 2005], [150.0, -80.0])),
}


def make_rigs(rig_params, setups):
    rigs = [Rig(preload(rig_params, 1.0 + 0.03 * c), seed=c + 1) for c in range(len(setups))]
    for rig, setup in zip(rigs, setups, strict=True):
        setup(rig)
    return rigs


def alone(rig_params, setups, controllers):
    out = []
    for rig, controller in zip(make_rigs(rig_params, setups), controllers, strict=True):
        try:
            out.append((run_lockstep(rig, controller, DURATION, setpoint=setpoint), rig))
        except (RigError, ZeroDivisionError) as err:
            out.append((err, rig))
    return out


def same_run(a, b):
    assert np.array_equal(a.times, b.times)
    for name in ("true", "measured", "duties", "setpoint"):
        assert np.array_equal(getattr(a, name), getattr(b, name), equal_nan=True), name
    assert a.flags.keys() == b.flags.keys()
    for f in a.flags:
        assert np.array_equal(a.flags[f], b.flags[f], equal_nan=True)
    assert (a.log, a.rejected) == (b.log, b.rejected)


def same_rig(a, b):
    assert a.steps == b.steps and np.array_equal(a.sim.x, b.sim.x, equal_nan=True)
    assert np.array_equal(a.sim.u, b.sim.u) and np.array_equal(a.sim.P, b.sim.P)
    assert (a.fault, a.faults.keys(), a.commands, a.duties) == (b.fault, b.faults.keys(), b.commands, b.duties)


def test_a_batch_runs_each_rig_bit_for_bit_as_alone(rig_params):
    setups = [SETUPS[0], SETUPS[1]]
    expected = alone(rig_params, setups, [PositionController(), PositionController()])
    rigs = make_rigs(rig_params, setups)
    counts = {}
    runs = run_lockstep_batch(rigs, [PositionController(), PositionController()], DURATION,
                              setpoints=[setpoint, setpoint], counts=counts)
    for (want, want_rig), got, rig in zip(expected, runs, rigs, strict=True):
        same_run(want, got)
        same_rig(want_rig, rig)
    assert not np.array_equal(runs[0].true, runs[1].true)
    assert runs[1].log != runs[0].log and np.isnan(runs[1].measured).sum() == 0   # noise, not a dropout
    n = round(DURATION / rig_params.timing.control_period)
    # most periods in the batch: the others are those around the faults' onsets, the fed force's
    # steps, the sensor fault, the watchdogs' deadlines and the last sample
    assert counts["together"] > 0.8 * n and counts["together"] + counts["alone"] == n + 1


def test_a_copy_that_runs_away_fails_alone_and_the_others_go_on(rig_params):
    """Its run ends as alone (RigError, the same time and reason, the rig in its fault state); the
    other copy's run is its run alone."""
    setups = [SETUPS[0], lambda rig: diverge(rig, 0.1)]
    expected = alone(rig_params, setups, [PositionController(), PositionController()])
    assert isinstance(expected[1][0], RigError)
    rigs = make_rigs(rig_params, setups)
    counts = {}
    runs = run_lockstep_batch(rigs, [PositionController(), PositionController()], DURATION,
                              setpoints=[setpoint, setpoint], counts=counts)
    same_run(expected[0][0], runs[0])
    assert isinstance(runs[1], RigError) and str(runs[1]) == str(expected[1][0])
    assert rigs[1].fault == expected[1][1].fault and rigs[1].steps == expected[1][1].steps
    assert counts["retaken"] >= 1          # it ran away inside a batched call: the period taken again alone


def test_a_controller_that_raises_stops_its_copy_alone(rig_params, fragile_controller):
    Fragile = fragile_controller
    setups = [SETUPS[1], SETUPS[0]]
    expected = alone(rig_params, setups, [Fragile(0.07), PositionController()])
    rigs = make_rigs(rig_params, setups)
    runs = run_lockstep_batch(rigs, [Fragile(0.07), PositionController()], DURATION, setpoints=[setpoint, setpoint])
    assert isinstance(runs[0], ZeroDivisionError)
    same_rig(expected[0][1], rigs[0])
    same_run(expected[1][0], runs[1])


def test_rigs_of_another_structure_do_not_share_a_batch(rig_params):
    other = dataclasses.replace(rig_params, timing=dataclasses.replace(rig_params.timing, control_period=2e-3))
    rigs = [Rig(rig_params), Rig(other)]
    assert "control period" in batchable(rigs)
    with pytest.raises(BatchError, match="cannot share a batch: rig 1 has another control period"):
        run_lockstep_batch(rigs, [None, None], 0.01)


def test_a_batch_knows_whether_its_compiled_code_is_at_hand(rig_params):
    """What the campaign's default (`--batch 0`) decides by: a batch that ran in this process is at
    hand; one of 7 copies of this rig never compiled is not (a compile: minutes)."""
    from pcv_sim.rig.batch import compiled_before

    rigs = [Rig(rig_params), Rig(rig_params)]
    run_lockstep_batch(rigs, [PositionController(), PositionController()], 0.01)
    assert compiled_before(rigs[0], 2)
    assert not compiled_before(rigs[0], 7)
