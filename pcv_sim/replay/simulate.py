"""Drive a model with a recorded input timeline and sample it at the recorded times.

Each recorded command takes effect at its timestamp and holds until the next one (zero-order
hold, as the emulator applies commands). Times are integer ns relative to the first duty
command; the model starts there at rest (`pcv_sim.simulation.rest.rest_state`, as the emulator).

Solvers (no integrator lives here):

- ``stepper`` (the default, also ``auto``): the emulator itself, its device
  (:class:`~pcv_sim.device.valve.ValveDevice`: the compiled core at the fixed 0.1 ms step, Heun
  for the simplified model, exponential Heun for the full one; the fall-rate limiter; the
  physical limits), started at rest at the recording's first inputs
  (`ValveDevice.start_at_rest`), its watchdog off. The duty and the load flow are fed
  (`feed`: into the model inside the compiled calls, the whole recording in one call), a duty
  through a configured fall-rate limiter and the supply pressure are submitted at their steps,
  and the outputs are taken at the steps the samples need (`sample_at`); a command between two
  steps takes effect at the next step, as in the emulator. ``fast`` is accepted as a name for
  it (the compiled device is faster than the former long-step solver was).
- ``radau``: the stiff variable-step reference (:func:`pcv_sim.simulation.reference.integrate_reference`:
  rtol 1e-8, per-state atol, inelastic end stops as events), integrated piecewise between
  input changes.

Outputs at a command instant are right-continuous: the coil current there already sees the new
coil voltage (it jumps with it, reading R27), as the emulator's samples do.
"""
from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Literal

import numpy as np
import numpy.typing as npt

from pcv_sim.device.spec import ModelFault
from pcv_sim.device.valve import ValveDevice
from pcv_sim.errors import CommandError, ParameterError
from pcv_sim.io.topics import CURRENT, DUTY_CYCLE, LOAD_FLOW, PRESSURE, SPOOL_POSITION, SUPPLY_PRESSURE
from pcv_sim.jit import backend
from pcv_sim.model.statics import EquilibriumError
from pcv_sim.params import ValveParams
from pcv_sim.replay.errors import ReplayError
from pcv_sim.replay.recording import Series
from pcv_sim.simulation.reference import VALVE_ATOL, ReferenceError, integrate_reference
from pcv_sim.simulation.rest import rest_state
from pcv_sim.simulation.valve import check_load_flow, check_supply_pressure, valve_system
from pcv_sim.units import NS_PER_S

__all__ = ["InputTimeline", "ModelRun", "Solver", "input_timeline", "run_model"]

