"""The simulation core: the model interface, composition, the generated integrators, and the
compiled and plain-Python paths of one source."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pcv_sim.jit import enabled
from pcv_sim.params import default_params
from pcv_sim.plant.mass_spring import mass_spring
from pcv_sim.simulation.compile import INTEGRATORS, ORDERS
from pcv_sim.simulation.reference import VALVE_ATOL, integrate_reference
from pcv_sim.simulation.rest import rest_state
from pcv_sim.simulation.simulator import Simulator
from pcv_sim.simulation.system import CompositionError, compose
from pcv_sim.simulation.valve import valve_system

REPO = Path(__file__).resolve().parents[2]
BAR = 1e5
PS = 200e5


def two_valves_and_a_piston():
    """Two simplified valves feeding the chambers of a small spring-loaded piston: each valve's
    load flow is the piston's displacement flow, the piston feels both valves' pressures."""
    params = default_params()
    piston = mass_spring("piston", area=1e-4, mass=1.0, stiffness=2e5, damping=2000.0, x_min=-5e-3, x_max=5e-3)
    plant = compose(
        [valve_system(params, "simplified", "left"), valve_system(params, "simplified", "right"), piston],
        [("left.pressure", "piston.pressure_a"), ("right.pressure", "piston.pressure_b"),
         ("piston.flow_a", "left.load_flow"), ("piston.flow_b", "right.load_flow")])
    rest = rest_state(params, "simplified", 0.5)
    x0 = np.concatenate([rest.state, rest.state, [0.0, 0.0]])
    w0 = np.array([rest.current, rest.current, 0.0])
    return plant, x0, w0


def test_composite_signals_are_named_and_wired():
    plant, _, _ = two_valves_and_a_piston()
    assert plant.inputs == ("left.duty_cycle", "left.supply_pressure", "left.load_volume",
                            "right.duty_cycle", "right.supply_pressure", "right.load_volume")
    assert plant.states[:4] == ("left.flux_linkage", "left.spool_position", "left.spool_velocity", "left.pressure")
    assert plant.states[-2:] == ("piston.position", "piston.velocity")
    assert plant.index("output", "right.current") == 4
    assert [s.position for s in plant.stops] == [1, 5, 8]


@pytest.mark.parametrize(("connections", "match"), [
    ([("left.current", "piston.pressure_a")], r"direct feedthrough"),
    ([("left.pressure", "piston.pressure_c")], r"piston has no input 'pressure_c'"),
    ([("left.pressure", "piston.pressure_a"), ("right.pressure", "piston.pressure_a")], r"connected twice"),
    ([("nosuch.pressure", "piston.pressure_a")], r"unknown system"),
    ([("left", "piston.pressure_a")], r"accepted is 'system.signal'"),
])
def test_bad_connections_are_refused_with_the_reason(connections, match):
    params = default_params()
    systems = [valve_system(params, "simplified", "left"), valve_system(params, "simplified", "right"),
               mass_spring("piston", area=1e-4, mass=1.0, stiffness=1e5, damping=100.0)]
    with pytest.raises(CompositionError, match=match):
        compose(systems, connections)


def test_two_valves_and_a_piston_at_the_fixed_step_agree_with_radau():
    """The composed system integrated together at 0.1 ms (Heun) against scipy's Radau on the same
    composite right-hand side: a 0.5 -> 0.7 duty step on the left valve moves the piston."""
    plant, x0, w0 = two_valves_and_a_piston()
    sim = Simulator(plant, 1e-4, "rk2")
    sim.x[:], sim.W[:] = x0, w0
    v = default_params().circuit.load_volume
    u_step = np.array([0.7, PS, v, 0.5, PS, v])
    n = 1500
    out = sim.run(np.array([0]), u_step[None, :], np.arange(0, n + 1, 10))
    times = np.arange(0, n + 1, 10) * 1e-4
    atol = np.array(list(VALVE_ATOL[:4]) * 2 + [1e-12, 1e-9])
    _xs, ys = integrate_reference(plant, x0, lambda t: u_step, [], times, atol=atol, workspace=w0)
    left, right = plant.index("output", "left.pressure"), plant.index("output", "right.pressure")
    position = plant.index("output", "piston.position")
    # It did something: the left pressure rose by ~50 bar and pushed the piston toward b.
    assert ys[left, -1] - ys[left, 0] > 40 * BAR
    assert ys[position, -1] > 1e-4
    assert np.max(np.abs(out[:, left] - ys[left])) < 0.05 * BAR
    assert np.max(np.abs(out[:, right] - ys[right])) < 0.05 * BAR
    assert np.max(np.abs(out[:, position] - ys[position])) < 1e-3 * abs(ys[position, -1])


@pytest.mark.parametrize("name", INTEGRATORS)
def test_generated_integrators_have_their_order(name):
    """The damped oscillator m x'' + c x' + k x = A dp from rest, against its closed form."""
    m, c, k, a, dp = 1.0, 4.0, 400.0, 1e-4, 1e5          # w_n 20 rad/s, zeta 0.1
    sim = Simulator(mass_spring("osc", area=a, mass=m, stiffness=k, damping=c), 1.0, name)
    wn, zeta = math.sqrt(k / m), c / (2 * math.sqrt(k * m))
    wd = wn * math.sqrt(1 - zeta**2)
    t_end = 0.5
    x_ss = a * dp / k
    exact = x_ss * (1 - math.exp(-zeta * wn * t_end) * (math.cos(wd * t_end) + zeta * wn / wd * math.sin(wd * t_end)))

    def error(h: float) -> float:
        s = Simulator(sim.plant, h, name)
        s.u[:] = (dp, 0.0)
        s.advance(round(t_end / h))
        return abs(s.x[0] - exact)

    h = 1e-3 if ORDERS[name] < 4 else 1e-2
    e1, e2, e3 = error(h), error(h / 2), error(h / 4)
    for observed in (math.log2(e1 / e2), math.log2(e2 / e3)):
        assert abs(observed - ORDERS[name]) < 0.2, (name, observed)


