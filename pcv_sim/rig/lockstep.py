"""The lockstep runner: a controller called every control period on that period's samples.

    controller(t, measurements) -> commands

At each control instant t_k = k T (given to the controller as the sample's stamp would give it
to a controller node: integer ns x 1e-9 s) the rig's signals are sampled (true values; the measured ones
after the sensor faults), the controller is called with the measurements (a dict `signal ->
value`, SI; a dropped sample is absent; `setpoint` holds the scenario's setpoint when there is
one) and returns a mapping `valve -> duty` (a valve left out keeps its command, and its watchdog
runs) and, optionally, `flags: {name: number}` which are recorded as `controller.<name>` (e.g.
`fault_detected`). The commands act from step k N + 1 on: the sample at t_k was shown before
they existed, so it shows the inputs in force at t_k (the project's one rule: a sample at step k
shows the inputs in force from k on; an input acts from the first step not yet shown). The rig
then runs to the next instant, and so on: deterministic bit for bit, as fast as the machine
allows. The rig node in lockstep applies a controller's answers at the same step.

A controller may also offer an array form, which the lockstep then calls instead while no sensor
fault is active (a dropped sample has no place in it; the dict form is called then):

    controller.lockstep_arrays(signals, valves) -> (step, commanded, flags) | None
    step(t, samples, out) -> None

`signals` are the rig's signals and `setpoint` last; `samples` a list of that period's values
in that order (NaN for the setpoint when the run has none); `step` writes the duties of the
valves `commanded` and then the values of `flags`, in those orders, into the list `out`. Each
is then taken as the dict form's would be (a refused duty counted, the last valid one kept).
It saves building and parsing two dicts each period; None keeps the dict form.

`lockstep_periods` is the same run as a generator, which a batch of rigs (`pcv_sim.rig.batch`)
drives one control period at a time; alone it never pauses (`run_lockstep`).
"""

from __future__ import annotations

import contextlib
import functools
import math
import operator
import time
from collections.abc import Callable, Generator, Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from pcv_sim.device.inputs import WatchdogState
from pcv_sim.errors import CommandError, PcvSimError
from pcv_sim.io.topics import DUTY_CYCLE
from pcv_sim.rig.profiles import Profile
from pcv_sim.rig.rig import InputHook, Rig

__all__ = ["Batched", "Controller", "ControllerError", "RigRun", "lockstep_periods", "run_lockstep"]

Controller = Callable[[float, Mapping[str, float]], Any]


class ControllerError(PcvSimError, TypeError):
    """The controller returned something that is not a mapping of valve duties."""


@dataclass
class RigRun:
    """The samples of a lockstep run, one row per control instant (SI units)."""

    times: np.ndarray                       # s, k T
    signals: tuple[str, ...]
    true: np.ndarray                        # (n, signals): the physics
    measured: np.ndarray                    # (n, signals): what the controller saw (NaN: dropped)
    duties: np.ndarray                      # (n, valves): the duty in force after each instant (its step + 1)
    valves: tuple[str, ...]
    setpoint: np.ndarray                    # (n,) NaN where none
    flags: dict[str, np.ndarray] = field(default_factory=dict)
    log: list[tuple[float, str]] = field(default_factory=list)
    rejected: list[tuple[float, str]] = field(default_factory=list)
    wall_time: float = 0.0
    sample_walls: np.ndarray | None = None  # perf_counter (s) at each instant's sample: a run over DDS

    @property
    def duration(self) -> float:
        return float(self.times[-1] - self.times[0]) if len(self.times) > 1 else 0.0

    @property
    def real_time_factor(self) -> float:
        return self.duration / self.wall_time if self.wall_time > 0 else math.inf

    def signal(self, name: str, *, measured: bool = False) -> np.ndarray:
        if name in self.flags:
            return self.flags[name]
        if name.endswith(".duty") and name[:-5] in self.valves:
            return self.duties[:, self.valves.index(name[:-5])]
        if name == "setpoint":
            return self.setpoint
        try:
            j = self.signals.index(name)
        except ValueError:
            names = [*self.signals, *(f"{v}.duty" for v in self.valves), "setpoint", *self.flags]
            raise KeyError(f"no signal {name!r}; signals: {', '.join(names)}") from None
        return (self.measured if measured else self.true)[:, j]


