"""What every device is, whatever it composes (one valve; valves and a plant): model time and its
stamps, the inputs it takes (each checked on arrival, queued to the step it acts from, counted
accepted or refused), one watchdog per valve and the duty it holds, the fault state, the injected
faults and the fault commands (`pcv_sim.device.faults`: physical ones through the subclass's
parameters, sensor faults through its `sensors`), and its log. No ROS.

A subclass says what it composes: its inputs (`_declare_inputs`: name -> check, apply), how a duty
reaches a valve's model input (`_put_duty`), the duty a waiting watchdog holds (`_waiting_duty`),
and how a physical fault changes its parameters. `ValveDevice` (pcv_sim.device.valve, the
emulator: one valve, inputs `duty_cycle`, `load_flow`, `supply_pressure`) and `Rig`
(pcv_sim.rig.rig, valves on the steering cylinder: `<valve>.duty_cycle`,
`cylinder.external_force`) are devices.

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
  another thread than the stepping, install runs between two `run_to`; `reset()` is both at once;
- diagnostics: `status()` (a `DeviceStatus`: commands, duties, watchdogs, faults, counts), `log`
  ((model time, text): faults set and cleared, watchdogs firing and cleared, resets), `fault`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

from pcv_sim.device.faults import (
    CYLINDER,
    CYLINDER_FAULTS,
    SENSOR_FAULTS,
    VALVE_FAULTS,
    Fault,
    FaultCommand,
    FaultError,
    parse_fault_command,
    valve_fault_parameters,
)
from pcv_sim.device.inputs import InputQueue, InputTiming, Watchdog, WatchdogState
from pcv_sim.device.sensors import Sensors
from pcv_sim.errors import CommandError
from pcv_sim.io.topics import FAULTS
from pcv_sim.simulation.duty import check_duty

__all__ = ["MODEL_FAILURES", "Device", "DeviceStatus", "InputCounts", "InputKind", "Sample"]

#: What the model may raise when its state runs away (e.g. no coil current solves Eq. 2): a fault.
MODEL_FAILURES = (ArithmeticError, ValueError)


@dataclass(frozen=True)
class InputKind:
    """One input a device takes: `check(value)` on arrival (the value as the model takes it, or
    CommandError saying what is accepted), `apply(value)` at the step it acts from (may raise
    CommandError or FaultError when what was valid on arrival no longer is: refused then)."""

    check: Callable[[Any], Any]
    apply: Callable[[Any], None]


@dataclass
class InputCounts:
    """Inputs accepted and refused per input name (and `FAULTS`), and the last refusal's reason."""

    accepted: dict[str, int] = field(default_factory=dict)
    rejected: dict[str, int] = field(default_factory=dict)
    last_rejection: str = ""

    def declare(self, names: Sequence[str]) -> None:
        for name in names:
            self.accepted.setdefault(name, 0)
            self.rejected.setdefault(name, 0)

    def clear(self) -> None:
        """Every count back to 0 (a fresh start)."""
        self.accepted = dict.fromkeys(self.accepted, 0)
        self.rejected = dict.fromkeys(self.rejected, 0)
        self.last_rejection = ""


class Sample(NamedTuple):
    """A device's true outputs at model step `step` (stamp `stamp_ns(step)`): `values` in the order of
    its `signals`, SI units."""

    step: int
    values: np.ndarray


@dataclass(frozen=True)
class DeviceStatus:
    """What diagnostics show of a device at one instant (model time `time`, s); per valve where keyed
    by valve name."""

    time: float
    commands: dict[str, float]            # the last valid duty command
    duties: dict[str, float]              # the duty in force (the safe duty once the watchdog fired)
    watchdogs: dict[str, str]             # `WatchdogState`
    watchdog_fired: dict[str, int]        # how often each watchdog fired
    faults: tuple[str, ...]               # active injected faults, "kind@target"
    fault: str | None                     # why the model stands still (it ran away), or None
    accepted: dict[str, int]              # inputs accepted per input name (and FAULTS)
    rejected: dict[str, int]              # refused
    last_rejection: str


