"""The emulated device around the model: inputs, watchdog, fault state, samples. No ROS here.

`ValveDevice` is what the ROS node adapts: it owns a `RealTimeStepper` and a step counter (the
device's model time, `steps * dt`), and

- takes inputs (`submit`) that are validated on arrival and take effect at a given step (the
  node passes the step that matches the input's reception time); a refused input is counted
  with its reason and the last valid value stays in force;
- runs the watchdog in model time: `watchdog_timeout` s after the last valid duty command took
  effect, the duty falls to `safe_duty`; the next valid command resumes;
- enters a fault state when the model state goes non-finite, leaves what any valve can produce
  (`PhysicalLimits`: a pressure outside -1 bar .. 2 x the highest supply, a coil current beyond
  2 x supply voltage / coil resistance) or a model step raises (e.g. no coil current solves
  Eq. 2 for a runaway state): it stops stepping and emits no samples (a controller must not read
  a dead sensor, or a diverging model, as a valid one) until `reset()` or new parameters
  (`install`); the limits are checked on every sample and recorder call before it leaves;
- returns samples at every `sample_every`-th step (`run`) and calls an optional recorder
  `recorder(t_ns, signals)` at every `record_every`-th step (the hook for bag logging);
- takes fault commands (`submit_fault`, at their step as any input; `pcv_sim.device.faults`):
  physical faults of the valve change its parameters and supply, sensor faults what `measure`
  makes of a sample (`MEASURED`); a reset or new parameters restart the valve without faults.

Everything is deterministic for a given sequence of (step, input) pairs.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping
from dataclasses import dataclass
from functools import partial
from typing import Protocol

import numpy as np

from pcv_sim.device.device import MODEL_FAILURES, Device, InputKind
from pcv_sim.device.device import Sample as DeviceSample
from pcv_sim.device.inputs import Watchdog, WatchdogState
from pcv_sim.device.sensors import Sensors
from pcv_sim.errors import CommandError
from pcv_sim.io.topics import INPUT_ROLES
from pcv_sim.params import ValveParams
from pcv_sim.simulation.duty import check_duty
from pcv_sim.simulation.stepper import (
    MAX_SUPPLY_PRESSURE,
    RealTimeStepper,
    check_load_flow,
    check_supply_pressure,
    check_temperature,
)
from pcv_sim.units import PA_PER_BAR, bar

__all__ = [
    "INPUTS", "MEASURED", "OPTION_SIGNALS", "SIGNALS", "PhysicalLimits", "Recorder", "Sample", "ValveDevice",
    "WatchdogState", "rest_stepper", "trial_run",
]

#: Input names, as the node's topics are called.
INPUTS = INPUT_ROLES

#: The measured signals of a sample (a sensor fault's targets), as the node's topics are called.
MEASURED = ("pressure", "current", "spool_position")

#: What a recorder receives per sample, SI units: duty fractions, m^3/s, Pa, A, m.
SIGNALS = ("duty_command", "duty", "load_flow", "supply_pressure", "pressure", "current", "spool_position")
#: The options' signals (docs/model.md R33-R35; `pcv_sim.io.topics.OPTION_INTERFACE`): inputs
#: ambient_temperature, oil_temperature (K), outputs coil_temperature (K), coil_resistance (ohm),
#: core_position (m); `signals()` adds those the valve's options bring.
OPTION_SIGNALS = ("ambient_temperature", "oil_temperature", "coil_temperature", "coil_resistance", "core_position")


class Recorder(Protocol):
    """Receives one model sample: t_ns (stamp of the sample's model time), signals by SIGNALS name."""

    def __call__(self, t_ns: int, signals: Mapping[str, float]) -> None: ...


#: Model steps a new rest state is run on trial before it is accepted (20 ms at 0.1 ms): a model
#: that diverges at rest at the present operating point is refused, not installed.
TRIAL_STEPS = 200


@dataclass(frozen=True)
class PhysicalLimits:
    """What a valve of these parameters can show; beyond it the model has diverged (a fault).

    pressure: -1 bar (vacuum, gauge) .. 2 x the highest supply the device accepts or is configured
    with (a reducing valve cannot exceed its supply; the factor leaves room for compression of the
    load by a pushed-in flow). current: |i| <= 2 x supply voltage / coil resistance (the steady
    current at duty 1 is V/R; the factor leaves room for the induced voltage)."""

    pressure_min: float     # Pa
    pressure_max: float     # Pa
    current_max: float      # A

    @classmethod
    def of(cls, params: ValveParams) -> PhysicalLimits:
        sol = params.solenoid
        return cls(-PA_PER_BAR, 2.0 * max(MAX_SUPPLY_PRESSURE, params.circuit.supply_pressure),
                   2.0 * sol.supply_voltage / sol.coil_resistance)

    def problem(self, pressure: float, current: float) -> str | None:
        """Why (pressure, current) is no valve's, or None."""
        if not self.pressure_min <= pressure <= self.pressure_max:
            return (f"pressure {bar(pressure):.4g} bar outside the physical range {bar(self.pressure_min):g} .. "
                    f"{bar(self.pressure_max):g} bar: the model diverged")
        if not abs(current) <= self.current_max:
            return (f"coil current {current:.4g} A beyond the coil's possible +-{self.current_max:.3g} A: "
                    "the model diverged")
        return None


@dataclass(frozen=True)
class Sample:
    """The device's outputs at model step `step` (time step * dt)."""

    step: int
    pressure: float          # Pa, load port
    current: float           # A, coil
    spool_position: float    # m, paper's sign: x > 0 opens pump -> load
    duty: float              # effective duty (after the fall-rate limiter), fraction
    command: float           # duty command in force (the watchdog's safe duty when it has fired)
    options: tuple[float, ...] = ()   # the valve's `option_outputs` (SI: K, ohm, m)


#: The name of the emulator's one valve (its watchdog's key).
VALVE = "valve"


class ValveDevice(Device):
    """One emulated valve: the model stepper plus the device behaviour around it (a `Device` of
    one valve and no plant)."""

    params: ValveParams

    def __init__(
        self, params: ValveParams, *, safe_duty: float = 0.0, watchdog_timeout: float = 0.5,
        sample_every: int = 10, recorder: Recorder | None = None, record_every: int = 1, seed: int = 0,
    ) -> None:
        # The inputs come at any rate for as long as the node runs: refusals are counted, not kept.
        super().__init__(params.simulation.time_step, (VALVE,), 0,
                         safe_duty=check_duty(safe_duty, params.command.duty_range), keep_rejections=False)
        self.params = params
        self.steps = 0
        self.sample_every = _positive_int(sample_every, "sample_every")
        self.recorder = recorder
        self.record_every = _positive_int(record_every, "record_every")
        self.commands[VALVE] = self.duties[VALVE] = self.safe_duty   # the safe duty before any command
        self.load_flow = 0.0
        self.supply_pressure: float | None = None   # None: the parameter file's circuit.supply_pressure
        self.watchdog: Watchdog = self.watchdogs[VALVE]   # the safe duty while it holds (waiting, fired)
        self.set_watchdog_timeout(watchdog_timeout)
        self.last_good: Sample | None = None
        self.limits = PhysicalLimits.of(params)
        #: Active faults by (target, kind); sensor faults on MEASURED, sampled every sample period.
        self.faults = {}
        self.sensors = Sensors(MEASURED, self.sample_every * self.dt, seed)
        self.stepper = rest_stepper(params, self.safe_duty)
        self._healthy = self.stepper.sim.P.copy()
        plant = self.stepper.sim.plant
        #: The options' signals this valve has: (name, index into the model's inputs or outputs, is an input).
        self._option_signals = [(n, plant.inputs.index(f"valve.{n}"), True) for n in OPTION_SIGNALS
                                if f"valve.{n}" in plant.inputs] + [
            (n, plant.outputs.index(f"valve.{n}"), False) for n in OPTION_SIGNALS if f"valve.{n}" in plant.outputs]
        # Every kernel the stepping uses is loaded (or compiled) now: compiled on first use in a
        # loop's first wake it would hold the loop (and its stop check) for seconds, a minute
        # on a busy machine with an empty kernel cache.
        #: The options' inputs and outputs this valve has (OPTION_SIGNALS), and the inputs' values
        #: taken (K; none: the valve YAML's).
        self.option_inputs = tuple(n for n, _, is_input in self._option_signals if is_input)
        self.option_outputs = tuple(n for n, _, is_input in self._option_signals if not is_input)
        #: A sample's values (`run_to`): the measured signals, then the options' outputs.
        self.signals = (*MEASURED, *self.option_outputs)
        self._option_out_i = [i for _, i, is_input in self._option_signals if not is_input]
        self.option_values: dict[str, float] = {}
        duty = InputKind(lambda v: check_duty(v, self.params.command.duty_range),
                         lambda d: self._take_command(VALVE, d))
        self._declare_inputs({
            "duty_cycle": duty,
            "load_flow": InputKind(check_load_flow, self._set_load_flow),
            "supply_pressure": InputKind(check_supply_pressure, self._set_supply_pressure),
            **{name: InputKind(partial(check_temperature, name.replace("_", " ")), partial(self._set_option, name))
               for name in self.option_inputs}})
        self.stepper.warm_up()
        self.last_good = self.sample()

    # --- configuration -----------------------------------------------------------------------

    def duty_range(self, valve: str) -> tuple[float, ...]:
        return self.params.command.duty_range

    @property
    def command(self) -> float:
        """The last valid duty command (the safe duty before any)."""
        return self.commands[VALVE]

    @property
    def watchdog_state(self) -> str:
        return self.watchdog.state

    @property
    def watchdog_fired(self) -> int:
        """How often the watchdog fired."""
        return self.watchdog.fired

    @property
    def watchdog_fired_step(self) -> int | None:
        return self.watchdog.fired_step

    @property
    def duty_applied_step(self) -> int | None:
        """The step at which the last valid duty command took effect."""
        return self.watchdog.command_step

    def prepare(self, params: ValveParams | None = None, integrator: str | None = None) -> RealTimeStepper:
        """A stepper at rest at the present operating point, for new parameters (default: the present
        ones). Raises if it cannot be built, or (ValueError) if it diverges within TRIAL_STEPS at rest.

        Reads the device but changes nothing: it may run in another thread than `run` (it takes
        25-60 ms); `install` then swaps the result in at a step boundary."""
        params = self.params if params is None else params
        if params.simulation.time_step != self.params.simulation.time_step:
            raise ValueError("the model time step cannot change while the device runs")
        duty = self.duty_command_in_force
        check_duty(duty, params.command.duty_range)
        if integrator is None and params is self.params:
            integrator = self.stepper.integrator
        stepper = rest_stepper(params, duty, self.load_flow, self.supply_pressure, integrator=integrator)
        problem = trial_run(stepper, PhysicalLimits.of(params))
        if problem is not None:
            raise ValueError(f"the model faults again at once at rest at duty {duty:g}: {problem}")
        return stepper

    def install(self, stepper: RealTimeStepper) -> str:
        """Swap in a stepper from `prepare`: the model restarts at rest (the equilibrium for the
        command, load flow and supply pressure in force when it was prepared; inputs taken since act
        from now); model time goes on; a fault is cleared. Returns what was done."""
        was = self.fault
        self.params = stepper.params
        self.limits = PhysicalLimits.of(stepper.params)
        self.stepper = stepper
        self._healthy = stepper.sim.P.copy()
        self.faults.clear()
        self.sensors.reset()
        try:
            stepper.set_duty(self.duty_command_in_force)
            stepper.set_load_flow(self.load_flow)
            if self.supply_pressure is not None:
                stepper.set_supply_pressure(self.supply_pressure)
            for name, value in self.option_values.items():
                stepper.set_input(name, value)
        except CommandError as err:      # e.g. duty_range narrowed: keep what prepare() checked
            self.counts.last_rejection = f"after a model restart: {err}"
        self.clear_fault()
        self.last_good = self.sample()
        what = f"model at rest at duty {self.duty_command_in_force:g}, {bar(stepper.pressure):.2f} bar"
        return f"{what} (cleared fault: {was})" if was else what

    # --- inputs ------------------------------------------------------------------------------

    @property
    def duty_command_in_force(self) -> float:
        return self.duty_held(VALVE)

    def first_open_step(self) -> int:
        """The present step has been shown already (sample, recorder): an input that arrives now
        can act from the next step at the earliest."""
        return self.steps + 1

    def _put_duty(self, valve: str, duty: float) -> None:
        self.stepper.set_duty(duty)

    def _waiting_duty(self, valve: str) -> float:
        return self.safe_duty

    def _set_load_flow(self, value: float) -> None:
        self.stepper.set_load_flow(value)
        self.load_flow = value

    def _set_option(self, name: str, value: float) -> None:
        self.stepper.set_input(name, value)
        self.option_values[name] = value

    def _set_supply_pressure(self, value: float) -> None:
        self.supply_pressure = value
        if self.faults:          # a supply fault holds over the input
            self._apply_valve_faults(VALVE)
        else:
            self.stepper.set_supply_pressure(value)

    def _healthy_parameters(self, valve: str) -> np.ndarray:
        return self._healthy

    def _supply_in_force(self, valve: str) -> float:
        return self.params.circuit.supply_pressure if self.supply_pressure is None else self.supply_pressure

    def _put_valve(self, valve: str, parameters: np.ndarray, supply: float, stuck: bool) -> None:
        st = self.stepper
        if stuck:
            st.sim.x[2] = 0.0
        st.sim.set_parameters(0, parameters)
        st.set_supply_pressure(supply)

    def measure(self, sample: DeviceSample) -> np.ndarray:
        """What the sensors show of `sample` (`Device.measure`; sensor faults act on MEASURED, the
        options' outputs are shown as they are)."""
        sensors = self.sensors
        if not sensors.active and not sensors.keeps_history:
            return sample.values
        n = len(MEASURED)
        y = sensors.measure(sample.step * self.dt, sample.values[:n])
        return np.concatenate((y, sample.values[n:]))

    def measure_valve(self, sample: Sample) -> tuple[float, float, float]:
        """What the sensors show of `sample` (MEASURED, sensor faults applied; NaN: no value, not to
        be published). Called once per sample, in order (a delay or noise fault keeps history)."""
        if not self.sensors.active and not self.sensors.keeps_history:
            return sample.pressure, sample.current, sample.spool_position
        y = self.sensors.measure(sample.step * self.dt,
                                 np.array([sample.pressure, sample.current, sample.spool_position]))
        return float(y[0]), float(y[1]), float(y[2])

    def _next_event(self, end: int) -> int:
        s = self.steps
        stop = min(end, s + self.sample_every - s % self.sample_every)
        if self.recorder is not None and (not self._traced() or self.stepper.ramping):
            stop = min(stop, s + self.record_every - s % self.record_every)
        return min(stop, self.next_due())

    # --- time --------------------------------------------------------------------------------

    def run(self, n: int) -> list[Sample]:
        """Advance n steps; returns the samples at the multiples of sample_every reached.

        Convention (the same in the recorder, replay and docs): the sample of step k is stamped
        k * dt and shows the state at that instant with the inputs in force from step k on; an
        input due at step k acts on the interval [k, k + 1) and on the sample of step k.
        """
        out: list[Sample] = []
        end = self.steps + n
        self._apply_due_inputs()
        self._check_watchdogs()
        while self.steps < end:
            stop = self._next_event(end)
            if self.fault is None:
                first = self.steps + 1
                try:
                    if stop - self.steps > 1 and self._traced() and not self.stepper.ramping:
                        # A recorder of every step takes the steps before `stop` as one block of
                        # outputs (inputs unchanged within it): one compiled call for the stretch.
                        rows = self.stepper.advance_traced(stop - first)
                        bad, problem = self._rows_problem(rows)
                        if problem is not None:
                            self.steps = first + bad
                            self._model_fault(problem)
                            continue
                        self.recorder.record_block(self.stamp_ns(first), self.dt_ns, rows)  # type: ignore[union-attr]
                        problem = self._state_problem(self.stepper.advance_finite(1))
                    else:
                        problem = self._state_problem(self.stepper.advance_finite(stop - self.steps))
                except MODEL_FAILURES as err:
                    problem = f"model step failed ({type(err).__name__}: {err})"
                if problem is not None:
                    self.steps = stop
                    self._model_fault(problem)
                    continue
            self.steps = stop
            # A sample at step k shows the state at k and the inputs in force from k on: inputs
            # and a watchdog timeout due at k act before it (right-continuous, as replay does).
            self._apply_due_inputs()
            self._check_watchdogs()
            if self.fault is None:
                try:
                    sample = self.sample() if stop % self.sample_every == 0 else None
                    signals = (self.record_values() if self.recorder is not None and stop % self.record_every == 0
                               else None)
                    # Nothing a valve cannot produce leaves the device: checked before it is shown.
                    shown = sample or signals
                    problem = (None if shown is None else
                               self.limits.problem(shown.pressure, shown.current) if isinstance(shown, Sample)
                               else self.limits.problem(shown["pressure"], shown["current"]))
                except MODEL_FAILURES as err:
                    problem = f"model output failed ({type(err).__name__}: {err})"
                if problem is not None:
                    self._model_fault(problem)
                    continue
                if sample is not None:
                    out.append(sample)
                    self.last_good = sample
                if signals is not None and self.recorder is not None:
                    self.recorder(self.stamp_ns(stop), signals)
        return out

    def run_to(self, step: int) -> list[DeviceSample]:
        """`Device.run_to`: `run` up to `step`, its samples as the device's `Sample`s (values in
        the order of `signals`)."""
        out = [self._values(s) for s in self.run(max(0, step - self.steps))]
        if out:
            self.shown = out[-1].step
        return out

    def present_sample(self) -> DeviceSample:
        sample = self._values(self.sample())
        self.shown = sample.step
        return sample

    @staticmethod
    def _values(s: Sample) -> DeviceSample:
        return DeviceSample(s.step, np.array((s.pressure, s.current, s.spool_position, *s.options)))

    def _traced(self) -> bool:
        """The recorder takes stretches of steps (`record_block(t0_ns, dt_ns, rows)`, rows of
        pressure, current, spool position at every step): see pcv_sim.io.recorder.BagRecorder."""
        return self.record_every == 1 and hasattr(self.recorder, "record_block")

    def _rows_problem(self, rows: np.ndarray) -> tuple[int, str | None]:
        """The first row (step) no valve can show, and why; (0, None) when all are fine."""
        lim = self.limits
        p, i = rows[:, 0], rows[:, 1]
        # The usual case in four reductions (a NaN fails every comparison); the row only when not.
        if lim.pressure_min <= p.min() and p.max() <= lim.pressure_max and -lim.current_max <= i.min() \
                and i.max() <= lim.current_max:
            return 0, None
        ok = np.isfinite(rows).all(axis=1) & (p >= lim.pressure_min) & (p <= lim.pressure_max) & (np.abs(i) <= lim.current_max)
        k = int(np.argmin(ok))
        return k, lim.problem(float(p[k]), float(i[k])) or "model state went non-finite"

    def _state_problem(self, finite: bool) -> str | None:
        """A cheap check after every stretch of steps (state only; the current is checked on output)."""
        if not finite:
            return "model state went non-finite"
        p = self.stepper.pressure
        lim = self.limits
        return None if lim.pressure_min <= p <= lim.pressure_max else lim.problem(p, 0.0)

    # --- outputs -----------------------------------------------------------------------------

    def sample(self) -> Sample:
        st = self.stepper
        if not self._option_out_i:
            return Sample(self.steps, st.pressure, st.current, st.spool_position, st.duty, st.command)
        current = st.current                 # solved first, as without options (the Newton start)
        y = st.sim.outputs()
        return Sample(self.steps, st.pressure, current, st.spool_position, st.duty, st.command,
                      tuple(float(y[i]) for i in self._option_out_i))

    def record_values(self) -> dict[str, float]:
        """What a recorder receives now: SIGNALS by name, and the OPTION_SIGNALS the valve's options bring."""
        st = self.stepper
        out = {
            "duty_command": st.command, "duty": st.duty, "load_flow": st.load_flow,
            "supply_pressure": st.supply_pressure, "pressure": st.pressure, "current": st.current,
            "spool_position": st.spool_position,
        }
        if self._option_signals:
            u = st.sim.u
            y = st.sim.outputs() if any(not is_input for _, _, is_input in self._option_signals) else u
            for name, i, is_input in self._option_signals:
                out[name] = float(u[i] if is_input else y[i])
        return out

    def option_input_values(self) -> dict[str, float]:
        """The valve options' inputs in force (K), read without computing an output."""
        u = self.stepper.sim.u
        return {name: float(u[i]) for name, i, is_input in self._option_signals if is_input}

    # --- faults ------------------------------------------------------------------------------

    def _model_fault(self, problem: str) -> None:
        st = self.stepper
        self.set_fault(f"{problem} at t = {self.time:.4f} s (duty {st.duty:g}, load flow {st.load_flow:g} m^3/s, "
                       f"supply {st.supply_pressure:g} Pa)")

    def reset(self) -> str:
        """Back to rest at the present operating point; clears a fault. Returns what was done.
        Raises (ValueError) and changes nothing if the model would fault again at once."""
        return self.install(self.prepare())


def rest_stepper(params: ValveParams, duty: float, load_flow: float = 0.0, supply_pressure: float | None = None,
                 *, integrator: str | None = None) -> RealTimeStepper:
    """A stepper at rest for these inputs (`pcv_sim.simulation.rest.rest_state`: the static
    equilibrium, or where the model settles when none exists, e.g. on the end stop at low duty)."""
    return RealTimeStepper(params, integrator=integrator, duty=duty, load_flow=load_flow,
                           supply_pressure=supply_pressure)


def trial_run(stepper: RealTimeStepper, limits: PhysicalLimits, steps: int = TRIAL_STEPS) -> str | None:
    """Run a copy of `stepper` for `steps` steps with its inputs; why it faulted, or None."""
    trial = copy.deepcopy(stepper)
    try:
        for _ in range(0, steps, 10):
            trial.advance(10)
            if not trial.finite():
                return "model state went non-finite"
            problem = limits.problem(trial.pressure, trial.current)
            if problem is not None:
                return problem
    except MODEL_FAILURES as err:
        return f"model step failed ({type(err).__name__}: {err})"
    return None


def _positive_int(value: int, name: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ValueError(f"{name} {value!r}: accepted is an integer >= 1")
    return value
