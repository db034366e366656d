"""Stiff reference solutions with scipy (Radau/BDF/LSODA) on the core's own right-hand side.

`integrate_reference` runs any composite of systems (`pcv_sim.simulation.system`) with its
compiled right-hand side under a stiff variable-step solver: the yardstick for every fixed-step
integrator (the full model's damping chamber has a pole near -2.6e8 1/s). Inputs are a function
of time with the instants where they jump or kink (`breakpoints`): the solver never steps across
one. End stops (`System.stops`) are hybrid: the solver stops at a stop crossing (event), the
impact sets the velocity to 0 (inelastic), and integration resumes; while the force pushes into
the stop the right-hand side holds the position.

`simulate_reference` is the valve's form of it: a duty profile (with the fall-rate limiter's
ramps), constant load flow and supply pressure, samples on a regular grid.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable

import numpy as np
from scipy.integrate import solve_ivp

from pcv_sim.errors import PcvSimError
from pcv_sim.model.valve import ValveModel
from pcv_sim.simulation.duty import DutyProfile
from pcv_sim.simulation.rest import rest_state
from pcv_sim.simulation.simulator import Simulator
from pcv_sim.simulation.system import Composite, System
from pcv_sim.simulation.trajectory import Trajectory
from pcv_sim.simulation.valve import valve_system

__all__ = ["VALVE_ATOL", "ReferenceError", "integrate_reference", "simulate_reference"]

#: Absolute tolerances of the valve's states: flux ~0.1 Wb, x ~1e-4 m, v ~1e-2 m/s, p, p_c ~1e7 Pa.
VALVE_ATOL = (1e-9, 1e-12, 1e-9, 1e-3, 1e-3)


class ReferenceError(PcvSimError, RuntimeError):
    """The stiff solver failed."""


def integrate_reference(
    plant: Composite | System,
    x0: np.ndarray,
    inputs: Callable[[float], np.ndarray],
    breakpoints: list[float],
    sample_times: np.ndarray,
    *,
    atol: np.ndarray | float = 1e-9,
    rtol: float = 1e-8,
    method: str = "Radau",
    max_step: float = np.inf,
    workspace: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """States (n_states x n_samples) and outputs (n_outputs x n_samples) at `sample_times`.

    `inputs(t)` gives the external inputs in force at t (right-continuous); `breakpoints` are the
    instants where they jump or kink, and the solver restarts there from the state at that
    instant exactly. Outputs at a sample use the inputs in force at the sample time.
    """
    sim = Simulator(plant, 1e-4, "rk2")     # its compiled right-hand side; the step is not used
    if workspace is not None:
        sim.W[:] = workspace
    stops = sim.plant.stops
    events = []
    for st in stops:
        for bound, direction in ((st.lo, -1), (st.hi, 1)):
            def event(t: float, y: np.ndarray, k: int = st.position, b: float = bound) -> float:
                return float(y[k] - b)

            event.terminal, event.direction = True, direction  # type: ignore[attr-defined]
            events.append((event, st, bound))
    sample_times = np.asarray(sample_times, dtype=float)
    t_end = float(sample_times[-1])
    bps = sorted({float(b) for b in breakpoints if sample_times[0] < b < t_end} | {float(sample_times[0]), t_end})
    eps = 1e-9 * max(1e-4, float(np.min(np.diff(sample_times))) if len(sample_times) > 1 else 1e-4)
    n_x = len(sim.plant.states)
    out_x = np.full((n_x, len(sample_times)), np.nan)
    y = np.array(x0, dtype=float)

    def rhs(t: float, yy: np.ndarray, u: np.ndarray) -> np.ndarray:
        return sim.derivatives(t, yy, u)

    for k, (t0, t1) in enumerate(itertools.pairwise(bps)):
        u = np.asarray(inputs(0.5 * (t0 + t1)), dtype=float)     # constant or linear within: the mid value
        kinked = not np.array_equal(u, np.asarray(inputs(t0), dtype=float))
        last = k == len(bps) - 2
        t = t0
        while t < t1 - eps:
            inside = (sample_times < t1 - eps) | (last & (sample_times <= t1 + eps))
            own = np.nonzero((sample_times >= t - eps) & inside)[0]
            t_eval = np.unique(np.clip(np.append(sample_times[own], t1), t, t1))

            def fun(tt: float, yy: np.ndarray, u: np.ndarray = u, kinked: bool = kinked) -> np.ndarray:
                return rhs(tt, yy, np.asarray(inputs(tt), float) if kinked else u)

            sol = solve_ivp(fun, (t, t1), y, method=method, t_eval=t_eval, rtol=rtol, atol=atol,
                            events=[e for e, _, _ in events] or None, max_step=max_step)
            if sol.status < 0:
                raise ReferenceError(f"{method} failed at t={t:.6g} s: {sol.message}")
            for j, ts in enumerate(sol.t):
                hit = np.nonzero(np.abs(sample_times[own] - ts) <= eps)[0]
                if hit.size:
                    out_x[:, own[hit[0]]] = sol.y[:, j]
            if sol.status == 1:       # a stop was hit: inelastic impact, then carry on
                which = next(i for i, te in enumerate(sol.t_events) if te.size)
                _, st, bound = events[which]
                t = float(sol.t_events[which][0])
                y = np.array(sol.y_events[which][0])
                y[st.position], y[st.velocity] = bound, 0.0
            else:
                y = sol.y[:, -1]
                t = t1
    outputs = np.empty((len(sim.plant.outputs), len(sample_times)))
    for j, ts in enumerate(sample_times):
        sim.x[:] = out_x[:, j]
        sim.u[:] = inputs(float(ts))
        sim.steps = 0
        outputs[:, j] = sim.outputs_at(float(ts))
    return out_x, outputs


def simulate_reference(
    model: ValveModel,
    profile: DutyProfile,
    t_end: float,
    *,
    sample_time: float = 1e-4,
    load_flow: float = 0.0,
    supply_pressure: float | None = None,
    initial_state: tuple[float, ...] | None = None,
    method: str = "Radau",
    rtol: float = 1e-8,
) -> Trajectory:
    """The valve (`model.kind`) under `profile` from t = 0 to t_end, sampled every `sample_time` s.

    Starts at rest for the profile's first duty unless `initial_state` is given. The duty is the
    profile's effective one (the fall-rate limiter's ramps in continuous time).
    """
    ps = model.p_supply if supply_pressure is None else supply_pressure
    d0 = profile.effective(0.0)
    if initial_state is None:
        rest = rest_state(model.params, model.kind, d0, load_flow, ps)
        x0, i0 = rest.state, rest.current
    else:
        x0, i0 = np.array(initial_state, float), model.steady_current(d0)
    n = round(t_end / sample_time) + 1
    t_samples = np.arange(n) * sample_time
    bps = profile.breakpoints(t_end)
    max_step = np.inf
    if model.switched:  # the coil voltage jumps at every PWM edge: on at k T, off at k T + D T
        edges = [k * model.pwm_period + off for k in range(int(t_end / model.pwm_period) + 1)
                 for off in (0.0, profile.effective(k * model.pwm_period) * model.pwm_period)]
        bps = sorted(set(bps) | {e for e in edges if 0.0 < e < t_end})
        max_step = model.pwm_period / 20

    def inputs(t: float) -> np.ndarray:
        return np.array([profile.effective(t), load_flow, ps, model.params.circuit.load_volume])

    xs, ys = integrate_reference(valve_system(model.params, model.kind), x0, inputs, bps, t_samples,
                                 atol=np.array(VALVE_ATOL[:len(x0)]), rtol=rtol, method=method, max_step=max_step,
                                 workspace=np.array([i0]))
    duty = np.array([profile.effective(tk) for tk in t_samples])
    return Trajectory(t_samples, duty, ys[1], xs[3], xs[1])