Solver = Literal["auto", "stepper", "fast", "radau"]


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

    ``solver``: ``auto``/``stepper``/``fast`` = the emulator's device running the model ``kind``;
    ``radau`` = the stiff reference. The config's ``command.duty_fall_rate_limit`` applies as in
    the emulator (stepper only; radau refuses a configured limiter rather than ignore it). A
    model that runs away (a sample no valve can show) is a ReplayError.
    ``fast_step`` is accepted for compatibility and not used.
    """
    if kind not in ("full", "simplified"):
        msg = f"model {kind!r}: accepted are 'full' and 'simplified'"
        raise ReplayError(msg)
    if solver not in ("auto", "stepper", "fast", "radau"):
        msg = f"solver {solver!r}: accepted are auto, stepper, fast, radau"
        raise ReplayError(msg)
    if solver == "radau" and params.command.duty_fall_rate_limit is not None:
        msg = (
            f"the config sets command.duty_fall_rate_limit = "
            f"{params.command.duty_fall_rate_limit:g} 1/s; only the stepper applies it "
            f"(--solver stepper); record the limited command instead, or set it to null"
        )
        raise ReplayError(msg)
    _check_inputs(timeline, params)
    sample_ns = np.asarray(sample_ns, dtype=np.int64)
    if sample_ns.size and (sample_ns[0] < 0 or np.any(np.diff(sample_ns) <= 0)):
        msg = "sample times must be >= 0 and strictly increasing"
        raise ReplayError(msg)
    if solver == "radau":
        return _run_radau(params, kind, timeline, sample_ns)
    return _run_stepper(params, kind, timeline, sample_ns)


# --- stiff piecewise integration ----------------------------------------------------------------


def _run_radau(params: ValveParams, kind: str, tl: InputTimeline, sample_ns: npt.NDArray[np.int64]) -> ModelRun:
    try:
        rest = rest_state(params, kind, float(tl.duty[0]), float(tl.load_flow[0]), float(tl.supply_pressure[0]))
    except EquilibriumError as exc:
        msg = f"no rest point for the first inputs (duty {tl.duty[0]:g}, load flow {tl.load_flow[0]:g} m^3/s): {exc}"
        raise ReplayError(msg) from exc
    changes = tl.t_ns.astype(np.float64) / NS_PER_S

    def inputs(t: float) -> np.ndarray:
        k = max(int(np.searchsorted(changes, t + 1e-12, side="right")) - 1, 0)
        return np.array([tl.duty[k], tl.load_flow[k], tl.supply_pressure[k], params.circuit.load_volume],
                        dtype=np.float64)

    times = sample_ns.astype(np.float64) / NS_PER_S
    if times.size == 0 or times[0] > 0.0:
        times = np.concatenate([[0.0], times])
    try:
        xs, ys = integrate_reference(valve_system(params, kind), rest.state, inputs, changes.tolist(), times,
                                     atol=np.array(VALVE_ATOL[:len(rest.state)]), workspace=np.array([rest.current]))
    except ReferenceError as exc:
        msg = f"the stiff solver failed: {exc}"
        raise ReplayError(msg) from exc
    keep = slice(len(times) - len(sample_ns), None)
    outputs = {PRESSURE: xs[3, keep].copy(), CURRENT: ys[1, keep].copy(), SPOOL_POSITION: xs[1, keep].copy()}
    return ModelRun(sample_ns, outputs, kind, "radau", len(tl))


# --- the emulator's device ---------------------------------------------------------------------


def _run_stepper(params: ValveParams, kind: str, tl: InputTimeline, sample_ns: npt.NDArray[np.int64]) -> ModelRun:
    dt_ns = round(params.simulation.time_step * NS_PER_S)
    if abs(dt_ns / NS_PER_S - params.simulation.time_step) > 1e-15:
        msg = f"simulation.time_step {params.simulation.time_step!r} s is not a whole number of ns"
        raise ReplayError(msg)
    try:
        # The emulator's device of this model kind (its integrator as the config gives it for the
        # config's own model, auto's for the other), its watchdog off: the recording's commands are
        # all it gets. Its safe duty is the first command's: its start state is the rest there.
        device = ValveDevice(_of_kind(params, kind), safe_duty=float(tl.duty[0]), watchdog_timeout=0.0)
        device.start_at_rest(float(tl.duty[0]), float(tl.load_flow[0]), float(tl.supply_pressure[0]))
    except EquilibriumError as exc:
        msg = f"no rest point for the first inputs (duty {tl.duty[0]:g}, load flow {tl.load_flow[0]:g} m^3/s): {exc}"
        raise ReplayError(msg) from exc
    except (CommandError, ParameterError) as exc:
        msg = f"the emulator's device does not run this config: {exc}"
        raise ReplayError(msg) from exc
    # Commands take effect at the first step boundary at or after their time.
    cmd_step = -(-tl.t_ns // dt_ns)
    off_grid = int(np.count_nonzero(tl.t_ns % dt_ns))
    # The recording's inputs at their steps: the duty and the load flow fed (into the model inside
    # the compiled calls), a duty through a fall-rate limiter and the supply as queued inputs.
    if params.command.duty_fall_rate_limit is None:
        device.feed(DUTY_CYCLE, cmd_step, tl.duty)
    else:
        for k, d in zip(cmd_step.tolist(), tl.duty.tolist()):
            device.submit(DUTY_CYCLE, d, k)
    device.feed(LOAD_FLOW, cmd_step, tl.load_flow)
    supply = np.flatnonzero(np.diff(tl.supply_pressure)) + 1
    for k, p in zip(cmd_step[supply].tolist(), tl.supply_pressure[supply].tolist()):
        device.submit(SUPPLY_PRESSURE, p, k)
    # Each sample needs the state at the step at or before it and, between steps, the next one.
    below = sample_ns // dt_ns
    frac = (sample_ns - below * dt_ns) / dt_ns
    needed = np.unique(np.concatenate([below, below[frac > 0] + 1]))
    try:
        rows = device.sample_at(needed)
    except ModelFault as exc:
        msg = f"the model ran away: {exc}"
        raise ReplayError(msg) from exc
    signals = [device.signals.index(role) for role in (PRESSURE, CURRENT, SPOOL_POSITION)]
    at = np.searchsorted(needed, below)
    v0 = rows[at][:, signals]
    between = frac > 0
    out = v0.copy()
    if np.any(between):
        v1 = rows[at[between] + 1][:, signals]
        out[between] = v0[between] + frac[between, None] * (v1 - v0[between])
    notes = []
    if off_grid:
        notes.append(
            f"{off_grid} input change(s) fell between the stepper's {dt_ns / 1e6:g} ms steps and "
            f"took effect at the next step (as in the emulator)"
        )
    if np.any(between):
        notes.append(
            f"{int(np.count_nonzero(between))} sample time(s) between steps: model outputs "
            f"interpolated linearly between the neighbouring steps"
        )
    engine = f"stepper: the emulator's {device.sim.integrator} at {device.dt * 1e3:g} ms ({backend()})"
    return ModelRun(sample_ns, {PRESSURE: out[:, 0].copy(), CURRENT: out[:, 1].copy(), SPOOL_POSITION: out[:, 2].copy()},
                    kind, "stepper", len(tl), (engine, *notes))


def _of_kind(params: ValveParams, kind: str) -> ValveParams:
    """`params` running the model `kind`: the config's integrator for its own model, auto's for the other."""
    if kind == params.simulation.model:
        return params
    return dataclasses.replace(params, simulation=dataclasses.replace(params.simulation, model=kind, integrator="auto"))
