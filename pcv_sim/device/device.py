"""The one device: valves and an optional plant in one `Simulator` at one fixed step, and what a
device is around the model. No ROS.

What it composes is data (`ValveSpec` per valve, an optional `PlantSpec`; `spec`): each valve is the
paper's model (`pcv_sim.simulation.valve.valve_system`); a valve wired to the plant (its pressure
state into the plant, the plant's flow and volume into its `load_flow` and `load_volume`, Eq. 15)
is integrated together with it at one step by one integrator (erk2 when any valve needs it), so
the load flow is never a step late; a valve on its own load volume takes `load_flow` as an input.
The emulator (`pcv_sim.device.valve.ValveDevice`) is one valve named `valve` on its own load
volume and no plant; the rig (`pcv_sim.rig.rig.Rig`) is its valves on the steering cylinder. A
device of one valve and no plant names its inputs and signals by their role alone (`duty_cycle`,
`pressure`); any other prefixes them with the valve's name (`left.duty_cycle`, `left.pressure`)
and names the plant's by the plant's (`cylinder.external_force`, `cylinder.position`).

Around the model, written once for every device (here: inputs, duties and watchdogs, stepping;
its other parts are modules beside it, named below):
- inputs (`submit`; per valve `duty_cycle`, `supply_pressure`, `load_flow` on its own volume, the
  options' temperatures; the plant's own): checked on arrival (refused with what is accepted,
  counted; the last valid value stays), queued to the step they act from (`InputTiming` gives
  it from the reception time), in the order they came; `schedule` runs an action at a step and
  `feed` puts a plain input's values in at given steps inside the compiled calls (`feed`);
- one watchdog per valve in model time: waiting (the valve's initial duty) before a first
  command, `watchdog_timeout` s after the last valid command the duty falls to `safe_duty`, the
  next valid command resumes;
- the duty fall-rate limiter per valve (`command.duty_fall_rate_limit`, Sec. 3.2): the duty a
  valve's model gets falls at most that fast (stepping goes one step at a time while it ramps);
- injected faults (`injection`; what a fault is: `pcv_sim.device.faults`): physical ones change
  a valve's (or the plant's) parameters and supply, sensor faults what `measure` makes of a sample;
- the fault state: a state that runs away (non-finite), a step that raises, or a sample or record
  a valve cannot show (`PhysicalLimits`, checked before anything leaves) stops the model
  (`fault`, `composition`) until a restart: nothing is shown of a diverging model;
- rest states (`restarts`; `pcv_sim.simulation.rest.rest_state`): at a start (`reset`) each valve at rest at
  its initial duty and the plant at its rest state (solved once); `prepare`/`install` restart
  the model at rest at a step boundary, with new parameters when given, after a trial run;
- outputs (`outputs`): `run_to` hands back the `Sample`s due (values in the order of `signals`) and calls a
  recorder (`recorder(t_ns, record_values())` every `record_every`-th step, or, where it takes
  them, `record_block(t0_ns, dt_ns, rows)` for a stretch of steps at the full rate); `on_input`
  hears every change of a model input with the step it acts from; the log of what happened.

Everything is deterministic: the same inputs at the same steps give the same numbers bit for bit,
whichever of `advance_to`, `advance_sample` (the lockstep's fused path) and `run_to` steps it.

The node-facing interface: a node adapts any device through these names alone, the same on every
device (what differs between devices is data: the names in `input_names` and `signals`).

- time: `dt`, `dt_ns`, `steps` (model time = steps * dt), `origin_ns` (the stamp of model time 0:
  the node anchors it to its clock), `stamp_ns(step)`, `timing` (`InputTiming`: the step an input
  received now acts from), `skip(n)` (model time passes without computing: a loop that fell
  behind, an external clock that jumped);
- inputs: `input_names` (what `submit` takes), `submit(name, value, at_step)` and
  `submit_fault(text, at_step)` (checked now, acting from max(at_step, `first_open_step()`);
  the reason of a refusal, or None), `counts` (`InputCounts`: accepted and refused per input name
  and `FAULTS`, the last refusal's reason);
- stepping: `run_to(step)` advances to `step` and hands back the `Sample`s due on the way (every
  `sample_every`-th step; each `Sample.values` in the order of `signals`, true values, SI);
  `present_sample()` is the sample at the present step (the first one a node shows); while
  `fault` is set (the model ran away) nothing is computed or handed back, model time goes on;
- outputs: `signals` (names of the sampled values), `measure(sample)` (what the sensors show of it:
  sensor faults applied, NaN = no value, not to be published; once per sample, in order);
- watchdogs and their settings: `valve_names`, `watchdogs`, `set_watchdog_timeout(s)`,
  `set_safe_duty(duty)`, `safe_duty`;
- restarts: `prepare(params=None)` reads the device and builds what `install(prepared)` swaps in
  at a step boundary (the model back at rest; new parameters when given): prepare may run in
  another thread than the stepping, install runs between two `run_to`; `reset()` is a fresh
  start at model time 0 (`keep_time`: the time goes on);
- diagnostics: `status()` (a `DeviceStatus`: commands, duties, watchdogs, faults, counts), `log`
  ((model time, text): faults set and cleared, watchdogs firing and cleared, resets), `fault`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from functools import partial
from typing import Any

import numpy as np

from pcv_sim.device.composition import Composition
from pcv_sim.device.faults import (
    CYLINDER,
    CYLINDER_FAULTS,
    SENSOR_FAULTS,
    VALVE_FAULTS,
    FaultError,
    parse_fault_command,
)
from pcv_sim.device.feed import FedInputs
from pcv_sim.device.injection import FaultInjection
from pcv_sim.device.inputs import NEVER, WatchdogState
from pcv_sim.device.outputs import Outputs
from pcv_sim.device.restarts import Restarts
from pcv_sim.device.spec import (
    MODEL_FAILURES,
    TEMPERATURE_INPUTS,
    DeviceStatus,
    InputCounts,
    InputHook,
    InputKind,
    ModelFault,
    PlantSpec,
    Prepared,
    Recorder,
    Sample,
    ValveSpec,
)
from pcv_sim.errors import CommandError
from pcv_sim.io.topics import DUTY_CYCLE, FAULTS, OIL_TEMPERATURE, SUPPLY_PRESSURE
from pcv_sim.model import kernel
from pcv_sim.params import WatchdogParams, check_field, declarations
from pcv_sim.simulation.duty import check_duty
from pcv_sim.simulation.valve import (
    check_oil_step,
    check_temperature,
)

__all__ = [
    "MODEL_FAILURES", "TEMPERATURE_INPUTS", "Device", "DeviceStatus", "InputCounts", "InputHook", "InputKind",
    "ModelFault", "PlantSpec", "Prepared", "Recorder", "Sample", "ValveSpec",
]


_WATCHDOG_TIMEOUT = declarations(WatchdogParams)["watchdog_timeout"]

class Device(Restarts, FedInputs, FaultInjection, Outputs, Composition):
    """Valves and an optional plant at one fixed step, with everything around the model (see the
    module docstring). Its queue holds inputs (`submit`), fault commands (`submit_fault`) and
    actions (`schedule`). What it composes, its restarts, fed inputs, injected faults and outputs
    are its parts (`composition`, `restarts`, `feed`, `injection`, `outputs`); here its inputs,
    duties and watchdogs, and its stepping.
    """

    def next_due(self) -> int:
        """The first step at which a queued input (a ramping duty's next value among them) or a
        watchdog deadline falls (`inputs.NEVER` if none): where a stretch of compiled steps must stop."""
        return min(self.queue.next_step, *(w.deadline for w in self.watchdogs.values()))

    def status(self) -> DeviceStatus:
        """Diagnostics' view of the device now (copies: it stays as it was when taken)."""
        c = self.counts
        return DeviceStatus(
            self.time, dict(self.commands), dict(self.duties),
            {name: w.state for name, w in self.watchdogs.items()},
            {name: w.fired for name, w in self.watchdogs.items()},
            tuple(f"{kind}@{target}" for target, kind in self.faults), self.fault,
            dict(c.accepted), dict(c.rejected), c.last_rejection)
    # --- inputs --------------------------------------------------------------------------------


    def submit(self, name: str, value: Any, at_step: int | None = None) -> str | None:
        """Check an input now; if valid it takes effect at step max(at_step, `first_open_step()`).
        Returns the reason it was refused (counted, and the last valid value stays), or None.
        ValueError for a name the device does not take."""
        kind = self.inputs.get(name)
        if kind is None:
            raise ValueError(f"unknown input {name!r}; accepted are {', '.join(self.inputs)}")
        try:
            value = kind.check(value)
        except CommandError as err:
            return self._reject(name, str(err))
        self.queue.push(self._acting_step(at_step), (name, value))
        return None

    def submit_fault(self, text: str, at_step: int | None = None) -> str | None:
        """A fault command (`parse_fault_command`: one line of YAML, on a valve, the cylinder or a
        sensor's signal) checked now, acting at step max(at_step, `first_open_step()`) as `submit`'s inputs;
        the reason it was refused (counted), or None. Clearing a fault that is not active then is
        refused (counted) when it is due."""
        try:
            command = parse_fault_command(text, valves=self.valve_names, signals=self.sensors.signals)
            if command.kind in CYLINDER_FAULTS and not self.has_cylinder:
                raise FaultError(f"{command.kind}: this device has no {CYLINDER}; accepted are "
                                 f"{', '.join(VALVE_FAULTS)} (on {', '.join(self.valve_names)}) and "
                                 f"{', '.join(SENSOR_FAULTS)} (on {', '.join(self.sensors.signals)})")
        except FaultError as err:
            return self._reject(FAULTS, str(err))
        self.queue.push(self._acting_step(at_step), (FAULTS, command))
        return None

    def first_open_step(self) -> int:
        """The first step an input may still act from: one whose sample or record nobody has seen
        (every sample shows the inputs in force at its stamp): the present step, or the one after
        the last shown (`shown`)."""
        return max(self.sim.steps, self.shown + 1)

    def _acting_step(self, at_step: int | None) -> int:
        first = self.first_open_step()
        return first if at_step is None else max(int(at_step), first)

    def _reject(self, name: str, reason: str) -> str:
        """Count a refused input (the last valid value stays); returns the reason."""
        counts = self.counts
        counts.rejected[name] = counts.rejected.get(name, 0) + 1
        counts.last_rejection = f"{name}: {reason}"
        if self.keep_rejections:
            self.rejected.append((self.time, f"{name}: {reason}"))
        return reason

    def _apply_due_inputs(self) -> None:
        """Act on everything queued for the present step or before, in the order it was queued."""
        while (due := self.queue.pop_due(self.sim.steps)) is not None:
            if callable(due):
                due()
                continue
            name, value = due
            try:
                if name == FAULTS:
                    self._fault_command(value)
                    if self.on_fault_command is not None:
                        self.on_fault_command(self.sim.steps, value.text)
                else:
                    self.inputs[name].apply(value)
            except (CommandError, FaultError) as err:   # valid on arrival, refused now (e.g. duty_range
                self._reject(name, str(err))           # changed since, a fault cleared that is not active)
                continue
            self.counts.accepted[name] = self.counts.accepted.get(name, 0) + 1

    def schedule(self, t: float, action: Callable[[], None]) -> int:
        """Run `action` (e.g. `lambda: device.inject(f)`) at the first step at or after time t (s);
        returns that step."""
        return self.schedule_step(math.ceil(t / self.dt - 1e-9), action)

    def schedule_step(self, step: int, action: Callable[[], None]) -> int:
        """Run `action` at `step` (the present one if that has passed); returns the step."""
        step = max(self.sim.steps, step)
        self.queue.push(step, action)
        return step

    def input_values(self) -> dict[str, float]:
        """The model's inputs in force now, by the names `on_input` uses (SI)."""
        u = self.sim.u
        out = {}
        for k, name in enumerate(self.valve_names):
            pre = self._prefix[name]
            out[f"{pre}{DUTY_CYCLE}"] = float(u[self._duty_i[k]])
            out[f"{pre}{SUPPLY_PRESSURE}"] = float(u[self._supply_i[k]])
        for name, i in self._plant_i.items():
            out[name] = float(u[i])
        for name, i in zip(self.option_inputs, self._option_in_i):
            out[name] = float(u[i])
        return out

    def _inputs_changed(self) -> None:
        """Every input to the hook (at a restart: they may all have changed)."""
        hook = self.on_input
        if hook is None:
            return
        steps = self.sim.steps
        for name, value in self.input_values().items():
            hook(steps, name, value)

    def _set_load_flow(self, k: int, flow: float) -> None:
        """Valve k's load flow (m^3/s, drawn from its own load volume) from the present step on."""
        self._load_flow[k] = flow
        self.sim.u[self._flow_i[k]] = flow

    def _set_supply(self, k: int, supply: float) -> None:
        """Valve k's supply pressure (Pa) from the present step on; a supply fault holds over it."""
        self._supply[k] = supply
        name = self.valve_names[k]
        if any(t == name and not f.sensor for (t, _), f in self.faults.items()):
            self._apply_valve_faults(name)
        else:
            self.sim.u[self._supply_i[k]] = supply
            if self.on_input is not None:
                self.on_input(self.sim.steps, f"{self._prefix[name]}{SUPPLY_PRESSURE}", supply)

    def _put_plant_input(self, name: str, value: float) -> None:
        self.sim.u[self._plant_i[name]] = value
        if self.on_input is not None:
            self.on_input(self.sim.steps, name, value)

    def temperature(self, valve: str, name: str) -> float:
        """A valve option's temperature input in force (K; see `set_temperature`)."""
        return float(self.sim.u[self.plant.index("input", f"{valve}.{name}")])

    def set_temperature(self, valve: str, name: str, temperature: Any) -> None:
        """A valve option's temperature input (`ambient_temperature` of a lumped coil, R33;
        `oil_temperature` of an oil with `fluid.temperature: input`, R34; K) from the present step
        on. CommandError for a valve without that input (naming the YAML key that brings it), a
        temperature beyond -60 .. 200 degC, or an oil too cold for an explicit step. The spool's
        damping pole follows the oil (the exponential step's rate, R34), also under a fault."""
        k = self.valve_names.index(valve)
        params = self.valve_specs[k].params
        inputs = kernel.layout(params, self.kind).inputs
        where = self._prefix[valve].replace(".", ": ")
        if name not in inputs[len(kernel.INPUTS):]:
            if name not in TEMPERATURE_INPUTS:
                raise CommandError(f"{where}temperature input {name!r}: accepted are {', '.join(TEMPERATURE_INPUTS)}")
            raise CommandError(f"{where}no {name.replace('_', ' ')} input; the valve YAML's "
                               f"{TEMPERATURE_INPUTS[name]} brings it")
        value = check_temperature(self._what(valve, name), temperature)
        if name == OIL_TEMPERATURE:
            off = self._p_off[k]
            p = self.sim.P[off:off + kernel.N_PARAMS]
            check_oil_step(params, p, self.dt, self._exact_spool[k], value)
            if self._exact_spool[k]:
                rate = kernel.spool_rate(value, p)
                self._healthy[k][kernel.V_RATE] = rate
                self.sim.P[off + kernel.V_RATE] = rate
                self.sim.refresh_rates()
        self.sim.u[self.plant.index("input", f"{valve}.{name}")] = value
        if self.on_input is not None:
            self.on_input(self.sim.steps, f"{self._prefix[valve]}{name}", value)
    # --- duties and watchdogs ------------------------------------------------------------------


    def set_duty(self, valve: str, duty: Any) -> None:
        """The duty command of `valve` from the present step on; CommandError (logged, the last
        valid command stays) unless it is within the valve's command.duty_range."""
        rng = self._ranges.get(valve)
        if rng is None:
            self.valve_names.index(valve)              # ValueError naming it, as for any unknown valve
        assert rng is not None
        lo, hi = rng
        if type(duty) is float and lo <= duty <= hi:   # the common case: what check_duty would return
            d = duty
        else:
            try:
                d = check_duty(duty, (lo, hi))
            except CommandError as err:
                self._reject(f"{self._prefix[valve]}{DUTY_CYCLE}", str(err))
                raise
        self._take_command(valve, d)

    def _take_command(self, valve: str, duty: float) -> None:
        """A valid duty command (checked) acts on `valve` from the present step on."""
        self.commands[valve] = duty
        self.duties[valve] = duty
        self._put_duty(valve, duty)
        if self.watchdogs[valve].command(self.sim.steps):
            self._note(f"{valve}: watchdog cleared by a valid command")

    def _put_duty(self, valve: str, duty: float) -> None:
        """`duty` is in force for `valve` from the present step on: its model input gets it, through
        the fall-rate limiter (which starts from the duty of the last step computed)."""
        sim = self.sim
        k = self._k[valve]
        i = self._duty_i[k]
        lim = self._limiters[k]
        if lim.rate is not None:
            if self._lim_step[k] != sim.steps:
                lim.value = float(sim.u[i])
                self._lim_step[k] = sim.steps
            target, duty = duty, lim.peek(duty, self.dt)
            if duty != target and self._ramp_at[k] != sim.steps + 1:
                # The next step's duty, one step further: queued, so that every stepping path
                # (this device's, the lockstep's fast paths) stops there.
                self._ramp_at[k] = sim.steps + 1
                self.queue.push(sim.steps + 1, partial(self._ramp_step, k))
        sim.u[i] = duty
        if self.on_input is not None:
            self.on_input(sim.steps, f"{self._prefix[valve]}{DUTY_CYCLE}", duty)

    def _ramp_step(self, k: int) -> None:
        """A step of a falling duty's ramp: valve k's duty for this step, from the last step's toward
        the duty in force (`FallRateLimiter.peek`; the next step queued while it has not arrived)."""
        if self._lim_step[k] != self.sim.steps:     # else an input at this step set it (and queued the next)
            name = self.valve_names[k]
            self._put_duty(name, self.duties[name])

    def _check_watchdogs(self) -> None:
        """Fire the watchdogs whose deadline is the present step: their valves get the safe duty."""
        steps = self.sim.steps
        for name, watchdog in self.watchdogs.items():
            if watchdog.check(steps):
                safe = self.safe_duty
                self.duties[name] = safe
                self._put_duty(name, safe)
                self._note(f"{name}: watchdog fired, duty -> {safe:g}")

    def duty_held(self, valve: str) -> float:
        """The duty in force for `valve` by its watchdog's state: the command while commands come,
        the safe duty once it fired, the valve's initial duty before a first command."""
        state = self.watchdogs[valve].state
        if state == WatchdogState.FIRED:
            return self.safe_duty
        if state == WatchdogState.WAITING:
            return self._initial_duty(self.valve_specs[self.valve_names.index(valve)])
        return self.commands[valve]

    def set_watchdog_timeout(self, timeout: float) -> None:
        """Seconds of model time without a valid duty command before the safe duty; 0 = off.
        ParameterError (a ValueError) from the one declaration, `WatchdogParams`, for anything
        else (nothing changes)."""
        timeout = check_field("watchdog_timeout", _WATCHDOG_TIMEOUT, timeout)
        for name, watchdog in self.watchdogs.items():
            if watchdog.set_timeout(round(timeout / self.dt)):
                self.duties[name] = self.commands[name]
                self._put_duty(name, self.commands[name])

    def set_safe_duty(self, duty: float) -> None:
        """The duty a fired watchdog holds, from the present step on; CommandError (nothing
        changes) unless it is within every valve's command.duty_range."""
        for name in self.valve_names:
            duty = check_duty(duty, self.duty_range(name))
        self.safe_duty = duty
        for name, watchdog in self.watchdogs.items():
            if watchdog.holds:
                held = self.duty_held(name)
                if held != self.duties[name]:
                    self.duties[name] = held
                    self._put_duty(name, held)
    # --- stepping ------------------------------------------------------------------------------


    def _advance(self, n: int) -> None:
        """n compiled steps with the present inputs."""
        self.sim.advance(n)

    def advance_to(self, step: int) -> None:
        """Integrate to `step`, running queued and fed inputs and the watchdogs at their steps; those
        due at `step` itself are applied (they act from there on). ModelFault (and `fault` set) if
        the state runs away."""
        sim = self.sim
        while True:
            self._due()
            if sim.steps >= step:
                break
            try:
                self._advance(min(step, self._next_due()) - sim.steps)
            except MODEL_FAILURES as err:
                self._fail(f"model step failed ({type(err).__name__}: {err})")
            self._check_finite()

    def advance_sample(self, step: int, after: int = 0, out: np.ndarray | None = None) -> np.ndarray:
        """`advance_to(step)`, `sample()`, then `after` more steps with the same inputs: the same
        numbers as those calls, in one compiled call when no input falls due before the last step
        (the lockstep's hot path: a call costs about as much as five steps). Returns the sample at
        `step` (in `out` when given: a float64 array of the signals' length); the device is then at
        `step + after`, or at `step` if an input fell due on the way (the caller checks `steps`).
        ModelFault (and `fault` set) if the state runs away or the sample is no valve's; ValueError
        for an `out` of another type, shape or layout (the compiled call would misread it)."""
        if out is not None and (out.dtype != np.float64 or out.shape != (len(self.signal_outputs),)
                                or not out.flags.c_contiguous):
            raise ValueError(f"out: accepted is a C-contiguous float64 array of the {len(self.signal_outputs)} "
                             f"signals; got {out.dtype} {out.shape}{'' if out.flags.c_contiguous else ', strided'}")
        now = self.sim.steps
        other = self._due_step(feed=False)
        if other <= now or self.planned_until() <= now:
            self._due()                                # inputs due now act over the whole stretch
            other = self._due_step(feed=False)
        if step >= now and step + after < min(other, self.planned_until(step)):
            # Nothing falls due on the way but a fed row at `step` itself (in the same call, after
            # the steps to it, before the sample): the planned stretch's one compiled call.
            if out is None:
                out = np.empty(len(self.signal_outputs))
            self.sample_planned(step, out, after)
            return out
        self.advance_to(step)
        if out is None:
            return self.sample()
        out[:] = self.sample()
        return out

    # --- the planned stretch: control periods in which nothing but duties falls due ---------

    def planned_until(self, at: int | None = None) -> int:
        """The first step at which a queued input or action (a ramping duty's next value among
        them) or a fed input falls due, a fed input at step `at` itself excepted (a later one than
        the present step: `sample_planned` takes it with the sample); `inputs.NEVER` if none. The
        watchdogs' deadlines are `next_due`'s."""
        fs = self._feed_steps
        r = self._feed_next
        fed = fs[r] if r < len(fs) else NEVER
        if fed == at and fed > self.sim.steps:
            fed = fs[r + 1] if r + 1 < len(fs) else NEVER
        return min(self.queue.next_step, fed)

    def direct_duties(self) -> dict[str, tuple[float, float, int]]:
        """valve -> (lowest, highest duty, the index of its duty among the model inputs, `sim.u`)
        for the valves whose valid duty may be written straight into the model in a planned
        stretch: there it has `set_duty`'s effect once the valve's watchdog is told the command's
        step (`watchdogs[valve].command(step)`) before the device's own path runs again, while
        that watchdog is armed (neither waiting for a first command nor fired: a command changes
        that state, `set_duty`). A valve with a fall-rate limiter is not among them: its duty
        ramps step by step (`set_duty`)."""
        out = {}
        for k, name in enumerate(self.valve_names):
            if k not in self._limited:
                lo, hi = self._ranges[name]
                out[name] = (lo, hi, self._duty_i[k])
        return out

    def sample_planned(self, at: int, out: np.ndarray, after: int = 0, taken: float | None = None) -> None:
        """The steps to `at`, the sample at `at` into `out` (a C-contiguous float64 array of the
        signals' length: not checked, the compiled call takes it as it is, `Simulator.sample_entry`),
        then `after` more steps with the same inputs, in one compiled call (the lockstep's hot path,
        and `advance_sample`'s); a fed input due at `at` goes in before the sample. The
        caller has made sure nothing else falls due before `at + after` is passed
        (`planned_until(at)`, the watchdogs' `next_due`). `taken`: a batch made that call over
        this device's arrays (`pcv_sim.rig.batch`: the sample in `out`) and returned `taken`; here
        only what follows it. ModelFault (and `fault` set) when the model runs away or the sample
        is none a valve can show (its physical limits, checked in the compiled call): the same
        error as on every path of the device."""
        r = self._feed_next
        if taken is not None or r >= len(self._feed_steps) or self._feed_steps[r] != at:
            self._stretch(at, out, after, taken)
            return
        sim = self.sim
        try:            # the row in the same call, after the steps to `at`, before the sample
            norm = sim.advance_sample(at - sim.steps, self.signal_outputs, out, after,
                                      feed=(self._feed_i, self._feed_v, r), bounds=self.signal_bounds)
        except MODEL_FAILURES as err:
            self._fail(f"model step failed ({type(err).__name__}: {err})")
        self._feed_row(r, at)                          # already in the model; for the hook and the bookkeeping
        if not math.isfinite(norm):
            self._planned_failed(at, after, out)

    def planned_stretch(self) -> Callable[[int, np.ndarray, int, float | None], None]:
        """The planned stretch's call as one function bound to the device's compiled call:
        `stretch(at, out, after=0, taken=None)` is `sample_planned(at, out, after, taken)` for a
        period at which no fed input is due either (the caller has made sure: `planned_until()`
        beyond `at + after`, and the watchdogs' `next_due`), without the method's lookups; what the
        lockstep calls every control period of such a stretch. `sample_planned` calls it for every
        period without a fed row: the same numbers and errors. Bound to the present simulator:
        take it again after a restart with new parameters (`install`)."""
        return self._stretch

    def _bind_stretch(self) -> None:
        """`planned_stretch`'s function over the simulator's compiled call as it is now (its arena,
        tables, the signals and their bounds: `Composition._planned_call`)."""
        fn, S, Fa, FL, dt, select, lo, hi = self._planned_call
        sim = self.sim
        isfinite = math.isfinite

        def stretch(at: int, out: np.ndarray, after: int = 0, taken: float | None = None) -> None:
            if taken is None:
                now = sim.steps
                try:
                    taken = fn(S, Fa, FL, at - now, now, dt, select, out, after, lo, hi)
                except MODEL_FAILURES as err:
                    self._fail(f"model step failed ({type(err).__name__}: {err})")
            sim.steps = at + after
            if not isfinite(taken):
                self._planned_failed(at, after, out)

        self._stretch = stretch

    def _planned_failed(self, at: int, after: int, out: np.ndarray) -> None:
        """A planned call's norm was not finite: the sample first (at its step: none a valve cannot
        show leaves), then the state reached; each raises, naming the time and the active faults."""
        sim = self.sim
        sim.steps = at
        self._check_limits(out)
        sim.steps = at + after
        self._check_finite()

    def run_to(self, step: int) -> list[Sample]:
        """Advance to `step` (inputs, fault commands and watchdog deadlines acting at their steps;
        those due at `step` itself act before its sample) and return the samples of the multiples
        of `sample_every` passed on the way, the one at `step` included; the recorder gets every
        `record_every`-th step. A model that runs away sets `fault` (no exception): the samples
        before it are returned, none after it; while `fault` is set model time passes without
        computing (inputs still act at their steps).

        Convention (the same in the recorder, replay and docs): the sample of step k is stamped
        k * dt and shows the state at that instant with the inputs in force from step k on; an
        input due at step k acts on the interval [k, k + 1) and on the sample of step k."""
        out: list[Sample] = []
        if self.fault is not None:
            self._idle_to(step)
            return out
        sim = self.sim
        per = self.sample_every
        recorder = self.recorder
        every = self.record_every
        traced = recorder is not None and every == 1 and hasattr(recorder, "record_block")
        try:
            self._due()
            while sim.steps < step:
                s = sim.steps
                due = self._next_due()
                stop = min(step, s + per - s % per, due)
                if recorder is not None and not traced:
                    stop = min(stop, s + every - s % every)
                if traced and stop - s > 1:
                    # A recorder of every step takes the steps before `stop` as one block of outputs
                    # (inputs unchanged within it): one compiled call for the stretch.
                    self._traced_block(stop - 1)
                sampled = stop % per == 0
                recorded = recorder is not None and stop % every == 0
                values = None
                try:
                    if (sampled or recorded) and due > stop:
                        # Nothing falls due at `stop`: the steps and its outputs in one compiled call
                        # (the same numbers as advance, then sample).
                        values = np.empty(len(self.signal_outputs))
                        if not math.isfinite(sim.advance_sample(stop - sim.steps, self.signal_outputs, values,
                                                                bounds=self.signal_bounds)):
                            self._check_finite()
                            self._check_limits(values)
                        self._outputs_taken(sim.Y)
                    else:
                        self._advance(stop - sim.steps)
                        self._check_finite()
                except MODEL_FAILURES as err:
                    self._fail(f"model step failed ({type(err).__name__}: {err})")
                if values is None:
                    # A sample at step k shows the state at k and the inputs in force from k on: inputs
                    # and a watchdog timeout due at k act before it (right-continuous, as replay does).
                    self._due()
                    if sampled or recorded:
                        values = self.sample()
                        self._check_limits(values)  # nothing a valve cannot produce leaves the device
                if values is not None:
                    self.shown = stop
                    if sampled:
                        out.append(Sample(stop, values))
                    if recorded and recorder is not None:
                        recorder(self.stamp_ns(stop), self._record_values(sim.Y))
        except ModelFault:
            self._idle_to(step)
        if out:
            self.last_sample = out[-1]
        return out

    def _traced_block(self, last: int) -> None:
        """Steps to `last` in one compiled call, their outputs to the recorder's `record_block`
        (checked first: a row no valve can show is the fault, at its step)."""
        sim = self.sim
        first = sim.steps + 1
        targets = np.arange(first, last + 1, dtype=np.int64)
        rows = self._run_rows(_NO_STEPS, np.empty((0, len(sim.u))), targets)
        if not self._all_outputs:
            rows = rows[:, self.signal_outputs]
        self._check_rows(rows, targets)
        self.recorder.record_block(self.stamp_ns(first), self.dt_ns, rows)  # type: ignore[union-attr]

    def _idle_to(self, step: int) -> None:
        """To `step` without computing (the fault state): what falls due acts at its step."""
        sim = self.sim
        while sim.steps < step:
            sim.steps = min(step, max(self._due_step(ramp=False), sim.steps + 1))
            self._due()

    def _next_due(self) -> int:
        """The first step after the present one at which a queued input, a watchdog deadline, a ramping
        duty or a fed input falls (a large number if none): where a batch of compiled steps must stop."""
        return max(self._due_step(), self.sim.steps + 1)

    def _due_step(self, *, feed: bool = True, ramp: bool = True) -> int:
        """The first step at which a queued input, a watchdog deadline, (with `ramp`) a ramping duty
        or (with `feed`) a fed input falls, pending now or later (NEVER if none)."""
        nxt = self.next_due() if ramp else min(self.queue.next_step, *(w.deadline for w in self.watchdogs.values()))
        if feed and self._feed_next < len(self._feed_steps):
            nxt = min(nxt, self._feed_steps[self._feed_next])
        return nxt

    def _due(self) -> None:
        """What falls due at the present step, in the devices' order: queued inputs and actions,
        fed inputs, then the watchdogs."""
        self._apply_due_inputs()
        steps = self.sim.steps
        while self._feed_next < len(self._feed_steps) and self._feed_steps[self._feed_next] <= steps:
            self._feed_row(self._feed_next, steps)
        self._check_watchdogs()


_NO_STEPS = np.empty(0, dtype=np.int64)
