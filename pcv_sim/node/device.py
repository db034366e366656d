"""The emulated device around the model: inputs, watchdog, fault state, samples. No ROS here.

`ValveDevice` is what the ROS node adapts: it owns a `RealTimeStepper` and a step counter (the
device's model time, `steps * dt`), and

- takes inputs (`submit`) that are validated on arrival and take effect at a given step (the
  node passes the step that matches the input's reception time); a refused input is counted
  with its reason and the last valid value stays in force;
- runs the watchdog in model time: `watchdog_timeout` s after the last valid duty command took
  effect, the duty falls to `safe_duty`; the next valid command resumes;
- enters a fault state when the model state goes non-finite or a model step raises (e.g. no
  coil current solves Eq. 2 for a runaway state): it stops stepping and emits no samples (a
  controller must not read a dead sensor as a valid one) until `reset()`;
- returns samples at every `sample_every`-th step (`run`) and calls an optional recorder
  `recorder(t_ns, signals)` at every `record_every`-th step (the hook for bag logging).

Everything is deterministic for a given sequence of (step, input) pairs.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass, field
from typing import Mapping, Protocol

from pcv_sim.errors import CommandError
from pcv_sim.params import ValveParams
from pcv_sim.simulation.duty import check_duty
from pcv_sim.simulation.stepper import RealTimeStepper, check_load_flow, check_supply_pressure

__all__ = ["INPUTS", "SIGNALS", "Recorder", "Sample", "ValveDevice", "WatchdogState", "rest_stepper"]

#: What the model may raise when its state runs away (e.g. no coil current solves Eq. 2): a fault.
MODEL_FAILURES = (ArithmeticError, ValueError)

#: Input names, as the node's topics are called.
INPUTS = ("duty_cycle", "load_flow", "supply_pressure")

#: What a recorder receives per sample, SI units: duty fractions, m^3/s, Pa, A, m.
SIGNALS = ("duty_command", "duty", "load_flow", "supply_pressure", "pressure", "current", "spool_position")


class Recorder(Protocol):
    """Receives one model sample: t_ns (stamp of the sample's model time), signals by SIGNALS name."""

    def __call__(self, t_ns: int, signals: Mapping[str, float]) -> None: ...


class WatchdogState:
    OFF = "off"            # watchdog_timeout = 0
    WAITING = "waiting"    # no valid duty command yet: safe duty
    OK = "ok"              # commands arriving
    FIRED = "fired"        # no valid command for watchdog_timeout: safe duty


@dataclass(frozen=True)
class Sample:
    """The device's outputs at model step `step` (time step * dt)."""

    step: int
    pressure: float          # Pa, load port
    current: float           # A, coil
    spool_position: float    # m, paper's sign: x > 0 opens pump -> load
    duty: float              # effective duty (after the fall-rate limiter), fraction
    command: float           # duty command in force (the watchdog's safe duty when it has fired)


@dataclass
class _Inputs:
    accepted: dict[str, int] = field(default_factory=lambda: dict.fromkeys(INPUTS, 0))
    rejected: dict[str, int] = field(default_factory=lambda: dict.fromkeys(INPUTS, 0))
    last_rejection: str = ""


class ValveDevice:
    """One emulated valve: the model stepper plus the device behaviour around it."""

    def __init__(
        self, params: ValveParams, *, safe_duty: float = 0.0, watchdog_timeout: float = 0.5,
        sample_every: int = 10, recorder: Recorder | None = None, record_every: int = 1,
    ) -> None:
        self.params = params
        self.dt = params.simulation.time_step
        self.dt_ns = round(self.dt * 1e9)
        self.origin_ns = 0                 # stamp of model time 0 (the node anchors it to the ROS clock)
        self.steps = 0
        self.safe_duty = check_duty(safe_duty, params.command.duty_range)
        self.sample_every = _positive_int(sample_every, "sample_every")
        self.recorder = recorder
        self.record_every = _positive_int(record_every, "record_every")
        self.counts = _Inputs()
        self._pending: list[tuple[int, int, str, float]] = []   # (step, seq, input, value), sorted
        self._seq = 0
        self.command = self.safe_duty       # last valid duty command (the safe duty before any)
        self.load_flow = 0.0
        self.supply_pressure: float | None = None   # None: the parameter file's circuit.supply_pressure
        self.duty_applied_step: int | None = None    # step at which the last valid duty took effect
        self.watchdog_state = WatchdogState.WAITING
        self.watchdog_fired_step: int | None = None
        self.watchdog_fired = 0                       # how often it fired
        self._timeout_steps = 0
        self.set_watchdog_timeout(watchdog_timeout)
        self.fault: str | None = None
        self.fault_step: int | None = None
        self.last_good: Sample | None = None
        self.stepper = rest_stepper(params, self.safe_duty)
        self.last_good = self.sample()

    # --- configuration -----------------------------------------------------------------------

    def set_watchdog_timeout(self, timeout: float) -> None:
        """Seconds of model time without a valid duty command before the safe duty; 0 = off."""
        if not (math.isfinite(timeout) and timeout >= 0.0):
            raise ValueError(f"watchdog_timeout {timeout!r} s: accepted is a finite number >= 0 (0 = off)")
        self._timeout_steps = round(timeout / self.dt)
        if self._timeout_steps == 0:
            if self.watchdog_state == WatchdogState.FIRED:
                self._apply_duty(self.command)
            self.watchdog_state = WatchdogState.OFF if self.duty_applied_step is not None else WatchdogState.WAITING
        elif self.watchdog_state == WatchdogState.OFF:
            self.watchdog_state = WatchdogState.OK

    def set_safe_duty(self, duty: float) -> None:
        self.safe_duty = check_duty(duty, self.params.command.duty_range)
        if self.watchdog_state in (WatchdogState.WAITING, WatchdogState.FIRED):
            self._apply_duty(self.safe_duty)

    def prepare(self, params: ValveParams, integrator: str | None = None) -> RealTimeStepper:
        """A stepper for new parameters at the present operating point (raises if it cannot be built)."""
        if params.simulation.time_step != self.params.simulation.time_step:
            raise ValueError("the model time step cannot change while the device runs")
        duty = self.duty_command_in_force
        check_duty(duty, params.command.duty_range)
        return rest_stepper(params, duty, self.load_flow, self.supply_pressure, integrator=integrator)

    def install(self, stepper: RealTimeStepper) -> None:
        """Swap in a stepper from `prepare`: the model restarts at rest at the present operating point
        (the equilibrium for the command, load flow and supply pressure in force); model time goes on."""
        self.params = stepper.params
        self.stepper = stepper
        if self.fault is None:
            self.last_good = self.sample()

    # --- inputs ------------------------------------------------------------------------------

    def submit(self, name: str, value: float, at_step: int | None = None) -> str | None:
        """Validate an input now; if valid it takes effect at step max(at_step, now + 1). Returns
        the reason it was refused (counted, and the last valid value stays), or None.

        The present step has been shown already (sample, recorder): an input that arrives now
        can act from the next step at the earliest, so that every sample shows the inputs in
        force at its stamp."""
        try:
            if name == "duty_cycle":
                value = check_duty(value, self.params.command.duty_range)
            elif name == "load_flow":
                value = check_load_flow(value)
            elif name == "supply_pressure":
                value = check_supply_pressure(value)
            else:
                raise ValueError(f"unknown input {name!r}; accepted are {', '.join(INPUTS)}")
        except CommandError as err:
            return self._reject(name, str(err))
        step = self.steps + 1 if at_step is None else max(int(at_step), self.steps + 1)
        self._seq += 1
        bisect.insort(self._pending, (step, self._seq, name, value))
        return None

    def _reject(self, name: str, reason: str) -> str:
        self.counts.rejected[name] += 1
        self.counts.last_rejection = f"{name}: {reason}"
        return reason

    @property
    def duty_command_in_force(self) -> float:
        if self.watchdog_state in (WatchdogState.WAITING, WatchdogState.FIRED):
            return self.safe_duty
        return self.command

    def _apply_duty(self, duty: float) -> None:
        self.stepper.set_duty(duty)

    def _apply_due_inputs(self) -> None:
        pending = self._pending
        while pending and pending[0][0] <= self.steps:
            _, _, name, value = pending.pop(0)
            try:
                if name == "duty_cycle":
                    self._apply_duty(value)
                    self.command = value
                    self.duty_applied_step = self.steps
                    if self.watchdog_state != WatchdogState.OFF:
                        self.watchdog_state = WatchdogState.OK if self._timeout_steps else WatchdogState.OFF
                elif name == "load_flow":
                    self.stepper.set_load_flow(value)
                    self.load_flow = value
                else:
                    self.stepper.set_supply_pressure(value)
                    self.supply_pressure = value
            except CommandError as err:   # valid on arrival, refused now (e.g. duty_range changed since)
                self._reject(name, str(err))
                continue
            self.counts.accepted[name] += 1

    def _check_watchdog(self) -> None:
        if (self.watchdog_state == WatchdogState.OK and self._timeout_steps
                and self.steps >= self.duty_applied_step + self._timeout_steps):
            self.watchdog_state = WatchdogState.FIRED
            self.watchdog_fired_step = self.steps
            self.watchdog_fired += 1
            self._apply_duty(self.safe_duty)

    def _next_event(self, end: int) -> int:
        s = self.steps
        stop = min(end, s + self.sample_every - s % self.sample_every)
        if self.recorder is not None:
            stop = min(stop, s + self.record_every - s % self.record_every)
        if self._pending:
            stop = min(stop, self._pending[0][0])
        if self.watchdog_state == WatchdogState.OK and self._timeout_steps:
            stop = min(stop, self.duty_applied_step + self._timeout_steps)
        return stop

    # --- time --------------------------------------------------------------------------------

    @property
    def time(self) -> float:
        """Model time, s."""
        return self.steps * self.dt

    def stamp_ns(self, step: int | None = None) -> int:
        return self.origin_ns + (self.steps if step is None else step) * self.dt_ns

    def run(self, n: int) -> list[Sample]:
        """Advance n steps; returns the samples at the multiples of sample_every reached.

        Convention (the same in the recorder, replay and docs): the sample of step k is stamped
        k * dt and shows the state at that instant with the inputs in force from step k on; an
        input due at step k acts on the interval [k, k + 1) and on the sample of step k.
        """
        out: list[Sample] = []
        end = self.steps + n
        self._apply_due_inputs()
        self._check_watchdog()
        while self.steps < end:
            stop = self._next_event(end)
            if self.fault is None:
                try:
                    self.stepper.advance(stop - self.steps)
                    problem = None if self.stepper.finite() else "model state went non-finite"
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
            self._check_watchdog()
            if self.fault is None:
                try:
                    sample = self.sample() if stop % self.sample_every == 0 else None
                    signals = (self.signals() if self.recorder is not None and stop % self.record_every == 0
                               else None)
                except MODEL_FAILURES as err:
                    self._model_fault(f"model output failed ({type(err).__name__}: {err})")
                    continue
                if sample is not None:
                    out.append(sample)
                    self.last_good = sample
                if signals is not None:
                    self.recorder(self.stamp_ns(stop), signals)
        return out

    def skip(self, n: int) -> None:
        """Let n steps of model time pass without computing them (the model state is held)."""
        self.steps += n

    # --- outputs -----------------------------------------------------------------------------

    def sample(self) -> Sample:
        st = self.stepper
        return Sample(self.steps, st.pressure, st.current, st.spool_position, st.duty, st.command)

    def signals(self) -> dict[str, float]:
        st = self.stepper
        return {
            "duty_command": st.command, "duty": st.duty, "load_flow": st.load_flow,
            "supply_pressure": st.supply_pressure, "pressure": st.pressure, "current": st.current,
            "spool_position": st.spool_position,
        }

    # --- faults ------------------------------------------------------------------------------

    def _model_fault(self, problem: str) -> None:
        st = self.stepper
        self.set_fault(f"{problem} at t = {self.time:.4f} s (duty {st.duty:g}, load flow {st.load_flow:g} m^3/s, "
                       f"supply {st.supply_pressure:g} Pa)")

    def set_fault(self, reason: str) -> None:
        """Enter the fault state (also the hook for fault injection): no stepping, no samples."""
        if self.fault is None:
            self.fault = reason
            self.fault_step = self.steps

    def reset(self) -> str:
        """Back to rest at the present operating point; clears a fault. Returns what was done."""
        was = self.fault
        self.stepper = rest_stepper(self.params, self.duty_command_in_force, self.load_flow, self.supply_pressure,
                                    integrator=self.stepper.integrator)
        self.fault = None
        self.fault_step = None
        self.last_good = self.sample()
        what = f"model at rest at duty {self.duty_command_in_force:g}, {self.stepper.pressure / 1e5:.2f} bar"
        return f"{what} (cleared fault: {was})" if was else what


def rest_stepper(params: ValveParams, duty: float, load_flow: float = 0.0, supply_pressure: float | None = None,
                 *, integrator: str | None = None) -> RealTimeStepper:
    """A stepper at rest for these inputs (`pcv_sim.simulation.rest.rest_state`: the static
    equilibrium, or where the model settles when none exists, e.g. on the end stop at low duty)."""
    return RealTimeStepper(params, integrator=integrator, duty=duty, load_flow=load_flow,
                           supply_pressure=supply_pressure)


def _positive_int(value: int, name: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ValueError(f"{name} {value!r}: accepted is an integer >= 1")
    return value
