"""Drive a model with a recorded input timeline and sample it at the recorded times.

Each recorded command takes effect at its timestamp and holds until the next one (zero-order
hold, as the emulator applies commands). Times are integer ns relative to the first duty
command; the model starts there at rest (the equilibrium for the first inputs).

- ``full``: the full model (with damping chamber) on scipy's Radau, integrated piecewise
  between input changes with the settings of :func:`pcv_sim.simulation.reference.simulate_reference`
  (rtol 1e-8, per-state atol, inelastic end stops as events). ``simulate_reference`` itself
  holds load flow and supply pressure constant and returns no end state, so it cannot be
  chained over a recorded timeline; this loop is its piecewise form.
- ``simplified`` with ``solver="stepper"``: the emulator's own engine,
  :class:`~pcv_sim.simulation.stepper.RealTimeStepper` (fixed 0.1 ms Heun), stepped to each
  command; a command between two steps takes effect at the next step.
- ``simplified`` with ``solver="fast"``: exponential Heun at a longer step (default 0.5 ms):
  the spool's viscous damping, the only stiff term of the simplified model (pole -B/m, about
  -7.5e3 1/s), is integrated exactly over the step, the rest with Heun. For quick replays of
  long bags; :mod:`bench/replay_speed.py` and the tests measure its distance from the stepper.

Outputs at a command instant are right-continuous: the coil current there already sees the new
coil voltage (it jumps with it, reading R27).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Literal

import numpy as np
import numpy.typing as npt
from scipy.integrate import solve_ivp

from pcv_sim.analysis.static import EquilibriumError, equilibrium_at_flow
from pcv_sim.errors import CommandError
from pcv_sim.io.topics import CURRENT, DUTY_CYCLE, LOAD_FLOW, PRESSURE, SPOOL_POSITION, SUPPLY_PRESSURE
from pcv_sim.model.valve import ValveModel
from pcv_sim.params import ValveParams, replace_param
from pcv_sim.replay.errors import ReplayError
from pcv_sim.replay.recording import Series
from pcv_sim.simulation.duty import FallRateLimiter
from pcv_sim.simulation.stepper import RealTimeStepper, check_load_flow, check_supply_pressure

__all__ = ["InputTimeline", "ModelRun", "Solver", "input_timeline", "run_model"]

Solver = Literal["auto", "stepper", "fast", "radau"]
_NS = 1_000_000_000


@dataclass(frozen=True)
class InputTimeline:
    """Piecewise-constant inputs: ``duty[k]``, ``load_flow[k]``, ``supply_pressure[k]`` hold
    from ``t_ns[k]`` (relative ns, ``t_ns[0] == 0``, strictly increasing) to the next change."""

    t_ns: npt.NDArray[np.int64]
    duty: npt.NDArray[np.float64]
    load_flow: npt.NDArray[np.float64]
    supply_pressure: npt.NDArray[np.float64]

    def __len__(self) -> int:
        return len(self.t_ns)


def input_timeline(
    inputs: Mapping[str, Series], default_load_flow: float, default_supply: float
) -> tuple[InputTimeline, list[str]]:
    """Merge the input series into one timeline of changes; returns it and notes.

    Repeated equal values (a rig recording its command every sample) add no change. Several
    commands at the same instant: the last one in the bag holds.
    """
    notes: list[str] = []
    series = {DUTY_CYCLE: inputs[DUTY_CYCLE]}
    defaults = {LOAD_FLOW: default_load_flow, SUPPLY_PRESSURE: default_supply}
    for role in (LOAD_FLOW, SUPPLY_PRESSURE):
        if role in inputs:
            series[role] = inputs[role]
            first = int(inputs[role].t_ns[0])
            if first > 0:
                notes.append(
                    f"{role}: first message {first / 1e6:.3f} ms after the first duty command; "
                    f"the configured {defaults[role]:g} holds until then"
                )
    times = np.unique(np.concatenate([s.t_ns for s in series.values()] + [np.zeros(1, np.int64)]))
    columns: dict[str, npt.NDArray[np.float64]] = {}
    for role in (DUTY_CYCLE, LOAD_FLOW, SUPPLY_PRESSURE):
        if role not in series:
            columns[role] = np.full(len(times), defaults[role])
            continue
        s = series[role]
        idx = np.searchsorted(s.t_ns, times, side="right") - 1  # last message at or before
        col = np.where(idx >= 0, s.value[np.clip(idx, 0, None)], defaults.get(role, math.nan))
        columns[role] = col.astype(np.float64)
    stacked = np.stack([columns[DUTY_CYCLE], columns[LOAD_FLOW], columns[SUPPLY_PRESSURE]])
    change = np.ones(len(times), dtype=bool)
    change[1:] = np.any(stacked[:, 1:] != stacked[:, :-1], axis=0)
    return (
        InputTimeline(
            times[change].astype(np.int64),
            columns[DUTY_CYCLE][change],
            columns[LOAD_FLOW][change],
            columns[SUPPLY_PRESSURE][change],
        ),
        notes,
    )


@dataclass(frozen=True)
class ModelRun:
    """Model outputs at the requested times (relative ns), SI units."""

    t_ns: npt.NDArray[np.int64]
    outputs: Mapping[str, npt.NDArray[np.float64]]
    model: str
    solver: str
    segments: int
    notes: tuple[str, ...] = ()


def _check_inputs(timeline: InputTimeline, params: ValveParams) -> None:
    lo, hi = params.command.duty_range
    for k in range(len(timeline)):
        t = timeline.t_ns[k] / 1e9
        d = float(timeline.duty[k])
        if not lo <= d <= hi:
            msg = f"duty {d:g} at t = {t:.6f} s is outside command.duty_range {lo:g}..{hi:g}"
            raise ReplayError(msg)
        try:
            check_load_flow(float(timeline.load_flow[k]))
            check_supply_pressure(float(timeline.supply_pressure[k]))
        except CommandError as exc:
            msg = f"input at t = {t:.6f} s: {exc}"
            raise ReplayError(msg) from exc


def _rest_state(model: ValveModel, duty: float, q: float, ps: float) -> tuple[tuple[float, ...], float]:
    try:
        eq = equilibrium_at_flow(model, duty, q, ps)
    except EquilibriumError as exc:
        msg = f"no rest point for the first inputs (duty {duty:g}, load flow {q:g} m^3/s): {exc}"
        raise ReplayError(msg) from exc
    return model.initial_state(duty, eq.spool_position, eq.pressure), eq.current


def run_model(
    params: ValveParams,
    kind: Literal["full", "simplified"],
    timeline: InputTimeline,
    sample_ns: npt.NDArray[np.int64],
    *,
    solver: Solver = "auto",
    fast_step: float = 5e-4,
) -> ModelRun:
    """The model's pressure, current and spool position at ``sample_ns`` (sorted, >= 0).

    ``solver``: ``auto`` = ``radau`` for the full model, ``stepper`` for the simplified one.
    The config's ``command.duty_fall_rate_limit`` applies as in the emulator (stepper only; the
    other solvers refuse a configured limiter rather than ignore it).
    """
    if kind not in ("full", "simplified"):
        msg = f"model {kind!r}: accepted are 'full' and 'simplified'"
        raise ReplayError(msg)
    if solver == "auto":
        solver = "radau" if kind == "full" else "stepper"
    if solver not in ("stepper", "fast", "radau"):
        msg = f"solver {solver!r}: accepted are auto, stepper, fast, radau"
        raise ReplayError(msg)
    if kind == "full" and solver != "radau":
        msg = f"the full model runs only on the stiff solver (radau), not {solver!r}"
        raise ReplayError(msg)
    if solver != "stepper" and params.command.duty_fall_rate_limit is not None:
        msg = (
            f"the config sets command.duty_fall_rate_limit = "
            f"{params.command.duty_fall_rate_limit:g} 1/s; only the simplified model's stepper "
            f"applies it (--model simplified --solver stepper); record the limited command "
            f"instead, or set it to null"
        )
        raise ReplayError(msg)
    _check_inputs(timeline, params)
    sample_ns = np.asarray(sample_ns, dtype=np.int64)
    if sample_ns.size and (sample_ns[0] < 0 or np.any(np.diff(sample_ns) <= 0)):
        msg = "sample times must be >= 0 and strictly increasing"
        raise ReplayError(msg)
    if solver == "radau":
        model = ValveModel(params, kind)
        return _run_radau(model, timeline, sample_ns)
    if solver == "stepper":
        return _run_stepper(params, timeline, sample_ns)
    return _run_fast(params, timeline, sample_ns, fast_step)


# --- stiff piecewise integration ----------------------------------------------------------------


def _run_radau(model: ValveModel, tl: InputTimeline, sample_ns: npt.NDArray[np.int64]) -> ModelRun:
    n_states = 5 if model.kind == "full" else 4
    state, i0 = _rest_state(model, float(tl.duty[0]), float(tl.load_flow[0]), float(tl.supply_pressure[0]))
    y = np.array(state, dtype=float)
    scale = (1e-9, 1e-12, 1e-9, 1e-3, 1e-3)[:n_states]  # as simulate_reference: flux, x, v, p, p_c
    out_y = np.empty((n_states, len(sample_ns)))
    seg_of_sample = np.empty(len(sample_ns), dtype=np.int64)
    i_last = [i0]
    ends = np.append(tl.t_ns[1:], max(int(sample_ns[-1]) if sample_ns.size else 0, int(tl.t_ns[-1])) + 1)
    x_min, x_max = model.x_min, model.x_max
    lo = 0
    for k in range(len(tl)):
        a_ns, b_ns = int(tl.t_ns[k]), int(ends[k])
        hi = int(np.searchsorted(sample_ns, b_ns, side="left"))  # samples in [a, b)
        if hi == lo and k == len(tl) - 1:
            break
        duty, q_l, p_s = float(tl.duty[k]), float(tl.load_flow[k]), float(tl.supply_pressure[k])

        def rhs(t: float, yy: npt.NDArray[np.float64], duty: float = duty, q_l: float = q_l,
                p_s: float = p_s) -> list[float]:
            dy, i = model.derivatives(t, tuple(yy), duty, q_l, p_s, i_last[0])
            i_last[0] = i
            return list(dy)

        def hit_min(t: float, yy: npt.NDArray[np.float64]) -> float:
            return float(yy[1] - x_min)

        def hit_max(t: float, yy: npt.NDArray[np.float64]) -> float:
            return float(yy[1] - x_max)

        hit_min.terminal, hit_min.direction = True, -1  # type: ignore[attr-defined]
        hit_max.terminal, hit_max.direction = True, 1  # type: ignore[attr-defined]
        t_samples = sample_ns[lo:hi].astype(np.float64) / _NS
        t, t_b = a_ns / _NS, b_ns / _NS
        done = lo
        while True:
            pending = t_samples[done - lo:]
            t_eval = np.append(pending[pending >= t], t_b)
            sol = solve_ivp(rhs, (t, t_b), y, method="Radau", t_eval=t_eval, rtol=1e-8,
                            atol=scale, events=(hit_min, hit_max))
            if sol.status < 0:
                msg = f"the stiff solver failed at t = {t:.6f} s: {sol.message}"
                raise ReplayError(msg)
            got = sol.t < t_b
            n_got = int(np.count_nonzero(got))
            out_y[:, done:done + n_got] = sol.y[:, got]
            seg_of_sample[done:done + n_got] = k
            done += n_got
            if sol.status == 1:  # a stop was hit: inelastic impact (v = 0), then carry on
                which = 0 if sol.t_events[0].size else 1
                t = float(sol.t_events[which][0])
                y = np.array(sol.y_events[which][0])
                y[1], y[2] = (x_min, x_max)[which], 0.0
                continue
            y = sol.y[:, -1]
            break
        lo = hi
    outputs = _outputs(model, tl, sample_ns, out_y, seg_of_sample, i0)
    return ModelRun(sample_ns, outputs, model.kind, "radau", len(tl))


def _outputs(
    model: ValveModel,
    tl: InputTimeline,
    sample_ns: npt.NDArray[np.int64],
    ys: npt.NDArray[np.float64],
    seg: npt.NDArray[np.int64],
    i0: float,
) -> dict[str, npt.NDArray[np.float64]]:
    """Pressure, position and the coil current (Eqs. 1-8 solved at each sample)."""
    current = np.empty(len(sample_ns))
    i_guess = i0
    for j in range(len(sample_ns)):
        v_s = model.coil_voltage(float(tl.duty[seg[j]]), sample_ns[j] / _NS)
        i_guess = model.current(float(ys[0, j]), float(ys[1, j]), v_s, i_guess)
        current[j] = i_guess
    return {PRESSURE: ys[3].copy(), CURRENT: current, SPOOL_POSITION: ys[1].copy()}


# --- the emulator's stepper ------------------------------------------------------------------


def _run_stepper(params: ValveParams, tl: InputTimeline, sample_ns: npt.NDArray[np.int64]) -> ModelRun:
    try:
        st = RealTimeStepper(params, duty=float(tl.duty[0]))
        st.reset(float(tl.duty[0]), float(tl.load_flow[0]), float(tl.supply_pressure[0]))
    except EquilibriumError as exc:
        msg = f"no rest point for the first inputs (duty {tl.duty[0]:g}, load flow {tl.load_flow[0]:g} m^3/s): {exc}"
        raise ReplayError(msg) from exc
    model = st.model
    dt_ns = int(round(params.simulation.time_step * _NS))
    if abs(dt_ns / _NS - params.simulation.time_step) > 1e-15:
        msg = f"simulation.time_step {params.simulation.time_step!r} s is not a whole number of ns"
        raise ReplayError(msg)
    # Commands take effect at the first step boundary at or after their time.
    cmd_step = -(-tl.t_ns // dt_ns)
    off_grid = int(np.count_nonzero(tl.t_ns % dt_ns))
    # Each sample needs the state at the step at or before it and, between steps, the next one.
    below = sample_ns // dt_ns
    frac = (sample_ns - below * dt_ns) / dt_ns
    needed = np.unique(np.concatenate([below, below[frac > 0] + 1]))
    values: dict[int, tuple[float, float, float]] = {}
    i_guess = st._i  # noqa: SLF001 - the stepper's last current: a good Newton start
    k_cmd = 0
    n_cmd = len(tl)
    for step in needed.tolist():
        # Apply every command due up to this step, advancing between them.
        while k_cmd < n_cmd and cmd_step[k_cmd] <= step:
            target = int(cmd_step[k_cmd])
            if target > st.steps:
                st.advance(target - st.steps)
            st.set_duty(float(tl.duty[k_cmd]))
            st.set_load_flow(float(tl.load_flow[k_cmd]))
            st.set_supply_pressure(float(tl.supply_pressure[k_cmd]))
            k_cmd += 1
        if step > st.steps:
            st.advance(step - st.steps)
        lam, x, _, p = st.state
        # The duty in force from this step on (after the limiter): outputs are right-continuous.
        i_guess = model.current(lam, x, model.coil_voltage(st.duty, st.time), i_guess)
        values[step] = (p, i_guess, x)
    p_out = np.empty(len(sample_ns))
    i_out = np.empty(len(sample_ns))
    x_out = np.empty(len(sample_ns))
    for j, (b, f) in enumerate(zip(below.tolist(), frac.tolist())):
        v0 = values[b]
        if f == 0.0:
            p_out[j], i_out[j], x_out[j] = v0
        else:
            v1 = values[b + 1]
            p_out[j] = v0[0] + f * (v1[0] - v0[0])
            i_out[j] = v0[1] + f * (v1[1] - v0[1])
            x_out[j] = v0[2] + f * (v1[2] - v0[2])
    notes = []
    if off_grid:
        notes.append(
            f"{off_grid} input change(s) fell between the stepper's {dt_ns / 1e6:g} ms steps and "
            f"took effect at the next step (as in the emulator)"
        )
    if np.any(frac > 0):
        notes.append(
            f"{int(np.count_nonzero(frac > 0))} sample time(s) between steps: model outputs "
            f"interpolated linearly between the neighbouring steps"
        )
    return ModelRun(sample_ns, {PRESSURE: p_out, CURRENT: i_out, SPOOL_POSITION: x_out},
                    "simplified", "stepper", len(tl), tuple(notes))


# --- exponential Heun for quick simplified replays ---------------------------------------------


def _run_fast(params: ValveParams, tl: InputTimeline, sample_ns: npt.NDArray[np.int64], h: float) -> ModelRun:
    """Simplified model, exponential Heun; commands and samples fall on step boundaries.

    With c = B/m and g = dv/dt + c v (the force per mass without the damping term), the
    velocity obeys v' = -c v + g. Per step: a = f(y_n); predictor: Euler for lam and p, the
    exact response v* = v_n e^{-ch} + g_n phi1(ch) h for v, and x* = x_n + (h g_n - (v* - v_n))/c
    (the exact integral of that v); b = f(y*); corrector: trapezoid for lam and p, the ETD2
    formula v_n e^{-ch} + h phi1 g_n + h phi2 (g* - g_n) for v (g linear over the step), and
    x_n + (h (g_n + g*)/2 - (v_{n+1} - v_n))/c, the exact integral of v under the same g.
    Integrating x with v's endpoints instead (plain trapezoid) makes the error 20x larger,
    since v follows g within 1/c = 0.13 ms.

    Step size: ``h`` (0.5 ms), except where the valve is at rest: an interval of up to 2 h is
    first tried as one step, kept when the predictor/corrector difference in pressure is below
    100 Pa and in position below 0.1 um, else redone in steps of h.
    """
    model = ValveModel(params, "simplified")
    if model.switched:
        msg = "the fast solver needs the averaged PWM (solenoid.pwm: averaged); use --solver stepper"
        raise ReplayError(msg)
    if not 0 < h <= 2e-3:
        msg = f"fast step {h!r} s: accepted is 0 < h <= 2 ms"
        raise ReplayError(msg)
    state, i = _rest_state(model, float(tl.duty[0]), float(tl.load_flow[0]), float(tl.supply_pressure[0]))
    c = model.damping / model.mass
    deriv, x_min, x_max, project = model.derivatives, model.x_min, model.x_max, model.project
    coef: dict[int, tuple[float, float, float]] = {}

    def phis(step_ns: int) -> tuple[float, float, float]:
        hh = step_ns / _NS
        z = c * hh
        e = math.exp(-z)
        phi1 = -math.expm1(-z) / z
        phi2 = (z - 1.0 + e) / (z * z) if z > 1e-4 else 0.5 - z / 6.0
        return e, phi1 * hh, phi2 * hh

    def step(y: tuple[float, float, float, float], t_ns: int, step_ns: int, i: float, duty: float, q_l: float,
             p_s: float) -> tuple[tuple[float, float, float, float], float, float, float]:
        """One step; returns the new state, current guess and the |corrector - predictor| of p, x."""
        got = coef.get(step_ns)
        if got is None:
            got = coef[step_ns] = phis(step_ns)
        e, p1h, p2h = got
        hh = step_ns / _NS
        y0, y1, y2, y3 = y
        (a0, a1, a2, a3), i = deriv(t_ns / _NS, y, duty, q_l, p_s, i)
        g_a = a2 + c * y2
        v_pred = y2 * e + g_a * p1h
        x_pred = y1 + (hh * g_a - (v_pred - y2)) / c
        p_pred = y3 + hh * a3
        (b0, _, b2, b3), i = deriv(t_ns / _NS + hh, (y0 + hh * a0, x_pred, v_pred, p_pred), duty, q_l, p_s, i)
        g_b = b2 + c * v_pred
        hh2 = 0.5 * hh
        v_new = y2 * e + g_a * p1h + (g_b - g_a) * p2h
        x_new = y1 + (hh2 * (g_a + g_b) - (v_new - y2)) / c
        p_new = y3 + hh2 * (a3 + b3)
        if not x_min <= x_new <= x_max:
            x_new, v_new = project(x_new, v_new)
        return (y0 + hh2 * (a0 + b0), x_new, v_new, p_new), i, abs(p_new - p_pred), abs(x_new - x_pred)

    stops = np.unique(np.concatenate([tl.t_ns, sample_ns]))
    h_ns = int(round(h * _NS))
    p_out = np.empty(len(sample_ns))
    i_out = np.empty(len(sample_ns))
    x_out = np.empty(len(sample_ns))
    seg = np.searchsorted(tl.t_ns, stops, side="right") - 1
    is_sample = np.isin(stops, sample_ns)
    y: tuple[float, float, float, float] = (state[0], state[1], state[2], state[3])
    j = 0
    t_ns = 0
    k_now = 0
    duty, q_l, p_s = float(tl.duty[0]), float(tl.load_flow[0]), float(tl.supply_pressure[0])
    calm = False
    steps = 0
    for s_ns, k, want in zip(stops.tolist(), seg.tolist(), is_sample.tolist()):
        remaining = s_ns - t_ns
        if calm and 0 < remaining <= 2 * h_ns:  # at rest: try the interval in one step
            y_try, i_try, dp, dx = step(y, t_ns, remaining, i, duty, q_l, p_s)
            steps += 1
            if dp < 100.0 and dx < 1e-7:
                y, i, t_ns, remaining = y_try, i_try, s_ns, 0
            else:
                calm = False
        while remaining > 0:
            step_ns = h_ns if remaining >= h_ns else remaining
            y, i, dp, dx = step(y, t_ns, step_ns, i, duty, q_l, p_s)
            steps += 1
            calm = dp < 25.0 and dx < 2.5e-8
            t_ns += step_ns
            remaining -= step_ns
        if k != k_now:
            k_now = k
            duty, q_l, p_s = float(tl.duty[k]), float(tl.load_flow[k]), float(tl.supply_pressure[k])
            calm = False
        if want:
            i = model.current(y[0], y[1], duty * model.v_supply, i)
            p_out[j], i_out[j], x_out[j] = y[3], i, y[1]
            j += 1
    return ModelRun(sample_ns, {PRESSURE: p_out, CURRENT: i_out, SPOOL_POSITION: x_out},
                    "simplified", f"fast (exponential Heun, {h * 1e3:g} ms)", len(tl),
                    (f"fast solver: {steps} steps for {t_ns / 1e9:.3f} s",))
