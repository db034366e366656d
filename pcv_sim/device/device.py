"""The one device: valves and an optional plant in one `Simulator` at one fixed step, and what a
device is around the model. No ROS.

What it composes is data (`ValveSpec` per valve, an optional `PlantSpec`): each valve is the
paper's model (`pcv_sim.simulation.valve.valve_system`); a valve wired to the plant (its pressure
state into the plant, the plant's flow and volume into its `load_flow` and `load_volume`, Eq. 15)
is integrated together with it at one step by one integrator (erk2 when any valve needs it), so
the load flow is never a step late; a valve on its own load volume takes `load_flow` as an input.
The emulator (`pcv_sim.device.valve.ValveDevice`) is one valve named `valve` on its own load
volume and no plant; the rig (`pcv_sim.rig.rig.Rig`) is its valves on the steering cylinder. A
device of one valve and no plant names its inputs and signals by their role alone (`duty_cycle`,
`pressure`); any other prefixes them with the valve's name (`left.duty_cycle`, `left.pressure`)
and names the plant's by the plant's (`cylinder.external_force`, `cylinder.position`).

Around the model, written once for every device:
- inputs (`submit`; per valve `duty_cycle`, `supply_pressure`, `load_flow` on its own volume, the
  options' temperatures; the plant's own): checked on arrival (refused with what is accepted,
  counted; the last valid value stays), queued to the step they act from (`InputTiming` gives
  it from the reception time), in the order they came; `schedule` runs an action at a step and
  `feed` puts a plain input's values in at given steps inside the compiled calls;
- one watchdog per valve in model time: waiting (the valve's initial duty) before a first
  command, `watchdog_timeout` s after the last valid command the duty falls to `safe_duty`, the
  next valid command resumes;
- the duty fall-rate limiter per valve (`command.duty_fall_rate_limit`, Sec. 3.2): the duty a
  valve's model gets falls at most that fast (stepping goes one step at a time while it ramps);
- injected faults (`pcv_sim.device.faults`): physical ones change a valve's (or the plant's)
  parameters and supply, sensor faults what `measure` makes of a sample;
- the fault state: a state that runs away (non-finite), a step that raises, or a sample or record
  a valve cannot show (`PhysicalLimits`, checked before anything leaves) stops the model
  (`fault`) until a restart: nothing is shown of a diverging model;
- rest states (`pcv_sim.simulation.rest.rest_state`): at a start (`reset`) each valve at rest at
  its initial duty and the plant at its rest state (solved once); `prepare`/`install` restart
  the model at rest at a step boundary, with new parameters when given, after a trial run;
- outputs: `run_to` hands back the `Sample`s due (values in the order of `signals`) and calls a
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
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from functools import partial
from typing import Any, NamedTuple, NoReturn, Protocol

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
from pcv_sim.device.inputs import NEVER, InputQueue, InputTiming, Watchdog, WatchdogState
from pcv_sim.device.limits import TRIAL_STEPS, PhysicalLimits
from pcv_sim.device.sensors import Sensors
from pcv_sim.errors import CommandError, ParameterError, PcvSimError
from pcv_sim.io.topics import FAULTS
from pcv_sim.model import kernel
from pcv_sim.params import ValveParams
from pcv_sim.simulation.duty import FallRateLimiter, check_duty
from pcv_sim.simulation.rest import rest_state
from pcv_sim.simulation.simulator import Simulator
from pcv_sim.simulation.stepper import (
    check_load_flow,
    check_oil_step,
    check_supply_pressure,
    check_temperature,
)
from pcv_sim.simulation.system import Composite, System, compose
from pcv_sim.simulation.valve import valve_integrator, valve_system
from pcv_sim.units import bar, kelvin

__all__ = [
    "MODEL_FAILURES", "TEMPERATURE_INPUTS", "Device", "DeviceStatus", "InputCounts", "InputHook", "InputKind",
    "ModelFault", "PlantSpec", "Recorder", "Sample", "ValveSpec",
]

#: What the model may raise when its state runs away (e.g. no coil current solves Eq. 2): a fault.
MODEL_FAILURES = (ArithmeticError, ValueError)

#: The valve options' temperature inputs (R33, R34) and the valve YAML's switch that brings each.
TEMPERATURE_INPUTS = {"ambient_temperature": "solenoid.coil_temperature: lumped",
                      "oil_temperature": "fluid.temperature: input"}

#: `Device.on_input(step, name, value)`: an input of the model changed, acting from `step` on.
InputHook = Callable[[int, str, float], None]


class ModelFault(PcvSimError, RuntimeError):
    """The device cannot go on: its model ran away (the fault state, `Device.fault`, until a restart)."""


class Recorder(Protocol):
    """Receives one model sample: t_ns (stamp of the sample's model time), values by `record_values` name."""

    def __call__(self, t_ns: int, signals: Mapping[str, float]) -> None: ...


@dataclass(frozen=True)
class ValveSpec:
    """One valve of a device: its name (its namespace, a fault's target), its parameters, and the
    duty it holds at a start until a first command (None: the device's safe duty)."""

    name: str
    params: ValveParams
    initial_duty: float | None = None


@dataclass(frozen=True)
class PlantSpec:
    """What the valves act on: its system, the wires between it and the valves (`compose`'s
    `(a.output, b.input)`), its state at a start (at rest), the inputs a device takes for it
    (composite name -> check; 0 at a start) and its sampled outputs (composite names)."""

    system: System
    wires: tuple[tuple[str, str], ...]
    rest: tuple[float, ...]
    inputs: Mapping[str, Callable[[Any], float]]
    signals: tuple[str, ...]
    #: How the log says it is at its start state.
    at_rest: str = "the plant at its start state"


@dataclass(frozen=True)
class Prepared:
    """What `Device.prepare` made: new parameters and their valves (None: the present ones) and a
    simulator at rest (None: the device's start state, put in by `install`)."""

    params: Any
    valves: tuple[ValveSpec, ...] | None
    sim: Simulator | None
    what: str


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
    """Valves and an optional plant at one fixed step, with everything around the model (see the
    module docstring). Its queue holds inputs (`submit`), fault commands (`submit_fault`) and
    actions (`schedule`)."""

    #: The device's parameters (its YAML: a valve's, a rig's), set by its configuration.
    params: Any

    def __init__(self, dt: float, valves: Sequence[ValveSpec], plant: PlantSpec | None = None, *,
                 watchdog_timeout: float = 0.0, safe_duty: float = 0.0, sample_every: int = 1, seed: int = 0,
                 keep_rejections: bool = True, restart_at_start: bool = False) -> None:
        self.dt = dt
        self.dt_ns = round(dt * 1e9)
        self.origin_ns = 0                  # stamp of model time 0 (a node anchors it to its clock)
        self.timing = InputTiming(self.dt_ns)
        #: Queued: an input (name, value), a fault command (FAULTS, FaultCommand), or an action to run.
        self.queue: InputQueue[Any] = InputQueue()
        self.valve_names = tuple(v.name for v in valves)
        self.watchdogs = {name: Watchdog(0) for name in self.valve_names}
        #: Per valve: the last valid duty command, and the duty in force (what a holding watchdog
        #: puts in place of the command; the fall-rate limiter's target).
        self.commands: dict[str, float] = {}
        self.duties: dict[str, float] = {}
        #: Why the model stands still (it ran away): nothing is stepped or shown until a restart.
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
        #: Called whenever an input of the model (a duty in force, a supply pressure, a plant input)
        #: changes, with the step it acts from (a recorder's hook); None: nobody listens.
        self.on_input: InputHook | None = None
        #: `recorder(t_ns, record_values())` at every `record_every`-th step of `run_to`.
        self.recorder: Recorder | None = None
        self.record_every = 1
        #: The last step whose sample or record left (`run_to`, `present_sample`; -1: none yet).
        self.shown = -1
        #: The last sample handed out (diagnostics), or None.
        self.last_sample: Sample | None = None
        self.sample_every = _positive_int(sample_every, "sample_every")
        #: Whether `install(prepare())` is a fresh start's rest (the rig: initial duties, the plant at
        #: its start) or the rest at the present operating point (the emulator: the duty in force).
        self.restart_at_start = restart_at_start
        self.plant_spec = plant
        #: Active faults by (target, kind).
        self.faults: dict[tuple[str, str], Fault] = {}
        self._rest: dict[tuple[int, float, float, float], tuple[np.ndarray, float]] = {}   # rest states solved
        #: Fed inputs (`feed`): their names, input indices, and one row per step at which any of
        #: them changes (NaN: that input does not change there); rows from _feed_next on are pending.
        self._feed_names: tuple[str, ...] = ()
        self._feed_i = np.zeros(0, dtype=np.int64)
        self._feed_steps: list[int] = []
        self._feed_v = np.zeros((0, 0))
        self._feed_next = 0
        self._configure(tuple(valves), None)
        self.safe_duty = safe_duty
        for name in self.valve_names:
            self.safe_duty = check_duty(safe_duty, self.duty_range(name))
        self.sensors = Sensors(self.signals, self.sample_every * dt, seed)
        self.reset()
        self.set_watchdog_timeout(watchdog_timeout)
        self._warm_up()

    # --- what it composes --------------------------------------------------------------------

    def _configure(self, valves: tuple[ValveSpec, ...], sim: Simulator | None) -> None:
        """Build (or, with `sim`, take) the simulator of `valves` and the plant, and everything
        read off its layout: input and output indices, names, limits, limiters, inputs taken."""
        plant_spec = self.plant_spec
        self.valve_specs = valves
        kind = valves[0].params.simulation.model
        self.kind = kind
        systems = [valve_system(v.params, kind, v.name) for v in valves]
        if plant_spec is not None:
            systems.append(plant_spec.system)
        self.plant: Composite = compose(systems, plant_spec.wires if plant_spec is not None else ())
        plant = self.plant
        if sim is None:
            # One integrator for all: erk2 when a valve's spool pole needs it (oil temperature, R34).
            methods = {valve_integrator(v.params, kind) for v in valves}
            sim = Simulator(plant, self.dt, "erk2" if "erk2" in methods else valves[0].params.simulation.method)
        self.sim = sim
        lone = len(valves) == 1 and plant_spec is None
        #: A valve's names: its role alone on a device of one valve and no plant, else `<valve>.<role>`.
        self._prefix = {v.name: "" if lone else f"{v.name}." for v in valves}
        names = self.valve_names
        self._k = {n: k for k, n in enumerate(names)}
        self._duty_i = [plant.index("input", f"{n}.duty_cycle") for n in names]
        self._supply_i = [plant.index("input", f"{n}.supply_pressure") for n in names]
        self._flow_i = [plant.inputs.index(f"{n}.load_flow") if f"{n}.load_flow" in plant.inputs else -1
                        for n in names]
        self._volume_in_i = [plant.inputs.index(f"{n}.load_volume") if f"{n}.load_volume" in plant.inputs else -1
                             for n in names]
        wired = {dst: src for src, dst in (plant_spec.wires if plant_spec is not None else ())}
        #: per valve: the output its load volume is wired from (the plant's), or -1 (its own, constant)
        self._volume_i = [plant.index("output", wired[f"{n}.load_volume"]) if f"{n}.load_volume" in wired else -1
                          for n in names]
        self._volumes = [v.params.circuit.load_volume for v in valves]
        self._wired_volumes = any(i >= 0 for i in self._volume_i)
        layouts = [kernel.layout(v.params, kind) for v in valves]
        sampled = [f"{v.name}.{o}" for v, lay in zip(valves, layouts) for o in lay.outputs]
        self.signals: tuple[str, ...] = tuple(
            f"{self._prefix[v.name]}{o}" for v, lay in zip(valves, layouts) for o in lay.outputs)
        if plant_spec is not None:
            sampled += plant_spec.signals
            self.signals += plant_spec.signals
        self._signal_i = np.array([plant.index("output", s) for s in sampled], dtype=np.int64)
        #: every output, in order: the outputs are the signals (no copy of a traced block's rows)
        self._all_outputs = np.array_equal(self._signal_i, np.arange(len(plant.outputs)))
        self._ranges = {v.name: v.params.command.duty_range for v in valves}
        self._limiters = [FallRateLimiter(v.params.command.duty_fall_rate_limit) for v in valves]
        self._limited = [k for k, v in enumerate(valves) if v.params.command.duty_fall_rate_limit is not None]
        self._lim_step = [-1] * len(valves)     # the step each limiter's value was last taken at
        self._ramp_at = [-1] * len(valves)      # the step each ramp's next step is queued for
        #: per valve: (its command.duty_range, its duty's input index): what the lockstep's fast path
        #: writes straight into the model; no range for a valve with a fall-rate limiter (its duty
        #: goes through `set_duty` and the limiter).
        self._duty_slot = {v.name: ((math.nan, math.nan) if k in self._limited else self._ranges[v.name],
                                    self._duty_i[k]) for k, v in enumerate(valves)}
        #: per valve: its limits and where its pressure and current are among the signals
        self.limits = {v.name: PhysicalLimits.of(v.params) for v in valves}
        self._limit_slots = [(sampled.index(f"{v.name}.pressure"), sampled.index(f"{v.name}.current"),
                              self.limits[v.name]) for v in valves]
        #: The valve options' inputs (ambient and oil temperature, K; R33, R34) at their configured
        #: values: (input index, value) per valve that has them.
        self._option_defaults = [(plant.index("input", f"{v.name}.{name}"), value) for v, lay in zip(valves, layouts)
                                 for name, value in zip(lay.inputs[len(kernel.INPUTS):], kernel.option_inputs(v.params),
                                                        strict=True)]
        #: The valve options' signals (io.topics.OPTION_INTERFACE): inputs (temperatures, K:
        #: `set_temperature`) and outputs, which are among `signals` (their true values at the last
        #: `sample()`: `option_sample`).
        self._option_in = [(v.name, name) for v, lay in zip(valves, layouts) for name in lay.inputs[len(kernel.INPUTS):]]
        self.option_inputs = tuple(f"{self._prefix[v]}{name}" for v, name in self._option_in)
        self._option_in_i = [plant.index("input", f"{v}.{name}") for v, name in self._option_in]
        option_out = [(v.name, name) for v, lay in zip(valves, layouts) for name in lay.outputs[len(kernel.OUTPUTS):]]
        self.option_outputs = tuple(f"{self._prefix[v]}{name}" for v, name in option_out)
        self._option_out_i = np.array([plant.index("output", f"{v}.{name}") for v, name in option_out], dtype=np.int64)
        self.option_sample: list[float] = []
        #: per valve: whether the erk2 step takes its spool's damping pole exactly (set_temperature)
        self._exact_spool = [sim.integrator == "erk2" and bool(s.rate_parameters) for s in systems[:len(valves)]]
        for k, v in enumerate(valves):
            if v.params.fluid.oil_temperature_model:      # the YAML's oil, as set_temperature checks one
                try:
                    check_oil_step(v.params, systems[k].p, self.dt, self._exact_spool[k],
                                   kelvin(v.params.fluid.oil_temperature_c))
                except CommandError as err:
                    where = "" if lone else f"valves.{v.name}: "
                    raise ParameterError(f"{where}fluid.oil_temperature_c: {err}") from None
        self._state_off = plant.offsets("states")
        self._p_off = plant.offsets("p")
        self._configured = [s.p.copy() for s in systems[:len(valves)]]     # the valves' YAML (at reset)
        self._healthy = [p.copy() for p in self._configured]                # and the temperatures set since
        self._healthy_plant = systems[-1].p.copy() if plant_spec is not None else np.zeros(0)
        self._supply0 = [v.params.circuit.supply_pressure for v in valves]
        #: per valve: the supply pressure input in force without faults (Pa), the own load volume's flow
        self._supply = list(self._supply0)
        self._load_flow = [0.0] * len(valves)
        self._plant_i = {name: plant.index("input", name) for name in (plant_spec.inputs if plant_spec else {})}
        self._declare_inputs({
            **{f"{self._prefix[v.name]}duty_cycle": InputKind(partial(check_duty, duty_range=self._ranges[v.name]),
                                                              partial(self._take_command, v.name)) for v in valves},
            **{f"{self._prefix[v.name]}load_flow": InputKind(check_load_flow, partial(self._set_load_flow, k))
               for k, v in enumerate(valves) if self._flow_i[k] >= 0},
            **{f"{self._prefix[v.name]}supply_pressure": InputKind(check_supply_pressure, partial(self._set_supply, k))
               for k, v in enumerate(valves)},
            **{f"{self._prefix[v]}{name}": InputKind(partial(check_temperature, name.replace("_", " ")),
                                                     partial(self.set_temperature, v, name))
               for v, name in self._option_in if name in TEMPERATURE_INPUTS},
            **{name: InputKind(check, partial(self._put_plant_input, name))
               for name, check in (plant_spec.inputs.items() if plant_spec else ())}})

    def _what(self, valve: str, name: str) -> str:
        """How an error names a valve's input (`oil temperature`, `left: oil temperature`)."""
        return f"{self._prefix[valve]}{name}".replace(".", ": ").replace("_", " ") if self._prefix[valve] \
            else name.replace("_", " ")

    def _warm_up(self) -> None:
        """Load (or compile) every compiled function the stepping calls, now and on a copy (the state
        stays): compiled on first use in a loop's first wake it would hold the loop (and its stop
        check) for seconds, a minute on a busy machine with an empty kernel cache."""
        trial = self.sim.copy()
        trial.outputs()
        trial.advance(1)
        trial.advance_sample(1, self._signal_i, np.empty(len(self._signal_i)), 1)
        trial.run(np.zeros(0, dtype=np.int64), np.empty((0, len(trial.u))),
                  np.arange(trial.steps + 1, trial.steps + 3, dtype=np.int64))

    @property
    def has_cylinder(self) -> bool:
        """Whether the device composes a cylinder (a target of the cylinder faults)."""
        return False

    def duty_range(self, valve: str) -> tuple[float, ...]:
        """The duties `valve` takes (its command.duty_range)."""
        return self._ranges[valve]

    # --- time --------------------------------------------------------------------------------

    @property
    def steps(self) -> int:
        """Model steps since the start (model time = steps * dt)."""
        return self.sim.steps

    @steps.setter
    def steps(self, steps: int) -> None:
        self.sim.steps = steps

    @property
    def time(self) -> float:
        """Model time, s (an integer count of steps: it never drifts)."""
        return self.sim.steps * self.dt

    def stamp_ns(self, step: int | None = None) -> int:
        """The stamp of model step `step` (default: the present one)."""
        return self.origin_ns + (self.sim.steps if step is None else step) * self.dt_ns

    def next_due(self) -> int:
        """The first step at which a queued input (a ramping duty's next value among them) or a
        watchdog deadline falls (`inputs.NEVER` if none): where a stretch of compiled steps must stop."""
        return min(self.queue.next_step, *(w.deadline for w in self.watchdogs.values()))

    def skip(self, n: int) -> None:
        """Let n steps of model time pass without computing them (the model state is held): a real-time
        loop that fell too far behind, an external clock that jumped."""
        self.sim.steps += n

    def set_fault(self, reason: str) -> None:
        """Enter the fault state (the first reason stays until it is cleared)."""
        if self.fault is None:
            self.fault = reason
            self.fault_step = self.sim.steps

    def clear_fault(self) -> str | None:
        """Leave the fault state; the reason it had, or None."""
        was, self.fault, self.fault_step = self.fault, None, None
        return was

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

    # --- restarts ----------------------------------------------------------------------------

    def reset(self, *, keep_time: bool = False) -> str:
        """A fresh start: each valve at rest at its initial duty (its YAML's supply, no load flow), the
        plant at its start state, no faults, the watchdogs waiting for a first command; t = 0 and
        the log, counts and queue cleared, or with `keep_time` the present time goes on (the log
        and the refused inputs are kept, inputs queued for later still act, and the reset is
        logged). Returns what was done."""
        sim = self.sim
        steps = sim.steps
        x, w = [], []
        initial = [self._initial_duty(v) for v in self.valve_specs]
        for k, v in enumerate(self.valve_specs):
            state, current = self._rest_state(k, v.params, initial[k], 0.0, self._supply0[k], sim.integrator)
            x.append(state)
            w.append(current)
        if self.plant_spec is not None:
            x.append(np.array(self.plant_spec.rest))
        sim.x[:] = np.concatenate(x)
        sim.W[:] = 0.0
        sim.W[:len(w)] = w
        sim.steps = steps if keep_time else 0
        self._healthy = [p.copy() for p in self._configured]
        self.commands = {v.name: d for v, d in zip(self.valve_specs, initial)}
        self.duties = dict(self.commands)
        self._supply = list(self._supply0)
        self._load_flow = [0.0] * len(self.valve_specs)
        for k, d in enumerate(initial):
            sim.set_parameters(k, self._healthy[k])
            sim.u[self._duty_i[k]] = d
            sim.u[self._supply_i[k]] = self._supply0[k]
            if self._flow_i[k] >= 0:
                sim.u[self._flow_i[k]] = 0.0
            if self._volume_in_i[k] >= 0:
                sim.u[self._volume_in_i[k]] = self._volumes[k]
            self._limiters[k].value = d
            self._lim_step[k] = sim.steps
        if self.plant_spec is not None:
            sim.set_parameters(len(self.valve_specs), self._healthy_plant)
        for i in self._plant_i.values():
            sim.u[i] = 0.0
        for i, value in self._option_defaults:
            sim.u[i] = value
        sim.refresh_rates()
        for watchdog in self.watchdogs.values():
            watchdog.restart()
        self.clear_fault()
        self.faults = {}
        self.sensors.reset()
        what = "valves at rest at their initial duty" + (
            f", {self.plant_spec.at_rest}" if self.plant_spec is not None else "") + ", faults cleared"
        if keep_time:
            self._note(f"reset: {what}")
        else:
            self.rejected = []
            self.log = []
            self.shown = -1
            self.counts.clear()
            self.queue.clear()
            self._ramp_at = [-1] * len(self.valve_specs)
            self._set_feed({})
        self._inputs_changed()
        return what

    def _initial_duty(self, v: ValveSpec) -> float:
        return self.safe_duty if v.initial_duty is None else v.initial_duty

    def _rest_state(self, k: int, params: ValveParams, duty: float, load_flow: float, supply: float,
                    integrator: str) -> tuple[np.ndarray, float]:
        """Valve k's rest state (and coil current) at these inputs: solved once per inputs (a restart
        to the same rest is the same numbers, and costs nothing)."""
        key = (k, duty, load_flow, supply)
        found = self._rest.get(key) if params is self.valve_specs[k].params else None
        if found is None:
            rest = rest_state(params, self.kind, duty, load_flow, supply, integrator=integrator)
            found = (rest.state, rest.current)
            if params is self.valve_specs[k].params:
                self._rest[key] = found
        return found

    def prepare(self, params: Any = None) -> Prepared:
        """What `install` needs to put the model back at rest: at the present operating point (the
        duties in force, load flows, supplies and temperatures), or for a device that restarts at
        its start (`restart_at_start`) at its start; with `params` (the device's own kind, e.g. a
        `ValveParams`) new parameters. Reads the device and changes nothing, so it may run off the
        stepping thread (a new rest state takes 25-60 ms). Raises (ValueError, ParameterError,
        CommandError) for what cannot run, e.g. a model that diverges within TRIAL_STEPS at rest."""
        if params is None and self.restart_at_start:
            return Prepared(None, None, None, "")
        valves = self.valve_specs if params is None else self._valve_specs_of(params)
        if params is not None and valves[0].params.simulation.time_step != self.dt:
            raise ValueError("the model time step cannot change while the device runs")
        kind = valves[0].params.simulation.model
        systems = [valve_system(v.params, kind, v.name) for v in valves]
        if self.plant_spec is not None:
            systems.append(self.plant_spec.system)
        methods = {valve_integrator(v.params, kind) for v in valves}
        sim = Simulator(compose(systems, self.plant_spec.wires if self.plant_spec else ()), self.dt,
                        "erk2" if "erk2" in methods else valves[0].params.simulation.method)
        at_start = self.restart_at_start
        duties = [self._initial_duty(v) if at_start else self.duty_held(v.name) for v in valves]
        x, w = [], []
        for k, v in enumerate(valves):
            check_duty(duties[k], v.params.command.duty_range)
            flow = 0.0 if at_start else self._load_flow[k]
            supply = self._supply0[k] if at_start else self._supply[k]
            if params is not None and not at_start and self._supply[k] == self._supply0[k]:
                supply = v.params.circuit.supply_pressure        # the new YAML's, unless an input set it
            state, current = self._rest_state(k, v.params, duties[k], flow, supply, sim.integrator)
            x.append(state)
            w.append(current)
            i = sim.plant.index
            sim.u[i("input", f"{v.name}.duty_cycle")] = duties[k]
            sim.u[i("input", f"{v.name}.supply_pressure")] = supply
            if f"{v.name}.load_flow" in sim.plant.inputs:
                sim.u[i("input", f"{v.name}.load_flow")] = flow
                sim.u[i("input", f"{v.name}.load_volume")] = v.params.circuit.load_volume
            lay = kernel.layout(v.params, kind)
            for name, configured in zip(lay.inputs[len(kernel.INPUTS):], kernel.option_inputs(v.params), strict=True):
                now = f"{v.name}.{name}"
                keep = not at_start and now in self.plant.inputs
                sim.u[i("input", now)] = float(self.sim.u[self.plant.index("input", now)]) if keep else configured
        if self.plant_spec is not None:
            x.append(np.array(self.plant_spec.rest))
        sim.x[:] = np.concatenate(x)
        sim.W[:] = 0.0
        sim.W[:len(w)] = w
        problem = _trial_run(sim, [(sim.plant.index("output", f"{v.name}.pressure"),
                                    sim.plant.index("output", f"{v.name}.current"), PhysicalLimits.of(v.params))
                                   for v in valves])
        if problem is not None:
            at = ", ".join(f"{d:g}" for d in duties)
            raise ValueError(f"the model faults again at once at rest at duty {at}: {problem}")
        pressures = ", ".join(f"{bar(float(sim.x[o + 3])):.2f}" for o in sim.plant.offsets("states")[:len(valves)])
        what = f"model at rest at duty {', '.join(f'{d:g}' for d in duties)}, {pressures} bar"
        return Prepared(params, None if params is None else valves, sim, what)

    def _valve_specs_of(self, params: Any) -> tuple[ValveSpec, ...]:
        """The valves of new parameters of the device's kind (its configuration says; none takes any)."""
        raise ParameterError(f"{type(self).__name__}: its parameters cannot change while it runs")

    def install(self, prepared: Prepared) -> str:
        """Swap in what `prepare` made, at a step boundary (between two `run_to`): the model at rest,
        injected faults and a fault state cleared, model time going on; inputs taken since `prepare`
        act from now. Returns what was done (for the log)."""
        was = self.fault
        if prepared.sim is None:
            what = self.reset(keep_time=True)
        else:
            steps = self.sim.steps
            new = prepared.sim
            if self._same_layout(new):
                self.sim._S[:] = new._S            # the simulator's arrays stay (a lockstep holds them)
                self.sim.steps = steps
                sim = self.sim
            else:
                sim = new
                sim.steps = steps
            if prepared.valves is not None:
                self.params = prepared.params
                self._rest.clear()
                self._configure(prepared.valves, sim)
                if self.sensors.signals != self.signals:
                    self.sensors = Sensors(self.signals, self.sensors.period, self.sensors.seed)
                if self.restart_at_start:
                    self.reset(keep_time=True)
            self._healthy = [p.copy() for p in self._configured]
            self.faults = {}
            self.sensors.reset()
            names = self.valve_names
            for k, name in enumerate(names):
                self._limiters[k].value = float(sim.u[self._duty_i[k]])
                self._lim_step[k] = steps
                self._supply[k] = float(sim.u[self._supply_i[k]])
                try:
                    check_duty(self.duties[name], self._ranges[name])
                except CommandError as err:      # e.g. duty_range narrowed: keep what prepare() checked
                    self.counts.last_rejection = f"after a model restart: {err}"
            for (valve, name), i in zip(self._option_in, self._option_in_i):
                if name == "oil_temperature":       # the spool's pole follows the oil in force (R34)
                    try:
                        self.set_temperature(valve, name, float(sim.u[i]))
                    except CommandError as err:     # too cold for the new step: the YAML's oil stays
                        self.counts.last_rejection = f"after a model restart: {err}"
            what = prepared.what
            self._inputs_changed()
        self.clear_fault()
        return f"{what} (cleared fault: {was})" if was else what

    def _same_layout(self, sim: Simulator) -> bool:
        """`sim` runs the same compiled code on arrays of the same layout and tables as the device's."""
        old = self.sim
        return (sim._module is old._module and sim._S.shape == old._S.shape and sim.integrator == old.integrator
                and np.array_equal(sim._Fa, old._Fa) and np.array_equal(sim._FL, old._FL))

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

    def _fault_command(self, command: FaultCommand) -> None:
        if command.clear:
            self.clear(command.target, command.kind)
        else:
            assert command.fault is not None     # a command that is not a clear carries its fault
            self.inject(command.fault)

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
            out[f"{pre}duty_cycle"] = float(u[self._duty_i[k]])
            out[f"{pre}supply_pressure"] = float(u[self._supply_i[k]])
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
                self.on_input(self.sim.steps, f"{self._prefix[name]}supply_pressure", supply)

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
        if name == "oil_temperature":
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

    # --- fed inputs --------------------------------------------------------------------------

    def feed(self, name: str, steps: Sequence[int], values: Sequence[float]) -> None:
        """The input `name` (a plant's input, or a valve's load flow on its own volume) takes
        `values[j]` from step `steps[j]` on (increasing steps; one before the present step acts at
        the present step), in place of any earlier feed of it; CommandError for a value `submit`
        refuses. The values are put into the model inside the compiled calls (a profile of the
        timeline, sampled at the control instants); `on_input` hears each one as it acts."""
        fed = self._feedable()
        if name not in fed:
            raise CommandError(f"feed {name!r}: accepted {'is' if len(fed) == 1 else 'are'} {', '.join(fed) or 'none'}")
        st = np.asarray(steps, dtype=np.int64)
        vs = np.asarray(values, dtype=np.float64)
        if st.ndim != 1 or st.shape != vs.shape or np.any(np.diff(st) < 0):
            raise CommandError(f"feed {name}: accepted are as many values as steps, the steps increasing")
        check = self.inputs[name].check
        for v in vs:
            check(float(v))                         # raises, naming the value
        pending = self._pending_feed()
        now = self.sim.steps
        pending[name] = {int(k): float(v) for k, v in zip(np.maximum(st, now), vs)}   # a later value at a step wins
        self._set_feed(pending)

    def _feedable(self) -> dict[str, int]:
        """The inputs `feed` takes (plain model inputs: nothing happens on a change but the value)."""
        out = dict(self._plant_i)
        for k, name in enumerate(self.valve_names):
            if self._flow_i[k] >= 0:
                out[f"{self._prefix[name]}load_flow"] = self._flow_i[k]
        return out

    def _pending_feed(self) -> dict[str, dict[int, float]]:
        """The feed's rows not yet applied, per input: step -> value."""
        out: dict[str, dict[int, float]] = {n: {} for n in self._feed_names}
        for r in range(self._feed_next, len(self._feed_steps)):
            for j, n in enumerate(self._feed_names):
                v = float(self._feed_v[r, j])
                if not math.isnan(v):
                    out[n][self._feed_steps[r]] = v
        return out

    def _set_feed(self, tracks: dict[str, dict[int, float]]) -> None:
        tracks = {n: t for n, t in tracks.items() if t}
        fed = self._feedable()
        self._feed_names = tuple(tracks)
        self._feed_i = np.array([fed[n] for n in tracks], dtype=np.int64)
        self._feed_steps = sorted({k for t in tracks.values() for k in t})
        v = np.full((len(self._feed_steps), len(tracks)), np.nan)
        where = {k: r for r, k in enumerate(self._feed_steps)}
        for j, t in enumerate(tracks.values()):
            for k, x in t.items():
                v[where[k], j] = x
        self._feed_v = np.ascontiguousarray(v)
        self._feed_next = 0

    def _feed_row(self, r: int, step: int) -> None:
        """Row r of the feed is in force from `step` (it is put into the model by the caller or here)."""
        u, hook = self.sim.u, self.on_input
        for j, name in enumerate(self._feed_names):
            v = float(self._feed_v[r, j])
            if not math.isnan(v):
                u[self._feed_i[j]] = v
                if name.endswith("load_flow"):
                    self._load_flow[self._flow_i.index(int(self._feed_i[j]))] = v
                if hook is not None:
                    hook(step, name, v)
        self._feed_next = r + 1

    # --- duties and watchdogs ----------------------------------------------------------------

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
                self._reject(f"{self._prefix[valve]}duty_cycle", str(err))
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
            self.on_input(sim.steps, f"{self._prefix[valve]}duty_cycle", duty)

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
        k = self.valve_names.index(valve)
        p, supply, stuck = valve_fault_parameters(
            self._healthy[k], self._supply[k],
            (f for (target, _), f in self.faults.items() if target == valve and not f.sensor))
        if stuck:
            self.sim.x[self._state_off[k] + 2] = 0.0
        self.sim.set_parameters(k, p)
        self.sim.u[self._supply_i[k]] = supply
        if self.on_input is not None:
            self.on_input(self.sim.steps, f"{self._prefix[valve]}supply_pressure", supply)

    def _apply_plant_faults(self) -> None:
        """The plant's parameters: healthy, then every active fault on it (a device with a plant)."""
        raise FaultError("this device has no plant")

    def _note(self, text: str) -> None:
        """Something for the device's log (faults, watchdogs, resets), at the present model time."""
        self.log.append((self.time, text))

    # --- stepping ----------------------------------------------------------------------------

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
        ModelFault (and `fault` set) if the state runs away or the sample is no valve's."""
        sim = self.sim
        now = sim.steps
        fs = self._feed_steps
        r = self._feed_next
        fed = fs[r] if r < len(fs) else NEVER
        other = self._due_step(feed=False)
        if other <= now or fed <= now:
            self._due()                                # inputs due now act over the whole stretch
            fs = self._feed_steps
            r = self._feed_next
            fed = fs[r] if r < len(fs) else NEVER
            other = self._due_step(feed=False)
        if step >= now:
            # A fed row due at `step` itself goes into the same call (after the steps to it,
            # before the sample); one due earlier, or up to step + after, takes the plain path.
            last = step + after
            if other > last and (fed > last or (fed == step and (r + 1 == len(fs) or fs[r + 1] > last))):
                row = r if fed == step else -1
                if out is None:
                    out = np.empty(len(self._signal_i))
                try:
                    norm = sim.advance_sample(step - now, self._signal_i, out, after, (self._feed_i, self._feed_v, row))
                except MODEL_FAILURES as err:
                    self._fail(f"model step failed ({type(err).__name__}: {err})")
                if row >= 0:
                    self._feed_row(row, step)          # already in the model; for the hook and the bookkeeping
                if not math.isfinite(norm):
                    self._check_finite()               # raises, naming the time and the faults
                self._check_limits(out)
                return out
        self.advance_to(step)
        if out is None:
            return self.sample()
        out[:] = self.sample()
        return out

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
                        values = np.empty(len(self._signal_i))
                        if not math.isfinite(sim.advance_sample(stop - sim.steps, self._signal_i, values)):
                            self._check_finite()
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
                if values is not None:
                    self._check_limits(values)      # nothing a valve cannot produce leaves the device
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
        try:
            rows = sim.run(_NO_STEPS, np.empty((0, len(sim.u))), np.arange(first, last + 1, dtype=np.int64))
        except MODEL_FAILURES as err:
            self._fail(f"model step failed ({type(err).__name__}: {err})")
        if not self._all_outputs:
            rows = rows[:, self._signal_i]
        bad = self._rows_problem(rows)
        if bad is not None:
            k, problem = bad
            sim.steps = first + k
            self._fail(problem)
        self.recorder.record_block(self.stamp_ns(first), self.dt_ns, rows)  # type: ignore[union-attr]

    def _rows_problem(self, rows: np.ndarray) -> tuple[int, str] | None:
        """The first row (step) no valve can show, and why; None when all are fine."""
        for jp, ji, lim in self._limit_slots:
            p, i = rows[:, jp], rows[:, ji]
            # The usual case in four reductions (a NaN fails every comparison); the row only when not.
            if lim.pressure_min <= p.min() and p.max() <= lim.pressure_max and -lim.current_max <= i.min() \
                    and i.max() <= lim.current_max and np.isfinite(rows).all():
                continue
            ok = np.isfinite(rows).all(axis=1) & (p >= lim.pressure_min) & (p <= lim.pressure_max) & \
                (np.abs(i) <= lim.current_max)
            k = int(np.argmin(ok))
            return k, lim.problem(float(p[k]), float(i[k])) or "the model state ran away (non-finite)"
        return None

    def _check_limits(self, values: np.ndarray) -> None:
        """ModelFault (and `fault` set) when a valve's pressure or current in `values` (the signals)
        is none a valve can show."""
        for jp, ji, lim in self._limit_slots:
            p, i = values[jp], values[ji]
            if not (lim.pressure_min <= p <= lim.pressure_max and -lim.current_max <= i <= lim.current_max):
                self._fail(lim.problem(float(p), float(i)) or "the model state ran away (non-finite)")

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

    def _check_finite(self) -> None:
        x = self.sim.x
        if not math.isfinite(float(np.dot(x, x))):       # any inf or NaN makes the sum so (cheaper than isfinite().all())
            self._fail("the model state ran away (non-finite)")

    def _fail(self, problem: str) -> NoReturn:
        """The fault state (`fault`, until a restart) and ModelFault, naming the time and the active faults."""
        reason = (f"{problem} before t = {self.sim.time:.6g} s; "
                  f"active faults: {', '.join(f'{k}@{t}' for t, k in self.faults) or 'none'}")
        self.set_fault(reason)
        raise ModelFault(reason)

    def _due(self) -> None:
        """What falls due at the present step, in the devices' order: queued inputs and actions,
        fed inputs, then the watchdogs."""
        self._apply_due_inputs()
        steps = self.sim.steps
        while self._feed_next < len(self._feed_steps) and self._feed_steps[self._feed_next] <= steps:
            self._feed_row(self._feed_next, steps)
        self._check_watchdogs()

    # --- outputs -----------------------------------------------------------------------------

    def sample(self) -> np.ndarray:
        """The true values of `signals` now (SI: Pa, A, m per valve, the plant's), with the inputs in
        force from now on. A new array."""
        y = self.sim.outputs()
        self._outputs_taken(y)
        return y.copy() if self._all_outputs else y[self._signal_i]

    def _outputs_taken(self, y: np.ndarray) -> None:
        """What a sample's outputs `y` (every output) tell besides the signals: the load volumes,
        the options' outputs."""
        if self._wired_volumes:
            self._volumes = [float(y[i]) if i >= 0 else v for i, v in zip(self._volume_i, self._volumes)]
        if len(self._option_out_i):
            self.option_sample = y[self._option_out_i].tolist()

    def present_sample(self) -> Sample:
        """The sample at the present step (with the inputs in force from it on); it counts as shown."""
        self.shown = self.sim.steps
        self.last_sample = Sample(self.sim.steps, self.sample())
        return self.last_sample

    def measure(self, sample: Sample) -> np.ndarray:
        """What the sensors show of `sample` (sensor faults applied; NaN: no value, not to be
        published). Called once per sample, in order (a delay or noise fault keeps history)."""
        sensors = self.sensors
        if not sensors.active and not sensors.keeps_history:
            return sample.values
        return sensors.measure(sample.step * self.dt, sample.values)

    def record_values(self) -> dict[str, float]:
        """What a recorder receives now, SI: per valve (its names as its inputs and signals are
        named) duty_command (the duty in force), duty (after the fall-rate limiter), load_flow,
        supply_pressure, pressure, current, spool_position and its options' inputs and outputs;
        the plant's inputs and signals."""
        return self._record_values(self.sim.outputs())

    def _record_values(self, y: np.ndarray) -> dict[str, float]:
        u = self.sim.u
        plant = self.plant
        out: dict[str, float] = {}
        for k, name in enumerate(self.valve_names):
            pre = self._prefix[name]
            out[f"{pre}duty_command"] = self.duties[name]
            out[f"{pre}duty"] = float(u[self._duty_i[k]])
            flow = self._flow_i[k]
            out[f"{pre}load_flow"] = float(u[flow]) if flow >= 0 else self._wired_flow(name, y)
            out[f"{pre}supply_pressure"] = float(u[self._supply_i[k]])
            for role in kernel.OUTPUTS:
                out[f"{pre}{role}"] = float(y[plant.index("output", f"{name}.{role}")])
        for name, i in zip(self.option_inputs, self._option_in_i):
            out[name] = float(u[i])
        for name, i in zip(self.option_outputs, self._option_out_i):
            out[name] = float(y[i])
        for name, i in self._plant_i.items():
            out[name] = float(u[i])
        if self.plant_spec is not None:
            for name in self.plant_spec.signals:
                out[name] = float(y[plant.index("output", name)])
        return out

    def _wired_flow(self, valve: str, y: np.ndarray) -> float:
        wired = {dst: src for src, dst in (self.plant_spec.wires if self.plant_spec else ())}
        return float(y[self.plant.index("output", wired[f"{valve}.load_flow"])])

    def option_input_values(self) -> dict[str, float]:
        """The valve options' inputs in force (K), read without computing an output."""
        u = self.sim.u
        return {name: float(u[i]) for name, i in zip(self.option_inputs, self._option_in_i)}

    def load_volumes(self) -> list[float]:
        """Each valve's load volume at the last `sample()` (not updated by `advance_sample`'s fused
        path; m^3: its chamber's, or its own), in the order of `valve_names`. Its change over an
        interval / the interval is the valve's mean load flow there (the chamber's displacement
        flow is dV/dt)."""
        return list(self._volumes)


_NO_STEPS = np.empty(0, dtype=np.int64)


def _trial_run(sim: Simulator, limits: Sequence[tuple[int, int, PhysicalLimits]], steps: int = TRIAL_STEPS) -> str | None:
    """Run a copy of `sim` for `steps` steps with its inputs; why it faulted, or None. `limits`:
    per valve the output indices of its pressure and current, and its limits."""
    trial = sim.copy()
    try:
        for _ in range(0, steps, 10):
            trial.advance(10)
            if not trial.finite():
                return "model state went non-finite"
            y = trial.outputs()
            for jp, ji, lim in limits:
                problem = lim.problem(float(y[jp]), float(y[ji]))
                if problem is not None:
                    return problem
    except MODEL_FAILURES as err:
        return f"model step failed ({type(err).__name__}: {err})"
    return None


def _positive_int(value: int, name: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ValueError(f"{name} {value!r}: accepted is an integer >= 1")
    return value