def _path_results(code: str, jit: bool) -> dict:
    env = {k: v for k, v in os.environ.items() if k != "_ROS_WHEELS_BOOTSTRAP_COMPLETE"}
    env["PCV_SIM_JIT"] = "1" if jit else "0"
    proc = subprocess.run([sys.executable, "-c", code], env=env, cwd=REPO, capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout)


_SCRIPT = """
import json, numpy as np
from pcv_sim.jit import enabled
from pcv_sim.params import default_params
from pcv_sim.plant.mass_spring import mass_spring
from pcv_sim.simulation.rest import rest_state
from pcv_sim.simulation.simulator import Simulator
from pcv_sim.simulation.system import compose
from pcv_sim.simulation.valve import valve_inputs, valve_integrator, valve_system
out = {"jit": enabled()}
params = default_params()
for kind in ("simplified", "full"):
    valve = Simulator(valve_system(params, kind), params.simulation.time_step, valve_integrator(params, kind))
    rest = rest_state(params, kind, 0.5, integrator=valve.integrator)
    valve.x[:], valve.W[0] = rest.state, rest.current
    valve.u[:] = valve_inputs(params, 0.7, 0.0, params.circuit.supply_pressure)
    valve.advance(300)
    out[kind] = valve.x.tolist() + [float(valve.outputs()[1])]
plant = compose([valve_system(params, "simplified", "left"), valve_system(params, "simplified", "right"),
                 mass_spring("piston", area=1e-4, mass=1.0, stiffness=2e5, damping=2000.0)],
                [("left.pressure", "piston.pressure_a"), ("right.pressure", "piston.pressure_b"),
                 ("piston.flow_a", "left.load_flow"), ("piston.flow_b", "right.load_flow")])
rest = rest_state(params, "simplified", 0.5)
x0 = np.concatenate([rest.state, rest.state, [0.0, 0.0]])
w0 = np.array([rest.current, rest.current, 0.0])
sim = Simulator(plant, 1e-4, "rk4")
sim.x[:], sim.W[:] = x0, w0
v = params.circuit.load_volume
sim.u[:] = (0.7, 200e5, v, 0.5, 200e5, v)
sim.advance(300)
out["composite"] = sim.x.tolist() + sim.outputs().tolist()
print(json.dumps(out))
"""


@pytest.mark.skipif(not enabled(), reason="numba is not installed or PCV_SIM_JIT=0: only the Python path exists")
def test_compiled_and_plain_python_paths_agree_to_rounding():
    compiled, python = _path_results(_SCRIPT, True), _path_results(_SCRIPT, False)
    assert compiled.pop("jit") is True and python.pop("jit") is False
    for key in compiled:
        a, b = np.array(compiled[key]), np.array(python[key])
        # Same arithmetic; numba may fuse multiply-adds (one rounding instead of two), so agreement
        # is to rounding amplified over 300 steps of a stable system, not bit for bit.
        assert np.allclose(a, b, rtol=1e-9, atol=1e-15), (key, a, b)