class Device:
    """The common part of the devices (see the module docstring); `steps` is the subclass's model
    step counter (model time = steps * dt)."""

    steps: int
    #: The device's parameters (its YAML: a valve's, a rig's), set by the subclass.
    params: Any
    #: Active faults by (target, kind), and the sensors the sensor faults act on (set by the subclass).
    faults: dict[tuple[str, str], Fault]
    sensors: Sensors
    #: Queued: an input (name, value), a fault command (FAULTS, FaultCommand), or an action to run.
    queue: InputQueue[Any]
    #: The names of a sample's values (`Sample.values`), in their order.
    signals: tuple[str, ...]
    #: Model steps between two samples `run_to` hands back.
    sample_every: int

    def __init__(self, dt: float, valve_names: Sequence[str], watchdog_steps: int, *, safe_duty: float,
                 keep_rejections: bool = True) -> None:
        self.dt = dt
        self.dt_ns = round(dt * 1e9)
        self.origin_ns = 0                  # stamp of model time 0 (a node anchors it to its clock)
        self.timing = InputTiming(self.dt_ns)
        self.queue = InputQueue()
        self.valve_names = tuple(valve_names)
        self.watchdogs = {name: Watchdog(watchdog_steps) for name in self.valve_names}
        #: The duty a fired watchdog holds (every valve's).
        self.safe_duty = safe_duty
        #: Per valve: the last valid duty command, and the duty in force (what a holding watchdog
        #: puts in place of the command).
        self.commands: dict[str, float] = {}
        self.duties: dict[str, float] = {}
        #: Why the model stands still (it ran away): nothing is stepped or shown until a reset.
        self.fault: str | None = None
        self.fault_step: int | None = None
        self.inputs: dict[str, InputKind] = {}
        self.counts = InputCounts()
        #: (model time, what happened): faults set and cleared, watchdogs firing and cleared, resets.
        self.log: list[tuple[float, str]] = []
        #: (model time, why) per refused input, kept with `keep_rejections` (a run of bounded length;
        #: a long-running device counts them in `counts` only).
        self.rejected: list[tuple[float, str]] = []
        self.keep_rejections = keep_rejections
        #: Called with (step, the command as given) when a fault command acted (a recorder's hook).
        self.on_fault_command: Callable[[int, str], None] | None = None
        #: The last step whose sample `run_to` or `present_sample` handed out (-1: none yet).
        self.shown = -1

    @property
    def time(self) -> float:
        """Model time, s (an integer count of steps: it never drifts)."""
        return self.steps * self.dt

    def stamp_ns(self, step: int | None = None) -> int:
        """The stamp of model step `step` (default: the present one)."""
        return self.origin_ns + (self.steps if step is None else step) * self.dt_ns

    def next_due(self) -> int:
        """The first step at which a queued input or a watchdog deadline falls (`inputs.NEVER` if
        none): where a stretch of compiled steps must stop."""
        return min(self.queue.next_step, *(w.deadline for w in self.watchdogs.values()))

    def skip(self, n: int) -> None:
        """Let n steps of model time pass without computing them (the model state is held): a real-time
        loop that fell too far behind, an external clock that jumped."""
        self.steps += n

    def set_fault(self, reason: str) -> None:
        """Enter the fault state (the first reason stays until it is cleared)."""
        if self.fault is None:
            self.fault = reason
            self.fault_step = self.steps

    def clear_fault(self) -> str | None:
        """Leave the fault state; the reason it had, or None."""
        was, self.fault, self.fault_step = self.fault, None, None
        return was

    # --- stepping, outputs, restarts (the node-facing part the subclass supplies) ---------------

    def run_to(self, step: int) -> list[Sample]:
        """Advance to `step` (inputs, fault commands and watchdog deadlines acting at their steps;
        those due at `step` itself act before its sample) and return the samples of the multiples
        of `sample_every` passed on the way, the one at `step` included. A model that runs away
        sets `fault` (no exception): the samples before it are returned, none after it."""
        raise NotImplementedError

    def present_sample(self) -> Sample:
        """The sample at the present step (with the inputs in force from it on); it counts as shown."""
        raise NotImplementedError

    def measure(self, sample: Sample) -> np.ndarray:
        """What the sensors show of `sample` (sensor faults applied; NaN: no value, not to be
        published). Called once per sample, in order (a delay or noise fault keeps history)."""
        sensors = self.sensors
        if not sensors.active and not sensors.keeps_history:
            return sample.values
        return sensors.measure(sample.step * self.dt, sample.values)

    def prepare(self, params: Any = None) -> Any:
        """What `install` needs to put the model back at rest (with `params`, new parameters: the
        device's own kind, e.g. a `ValveParams`); reads the device and changes nothing, so it may
        run off the stepping thread. Raises (ValueError, ParameterError) for what cannot run."""
        raise NotImplementedError

    def install(self, prepared: Any) -> str:
        """Swap in what `prepare` made, at a step boundary (between two `run_to`): the model at rest,
        a fault cleared, model time going on. Returns what was done (for the log)."""
        raise NotImplementedError

    @property
    def input_names(self) -> tuple[str, ...]:
        """The inputs `submit` takes, by name."""
        return tuple(self.inputs)

    def status(self) -> DeviceStatus:
        """Diagnostics' view of the device now (copies: it stays as it was when taken)."""
        c = self.counts
        return DeviceStatus(
            self.time, dict(self.commands), dict(self.duties),
            {name: w.state for name, w in self.watchdogs.items()},
            {name: w.fired for name, w in self.watchdogs.items()},
            tuple(f"{kind}@{target}" for target, kind in self.faults), self.fault,
            dict(c.accepted), dict(c.rejected), c.last_rejection)

    # --- inputs ------------------------------------------------------------------------------

    def _declare_inputs(self, inputs: Mapping[str, InputKind]) -> None:
        """The inputs `submit` takes, by name (counted from now on)."""
        self.inputs = dict(inputs)
        self.counts.declare((*inputs, FAULTS))

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

    @property
    def has_cylinder(self) -> bool:
        """Whether the device composes a cylinder (a target of the cylinder faults)."""
        return False

    def first_open_step(self) -> int:
        """The first step an input may still act from: one whose sample nobody has seen (every
        sample shows the inputs in force at its stamp). A device that shows its own samples
        (the emulator's `run`) has shown the present step; one whose caller takes them (the rig)
        leaves it to the caller's `at_step`, and the present step is open."""
        return self.steps

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
        while (due := self.queue.pop_due(self.steps)) is not None:
            if callable(due):
                due()
                continue
            name, value = due
            try:
                if name == FAULTS:
                    self._fault_command(value)
                    if self.on_fault_command is not None:
                        self.on_fault_command(self.steps, value.text)
                else:
                    self.inputs[name].apply(value)
            except (CommandError, FaultError) as err:   # valid on arrival, refused now (e.g. duty_range
                self._reject(name, str(err))           # changed since, a fault cleared that is not active)
                continue
            self.counts.accepted[name] = self.counts.accepted.get(name, 0) + 1

    def _fault_command(self, command: FaultCommand) -> None:
        if command.clear:
            self.clear(command.target, command.kind)
        else:
            assert command.fault is not None     # a command that is not a clear carries its fault
            self.inject(command.fault)

    # --- duties and watchdogs ----------------------------------------------------------------

    def _take_command(self, valve: str, duty: float) -> None:
        """A valid duty command (checked) acts on `valve` from the present step on."""
        self.commands[valve] = duty
        self.duties[valve] = duty
        self._put_duty(valve, duty)
        if self.watchdogs[valve].command(self.steps):
            self._note(f"{valve}: watchdog cleared by a valid command")

    def _check_watchdogs(self) -> None:
        """Fire the watchdogs whose deadline is the present step: their valves get the safe duty."""
        steps = self.steps
        for name, watchdog in self.watchdogs.items():
            if watchdog.check(steps):
                safe = self.safe_duty
                self.duties[name] = safe
                self._put_duty(name, safe)
                self._note(f"{name}: watchdog fired, duty -> {safe:g}")

    def duty_held(self, valve: str) -> float:
        """The duty in force for `valve` by its watchdog's state: the command while commands come,
        the safe duty once it fired, the device's waiting duty before a first command."""
        state = self.watchdogs[valve].state
        if state == WatchdogState.FIRED:
            return self.safe_duty
        if state == WatchdogState.WAITING:
            return self._waiting_duty(valve)
        return self.commands[valve]

    def set_watchdog_timeout(self, timeout: float) -> None:
        """Seconds of model time without a valid duty command before the safe duty; 0 = off.
        ValueError for anything else (nothing changes)."""
        if isinstance(timeout, bool) or not isinstance(timeout, (int, float)) \
                or not (math.isfinite(timeout) and timeout >= 0.0):
            raise ValueError(f"watchdog_timeout {timeout!r} s: accepted is a finite number >= 0 (0 = off)")
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

    def _restart_watchdogs(self) -> None:
        for watchdog in self.watchdogs.values():
            watchdog.restart()

    def duty_range(self, valve: str) -> tuple[float, ...]:
        """The duties `valve` takes (its command.duty_range)."""
        raise NotImplementedError

    def _put_duty(self, valve: str, duty: float) -> None:
        """Put `duty` into `valve`'s model input from the present step on."""
        raise NotImplementedError

    def _waiting_duty(self, valve: str) -> float:
        """The duty `valve` holds before a first command."""
        raise NotImplementedError

    # --- injected faults ---------------------------------------------------------------------

    def inject(self, fault: Fault) -> None:
        """Start `fault` at the present step (a second fault of the same kind on the same target
        replaces the first); FaultError for a target this device does not have."""
        if fault.sensor:
            if fault.target not in self.sensors.signals:
                raise FaultError(f"sensor fault on {fault.target!r}: accepted are {', '.join(self.sensors.signals)}")
            self.sensors.add(fault, self.time)
        elif (accepted := self._fault_targets(fault)) is not None:
            raise FaultError(f"{fault.kind} on {fault.target!r}: accepted {accepted}")
        self.faults[fault.key] = fault
        if not fault.sensor:
            self._apply_physical_faults(fault)
        self._note(f"fault {fault.kind} on {fault.target} {dict(fault.values) or ''}".rstrip())

    def clear(self, target: str, kind: str) -> None:
        """End a fault: the target is back to normal from the present step on."""
        fault = self.faults.pop((target, kind), None)
        if fault is None:
            active = ", ".join(f"{k}@{t}" for t, k in self.faults) or "none"
            raise FaultError(f"no active fault {kind} on {target}; active: {active}")
        if fault.sensor:
            self.sensors.clear(target, kind)
        else:
            self._apply_physical_faults(fault)
        self._note(f"cleared {kind} on {target}")

    def _fault_targets(self, fault: Fault) -> str | None:
        """What a physical fault's target may be, when `fault`'s is not one (None: it is)."""
        if fault.on_cylinder:
            return None if self.has_cylinder and fault.target == CYLINDER else (
                f"is {CYLINDER}" if self.has_cylinder else f"are none: this device has no {CYLINDER}")
        if fault.target in self.valve_names:
            return None
        return f"is the valve {self.valve_names[0]}" if len(self.valve_names) == 1 else \
            f"are the valves {', '.join(self.valve_names)}"

    def _apply_physical_faults(self, fault: Fault) -> None:
        """Re-apply every active physical fault on `fault`'s target (after one was set or cleared)."""
        if fault.on_cylinder:
            self._apply_plant_faults()
        else:
            self._apply_valve_faults(fault.target)

    def _apply_valve_faults(self, valve: str) -> None:
        """The valve's parameters and supply: healthy, then every active physical fault on it."""
        p, supply, stuck = valve_fault_parameters(
            self._healthy_parameters(valve), self._supply_in_force(valve),
            (f for (target, _), f in self.faults.items() if target == valve and not f.sensor))
        self._put_valve(valve, p, supply, stuck)

    def _healthy_parameters(self, valve: str) -> np.ndarray:
        """`valve`'s packed model parameters without faults."""
        raise NotImplementedError

    def _supply_in_force(self, valve: str) -> float:
        """`valve`'s supply pressure without faults, Pa."""
        raise NotImplementedError

    def _put_valve(self, valve: str, parameters: np.ndarray, supply: float, stuck: bool) -> None:
        """Put `valve`'s parameters and supply pressure into the model; `stuck`: its spool seized
        where it is (its velocity state to 0: the continuity's A v term stops with it)."""
        raise NotImplementedError

    def _apply_plant_faults(self) -> None:
        """The plant's parameters: healthy, then every active fault on it (a device with a plant)."""
        raise NotImplementedError

    def _note(self, text: str) -> None:
        """Something for the device's log (faults, watchdogs, resets), at the present model time."""
        self.log.append((self.time, text))
