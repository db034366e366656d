"""Stiff reference solutions with scipy (Radau/BDF/LSODA) on the same right-hand side.

The full model's restrictor/chamber pole is about -2.6e8 1/s: no explicit method survives a
0.1 ms step, so offline it runs here. The simplified model runs here too, as the yardstick for
the fixed-step real-time stepper.

End stops (Sec. 4.2) are hybrid: the solver stops at a stop crossing (event), the impact sets
v = 0 (inelastic), and integration resumes; while the force pushes into the stop the
right-hand side holds the spool (ValveModel.derivatives).
"""

from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp

from pcv_sim.analysis.static import zero_flow_equilibrium
from pcv_sim.errors import PcvSimError
from pcv_sim.model.valve import ValveModel
from pcv_sim.simulation.duty import DutyProfile
from pcv_sim.simulation.trajectory import Trajectory

__all__ = ["simulate_reference", "ReferenceError"]


class ReferenceError(PcvSimError, RuntimeError):
    """The stiff solver failed."""


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
    """Simulate `profile` from t = 0 to t_end, sampled every `sample_time` s.

    Starts at the zero-flow equilibrium of the profile's first duty unless `initial_state` is
    given. The input is integrated piecewise between the profile's breakpoints, so the solver
    never steps across a jump.
    """
    ps = model.p_supply if supply_pressure is None else supply_pressure
    if initial_state is None:
        eq = zero_flow_equilibrium(model, profile.effective(0.0), ps)
        initial_state = model.initial_state(profile.effective(0.0), eq.spool_position, eq.pressure)
    i_last = [model.steady_current(profile.effective(0.0))]

    def rhs(t: float, y: np.ndarray) -> list[float]:
        dy, i = model.derivatives(t, tuple(y), profile.effective(t), load_flow, ps, i_last[0])
        i_last[0] = i
        return list(dy)

    def hit_min(t: float, y: np.ndarray) -> float:
        return y[1] - model.x_min

    def hit_max(t: float, y: np.ndarray) -> float:
        return y[1] - model.x_max

    hit_min.terminal, hit_min.direction = True, -1  # type: ignore[attr-defined]
    hit_max.terminal, hit_max.direction = True, 1  # type: ignore[attr-defined]

    n = int(round(t_end / sample_time)) + 1
    t_samples = np.arange(n) * sample_time
    # Absolute tolerances per state: flux ~0.1 Wb, x ~1e-4 m, v ~1e-2 m/s, pressures ~1e7 Pa.
    scale = {0: 1e-9, 1: 1e-12, 2: 1e-9, 3: 1e-3, 4: 1e-3}
    atol = [scale[k] for k in range(len(initial_state))]
    out_t, out_y = [], []
    y = np.array(initial_state, dtype=float)
    bps = profile.breakpoints(t_end)
    if model.switched:  # the coil voltage jumps at every PWM edge: on at k T, off at k T + D T
        edges = [k * model.pwm_period + off for k in range(int(t_end / model.pwm_period) + 1)
                 for off in (0.0, profile.effective(k * model.pwm_period) * model.pwm_period)]
        bps = sorted(set(bps) | {e for e in edges if 0.0 < e < t_end})
    eps = 1e-9 * sample_time
    for t0, t1 in zip(bps[:-1], bps[1:]):
        t = t0
        last = t1 >= t_end - eps
        while t < t1 - eps:
            # Samples owned by this segment: [t, t1), and t_end itself in the last one. t1 is
            # always evaluated too, so the next segment starts from the state at t1 exactly.
            own = t_samples[(t_samples >= t - eps) & ((t_samples < t1 - eps) | (last & (t_samples <= t1 + eps)))]
            t_eval = np.unique(np.clip(np.append(own, t1), t, t1))
            sol = solve_ivp(
                rhs, (t, t1), y, method=method, t_eval=t_eval, rtol=rtol, atol=atol,
                events=(hit_min, hit_max), max_step=model.pwm_period / 20 if model.switched else np.inf,
            )
            if sol.status < 0:
                raise ReferenceError(f"{method} failed at t={t:.6g} s: {sol.message}")
            keep = np.isin(sol.t, np.clip(own, t, t1))
            out_t.append(sol.t[keep])
            out_y.append(sol.y[:, keep])
            if sol.status == 1:  # a stop was hit: inelastic impact (v = 0), then carry on
                which = 0 if sol.t_events[0].size else 1
                t = float(sol.t_events[which][0])
                y = np.array(sol.y_events[which][0])
                y[1], y[2] = (model.x_min, model.x_max)[which], 0.0
            else:
                y = sol.y[:, -1]
                t = t1
    ts = np.concatenate(out_t)
    ys = np.concatenate(out_y, axis=1)
    ts, idx = np.unique(ts, return_index=True)
    ys = ys[:, idx]
    currents = np.empty_like(ts)
    i_guess = model.steady_current(profile.effective(0.0))
    for k, tk in enumerate(ts):
        i_guess = model.current(ys[0, k], ys[1, k], model.coil_voltage(profile.effective(tk), tk), i_guess)
        currents[k] = i_guess
    duty = np.array([profile.effective(tk) for tk in ts])
    return Trajectory(ts, duty, currents, ys[3], ys[1])