def _valve_at_rest() -> Simulator:
    from pcv_sim.simulation.valve import valve_inputs

    params = default_params()
    sim = Simulator(valve_system(params), params.simulation.time_step, "rk2")
    rest = rest_state(params, "simplified", 0.5, 0.0, params.circuit.supply_pressure, integrator="rk2")
    sim.u[:] = valve_inputs(params, 0.5, 0.0, params.circuit.supply_pressure)
    sim.x[:] = rest.state
    sim.W[0] = rest.current
    sim.u[0] = 0.7                  # a duty step: the outputs move
    return sim


def test_advance_sample_checks_the_sampled_outputs_against_their_bounds() -> None:
    """`bounds` (lo, hi) on the first sampled outputs: a sample outside them (or NaN) makes the
    returned norm NaN, as a state that ran away does; the sample is written and the steps taken
    all the same, the same numbers as without bounds."""
    select = np.arange(3, dtype=np.int64)
    free, inside, outside = _valve_at_rest(), _valve_at_rest(), _valve_at_rest()
    y_free, y_in, y_out = np.empty(3), np.empty(3), np.empty(3)
    norm = free.advance_sample(50, select, y_free, 1)
    assert math.isfinite(norm)
    assert inside.advance_sample(50, select, y_in, 1, bounds=(y_free - 1.0, y_free + 1.0)) == norm
    lo, hi = np.full(2, -np.inf), np.full(2, np.inf)
    hi[1] = y_free[1] * 0.5         # the current: half of what it is
    assert math.isnan(outside.advance_sample(50, select, y_out, 1, bounds=(lo, hi)))
    assert np.array_equal(y_in, y_free) and np.array_equal(y_out, y_free)
    assert inside.steps == outside.steps == free.steps == 51 and np.array_equal(outside.x, free.x)


def test_bind_hands_the_arrays_to_another_arena_and_unbind_takes_them_back() -> None:
    """What a batch does with a copy's simulator: bound, its arrays are views of another arena
    (stepped there), unbound they are its own again with the values the other arena reached."""
    from pcv_sim.simulation.compile import arena_layout

    sim, other = _valve_at_rest(), _valve_at_rest()
    assert sim.runs_like(other)
    big = np.zeros(2 * len(sim.arena))
    parts = {name: big[len(sim.arena) + a:len(sim.arena) + b] for name, (a, b) in arena_layout(sim.plant).items()}
    sim.bind(parts)
    assert np.array_equal(big[len(sim.arena):], sim.arena) and sim.x.base is big
    sim.u[0] = 0.3                                  # written where the other arena is
    assert parts["u"][0] == 0.3 and sim.arena[arena_layout(sim.plant)["u"][0]] == 0.7
    parts["x"][3] += 1.0                            # stepped there
    sim.unbind()
    assert sim.x.base is sim.arena and sim.u[0] == 0.3 and sim.x[3] == other.x[3] + 1.0


def test_sample_entry_is_advance_sample_without_the_dispatch() -> None:
    """`sample_entry` hands out the compiled code of `advance_sample` without a fed row, for exactly
    the argument types it takes (with numba: not the dispatcher, which types every argument on
    every call): the same numbers, the bounds included; the caller adds the steps."""
    select = np.arange(3, dtype=np.int64)
    lo, hi = np.full(2, -np.inf), np.full(2, np.inf)
    method, entry = _valve_at_rest(), _valve_at_rest()
    y_method, y_entry = np.empty(3), np.empty(3)
    norm = method.advance_sample(40, select, y_method, 2, bounds=(lo, hi))
    fn, (S, Fa, FL) = entry.sample_entry()
    assert fn(S, Fa, FL, 40, entry.steps, entry.dt, select, y_entry, 2, lo, hi) == norm
    entry.steps += 42
    assert np.array_equal(y_entry, y_method) and np.array_equal(entry.arena, method.arena)
    hi[1] = y_method[1] * 0.5       # a sample beyond its bounds: the NaN norm, as the method's
    assert math.isnan(method.advance_sample(0, select, y_method, 0, bounds=(lo, hi)))
    assert math.isnan(fn(S, Fa, FL, 0, entry.steps, entry.dt, select, y_entry, 0, lo, hi))
    assert np.array_equal(y_entry, y_method) and np.array_equal(entry.arena, method.arena)
    if enabled():
        assert fn is not entry._sample and fn is entry.sample_entry()[0]   # made once
    else:
        assert fn is entry._sample