def run_lockstep(rig: Rig, controller: Controller | None, duration: float, *,
                 setpoint: Callable[[float], float] | None = None) -> RigRun:
    """Run `rig` from its present state for `duration` s in lockstep with `controller` (None:
    the duties come from the rig's schedule alone). Returns every control instant's samples."""
    periods = lockstep_periods(rig, controller, duration, setpoint=setpoint)
    try:
        next(periods)               # alone, the run never pauses: it returns at once
    except StopIteration as done:
        run: RigRun = done.value
        return run
    raise AssertionError("a lockstep run alone paused")


#: What a batched lockstep run sends a copy at a control period it may take in the batch: the
#: norm the batch's compiled call returned (its sample already in the copy's row); None: the copy
#: takes the period alone.
Batched = float | None


def lockstep_periods(rig: Rig, controller: Controller | None, duration: float, *,
                     setpoint: Callable[[float], float] | None = None, rows: np.ndarray | None = None,
                     batched: bool = False) -> Generator[int, Batched, RigRun]:
    """`run_lockstep` as a generator that returns the run. Alone (`batched` False) it never yields.
    In a batch (`pcv_sim.rig.batch`), at every control period k it yields the period before which
    it could go on in the batch (k when it cannot: something other than its array form's duties
    falls due, a sensor fault is active, the last sample) and is sent the batch's norm after the
    batch took period k for it (its true sample in `rows[k]`, its state stepped one period and the
    step after the sample, in the arrays the batch holds and has bound `rig.sim` to), or None:
    it takes period k alone, on its own arrays. `rows`: the (n + 1, signals) array the true
    samples go into (a new one by default; float64, each row contiguous)."""
    T = rig.params.timing.control_period
    per = rig.params.steps_per_period
    n = round(duration / T)
    k0 = rig.steps
    names = rig.signals
    valves = rig.valve_names
    if rows is not None and (rows.dtype != np.float64 or rows.shape != (n + 1, len(names))
                             or rows.strides[1] != rows.itemsize):
        # (each row goes to the rig's compiled sampling as it is: `Rig.sample_planned`)
        raise ValueError(f"rows: accepted is a ({n + 1}, {len(names)}) float64 array of contiguous rows; got "
                         f"{rows.dtype} {rows.shape} strides {rows.strides}")
    true = np.empty((n + 1, len(names))) if rows is None else rows
    measured: dict[int, np.ndarray] = {}    # the rows a sensor fault made differ from the true ones
    duty_rows: list[Any] = []
    in_force = operator.itemgetter(*valves)
    sp = [math.nan] * (n + 1)
    flags: dict[str, list[float]] = {}
    sensors = rig.sensors
    dt_ns = round(rig.dt * 1e9)
    dt = rig.dt
    advance_sample = rig.advance_sample
    measure = sensors.measure
    sim = rig.sim
    # The periods in which nothing but the controller's commands falls due (no scheduled input,
    # watchdog deadline, or fed input other than one at the sampled step) take the fast path:
    # the rig's planned stretch (one compiled call, `rig.sample_planned`; `rig.planned_stretch`
    # where no fed input is due at all), the commands of the valves the rig lets write their duty
    # straight into the model (`rig.direct_duties`) written there; every other period the rig's
    # own (rig.advance_sample, rig.set_duty). Both give the same numbers bit for bit.
    sample_planned = rig.sample_planned
    stretch = rig.planned_stretch()
    planned_until = rig.planned_until
    watchdogs = [rig.watchdogs[v] for v in valves]
    duty_name = [f"{v}.{DUTY_CYCLE}" for v in valves]
    valve_names = set(valves)
    #: valve -> (lowest, highest duty, input index, position) of the valves whose duty is written
    #: straight into the model: what set_duty checks and writes
    slots: dict[str, tuple[float, float, int, int]] = {
        v: (*direct, valves.index(v)) for v, direct in rig.direct_duties().items()}
    u = sim.u
    # The watchdogs hear the fast path's commands when it ends (`sync`): their deadlines only move
    # later with each command, so a horizon computed from them is early, never late, meanwhile.
    heard: list[int | None] = [None] * len(valves)

    def sync() -> tuple[int, dict[str, float], dict[str, float], InputHook | None, bool]:
        """Tell the watchdogs the commands of the fast path; the step before which nothing but
        the controller's commands falls due (-1 when a watchdog is not armed: waiting for a first
        command, or fired, a command then changes its state and the rig must apply it), and what
        the fast path writes and reads until the next sync (only the rig's path changes them)."""
        for j, step in enumerate(heard):
            if step is not None:
                watchdogs[j].command(step)
                heard[j] = None
        armed = all(w.state in (WatchdogState.OK, WatchdogState.OFF) for w in watchdogs)
        return rig.next_due() if armed else -1, rig.commands, rig.duties, rig.on_input, sensors.active

    horizon, in_command, in_force_now, hook, active = sync()
    array_step, commanded, flag_rows = _array_form(controller, names, valves, flags, n)
    out = [math.nan] * (len(commanded) + len(flag_rows))
    #: Whether the array form commands only valves whose duty is written straight into the model
    #: (else each period's duties go through the rig's set_duty: its stretches are one period).
    direct = all(v in slots for v in commanded)
    #: the array form's valves with their slots, and each flag's row with its place in `out`
    out_slots = [(v, *slots[v]) for v in commanded] if direct else []
    out_flags = [(row, len(commanded) + f) for f, row in enumerate(flag_rows)]
    # The setpoint at every instant before the run, where it is a profile (its segments evaluated
    # in one pass: the same numbers as calling it at each instant).
    sp_all = setpoint.sample([(k0 + k * per) * dt for k in range(n + 1)]) if isinstance(setpoint, Profile) else None

    def refuse(j: int, key: str, value: Any) -> None:
        """A duty the fast path does not write (not a float in the valve's range): its watchdog told
        of the last valid command, then the rig's set_duty refuses it (counted in rig.rejected)."""
        if (step := heard[j]) is not None:
            watchdogs[j].command(step)
            heard[j] = None
        try:                        # (not contextlib.suppress: ~1 us a call on the hot path)  # noqa: SIM105
            rig.set_duty(key, value)
        except CommandError:
            pass

    got: Batched = None
    wall0 = time.perf_counter()
    try:
        k = 0
        while k <= n:
            end = k
            if array_step is not None and direct and hook is None and not active and k < n \
                    and sim.steps <= k0 + k * per:
                # A stretch of periods in which nothing but the array form's duties falls due (the
                # fast path's tests below, made once for the stretch: the step before which a fed
                # input, a queued one or a watchdog deadline falls; the array form's step sees only
                # its samples and its duties are written straight, so nothing it does can queue
                # one). The same numbers as below.
                due = min(horizon, planned_until())
                end = min(n, (due - 2 - k0) // per + 1)       # each k0 + k per + 1 < due
            if batched and end <= k:
                # Not in the batch: this period alone. (The batch may have bound the simulator's
                # arrays to its own, or given them back, while this run waited: u read again.)
                got = yield k
                u = sim.u
            if end > k:
                start = k
                assert array_step is not None
                for k in range(start, end):
                    at = k0 + k * per
                    y = true[k]
                    if batched:             # each period in the batch (got: its norm) or alone (None)
                        got = yield end
                        u = sim.u
                    stretch(at, y, 1, got)
                    now = at + 1
                    t = at * dt
                    measure(t, y)                   # no sensor fault: y itself (kept for a later fault)
                    samples = y.tolist()
                    if sp_all is not None:
                        sp[k] = now_sp = sp_all[k]
                    elif setpoint is not None:
                        sp[k] = now_sp = setpoint(t)
                    else:
                        now_sp = math.nan
                    samples.append(now_sp)
                    array_step((at * dt_ns) * 1e-9, samples, out)
                    for flag_row, f in out_flags:
                        flag_row[k] = float(out[f])
                    for (key, lo, hi, i, j), value in zip(out_slots, out):
                        if type(value) is float and lo <= value <= hi:
                            in_command[key] = in_force_now[key] = u[i] = value      # as set_duty
                            heard[j] = now
                        else:
                            refuse(j, key, value)
                    duty_rows.append(in_force(in_force_now))
                k = end
                continue
            at = k0 + k * per
            answer = k < n and controller is not None
            last = at + 1 if answer else at
            # With a controller the step after the sample (still the old inputs: the answer acts
            # from at + 1) is taken in the same compiled call, when nothing else falls due there.
            fast = sim.steps <= at and last < horizon and last < planned_until(at)
            if fast:
                y = true[k]
                sample_planned(at, y, last - at)
            else:
                horizon, in_command, in_force_now, hook, active = sync()
                y = advance_sample(at, last - at, true[k])
                active = sensors.active             # a sensor fault may have come or gone on the way
            t = at * dt
            m = measure(t, y)
            if m is not y:
                measured[k] = m
            if answer and controller is not None:
                # The time a controller node reads from the sample's stamp (integer ns x 1e-9), so that
                # a callable and a node see the same number to the last bit (steps x dt may differ).
                commands: Iterable[tuple[str, Any]]
                if array_step is not None and not active:
                    samples = m.tolist()
                    if sp_all is not None:
                        sp[k] = now_sp = sp_all[k]
                    elif setpoint is not None:
                        sp[k] = now_sp = setpoint(t)
                    else:
                        now_sp = math.nan
                    samples.append(now_sp)
                    array_step((at * dt_ns) * 1e-9, samples, out)
                    for flag_row, f in out_flags:
                        flag_row[k] = float(out[f])
                    if fast and direct:
                        # rig.set_duty's effect for each valid duty (its watchdog told at the next sync)
                        for (key, lo, hi, i, j), value in zip(out_slots, out):
                            if type(value) is float and lo <= value <= hi:
                                in_command[key] = in_force_now[key] = u[i] = value
                                heard[j] = last
                                if hook is not None:
                                    hook(last, duty_name[j], value)
                            else:
                                refuse(j, key, value)
                        commands = ()
                    else:
                        commands = zip(commanded, out)
                else:
                    # A dropped (NaN) measurement is absent from the controller's dict.
                    measurement = ({s: v for s, v in zip(names, m.tolist()) if not math.isnan(v)} if active
                                   else dict(zip(names, m.tolist())))
                    if setpoint is not None:
                        sp[k] = measurement["setpoint"] = sp_all[k] if sp_all is not None else setpoint(t)
                    answered = controller((at * dt_ns) * 1e-9, measurement)
                    if answered is None:
                        commands = ()
                    elif type(answered) is dict or isinstance(answered, Mapping):
                        commands = answered.items()
                    else:
                        raise ControllerError(f"the controller returned {type(answered).__name__} at t = {t:g} s; "
                                              f"accepted is a mapping valve -> duty ({', '.join(valves)}) "
                                              "with an optional 'flags' mapping")
                taken = sim.steps == at + 1       # the step after the sample was taken with it
                for key, value in commands:
                    slot = slots.get(key)
                    if slot is not None and fast:
                        lo, hi, i, j = slot
                        if type(value) is float and lo <= value <= hi:
                            # rig.set_duty's effect, its watchdog told at the next sync
                            in_command[key] = in_force_now[key] = u[i] = value
                            heard[j] = last
                            if hook is not None:
                                hook(last, duty_name[j], value)
                            continue
                        if (step := heard[j]) is not None:      # its last valid command first
                            watchdogs[j].command(step)
                            heard[j] = None
                    if slot is not None or key in valve_names:
                        if taken:             # nothing else falls due at at + 1: it acts from now
                            try:              # (not contextlib.suppress: ~1 us a call on the hot path)  # noqa: SIM105
                                rig.set_duty(key, value)
                            except CommandError:
                                pass          # counted in rig.rejected; the last valid command stays
                        else:                 # as the rig node schedules an answer: after the step's
                            # timeline inputs, before its watchdog check
                            rig.schedule((at + 1) * dt, functools.partial(_set_duty, rig, key, value))
                    elif key == "flags":
                        for fname, fv in (value if type(value) is dict else dict(value)).items():
                            arr = flags.get(fname)
                            if arr is None:
                                arr = flags[fname] = [math.nan] * (n + 1)
                            arr[k] = float(fv)
                    else:
                        raise ControllerError(f"the controller commanded {key!r} at t = {t:g} s; accepted are the "
                                              f"valves {', '.join(valves)} and 'flags'")
                if not taken:
                    rig.advance_to(at + 1)
            elif setpoint is not None:
                sp[k] = sp_all[k] if sp_all is not None else setpoint(t)
            if not fast:                        # what ran there may have scheduled, fired, armed, reset
                horizon, in_command, in_force_now, hook, active = sync()
            duty_rows.append(in_force(in_force_now))
            k += 1
    finally:
        sync()                                  # the watchdogs know every command, also after an error
    wall = time.perf_counter() - wall0
    times = (k0 + np.arange(n + 1) * per) * rig.dt
    true = np.ascontiguousarray(true)           # a batch's rows are a strided view of its samples
    meas = true.copy()
    for k, values in measured.items():
        meas[k] = values
    duties = np.array(duty_rows, dtype=float).reshape(n + 1, len(valves))
    return RigRun(times, names, true, meas, duties, valves, np.array(sp),
                  {f"controller.{f}": np.array(a) for f, a in flags.items()}, list(rig.log), list(rig.rejected), wall)


def _array_form(controller: Controller | None, signals: tuple[str, ...], valves: tuple[str, ...],
                flags: dict[str, list[float]], n: int
                ) -> tuple[Callable[[float, list[float], list[float]], None] | None, tuple[str, ...],
                           list[list[float]]]:
    """The controller's array form (step, commanded valves, the rows of its flags, added to `flags`),
    or (None, (), []) when it offers none."""
    bind = getattr(controller, "lockstep_arrays", None)
    form = bind((*signals, "setpoint"), valves) if bind is not None and n > 0 else None
    if form is None:
        return None, (), []
    step, commanded, flag_names = form
    commanded, flag_names = tuple(commanded), tuple(flag_names)
    wrong = [v for v in commanded if v not in valves]
    if wrong or len(set(commanded)) != len(commanded) or not callable(step):
        raise ControllerError(f"the controller's array form commands {', '.join(map(repr, commanded))}; accepted "
                              f"is a callable step and each of the valves {', '.join(valves)} at most once")
    if not all(isinstance(f, str) for f in flag_names) or len(set(flag_names)) != len(flag_names):
        raise ControllerError(f"the controller's array form names the flags {flag_names!r}; accepted are "
                              "distinct names (str)")
    rows = [flags.setdefault(f, [math.nan] * (n + 1)) for f in flag_names]
    return step, commanded, rows


def _set_duty(rig: Rig, valve: str, value: Any) -> None:
    with contextlib.suppress(CommandError):     # counted in rig.rejected; the last valid command stays
        rig.set_duty(valve, value)
