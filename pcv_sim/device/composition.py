"""A device's composition: the one `Simulator` of its valves and its plant, everything read off
the composite's layout once (input and output indices, the names of its inputs and signals, the
physical limits, the fall-rate limiters, the inputs it takes), its state (model time, the fault
state, the log), on which its parts build: inputs, duties and watchdogs and stepping
(`pcv_sim.device.device`), restarts (`restarts`), fed inputs (`feed`), injected faults
(`injection`), outputs (`outputs`). No ROS.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from functools import partial
from typing import Any, NoReturn

import numpy as np

from pcv_sim.device.faults import Fault
from pcv_sim.device.inputs import InputQueue, InputTiming, Watchdog
from pcv_sim.device.limits import PhysicalLimits
from pcv_sim.device.sensors import Sensors
from pcv_sim.device.spec import (
    RECORD_INPUTS,
    TEMPERATURE_INPUTS,
    InputCounts,
    InputHook,
    InputKind,
    ModelFault,
    PlantSpec,
    Recorder,
    Sample,
    ValveSpec,
)
from pcv_sim.errors import CommandError, ParameterError
from pcv_sim.io.topics import DUTY_CYCLE, FAULTS, LOAD_FLOW, SUPPLY_PRESSURE
from pcv_sim.model import kernel
from pcv_sim.simulation.duty import FallRateLimiter, check_duty
from pcv_sim.simulation.simulator import Simulator
from pcv_sim.simulation.system import Composite, compose
from pcv_sim.simulation.valve import (
    check_load_flow,
    check_oil_step,
    check_supply_pressure,
    check_temperature,
    valve_integrator,
    valve_system,
)
from pcv_sim.units import kelvin

__all__ = ["Composition"]


class Composition:
    """The composite model of a device and its layout, time and fault state (see the module
    docstring); `pcv_sim.device.device.Device` is it with its parts."""

    #: The device's parameters (its YAML: a valve's, a rig's), set by its configuration.
    params: Any
    #: The emulator's lone valve (`pcv_sim.device.valve.ValveDevice` sets it): one valve and no
    #: plant, its inputs, signals and topics named by their roles alone (`duty_cycle`, `pressure`);
    #: else `<valve>.<role>`. The bag layout, the diagnostics and the names below read it.
    lone_valve: bool = False
    # What the device's other parts offer (`Device`): the composition calls them.
    _take_command: Callable[[str, float], None]
    _set_load_flow: Callable[[int, float], None]
    _set_supply: Callable[[int, float], None]
    set_temperature: Callable[[str, str, Any], None]
    _put_plant_input: Callable[[str, float], None]
    reset: Callable[..., str]
    set_watchdog_timeout: Callable[[float], None]
    _set_feed: Callable[[dict[str, dict[int, float]]], None]
    _inputs_changed: Callable[[], None]
    input_values: Callable[[], dict[str, float]]
    duty_held: Callable[[str], float]
    _bind_stretch: Callable[[], None]

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
        lone = self.lone_valve
        if lone and (len(valves) != 1 or plant_spec is not None):
            raise ValueError(f"a lone valve is one valve and no plant; got {len(valves)} valves"
                             f"{' and a plant' if plant_spec is not None else ''}")
        #: A valve's names: its role alone on a device of one valve and no plant, else `<valve>.<role>`.
        self._prefix = {v.name: "" if lone else f"{v.name}." for v in valves}
        names = self.valve_names
        self._k = {n: k for k, n in enumerate(names)}
        self._duty_i = [plant.index("input", f"{n}.{DUTY_CYCLE}") for n in names]
        self._supply_i = [plant.index("input", f"{n}.{SUPPLY_PRESSURE}") for n in names]
        self._flow_i = [plant.inputs.index(f"{n}.{LOAD_FLOW}") if f"{n}.{LOAD_FLOW}" in plant.inputs else -1
                        for n in names]
        self._volume_in_i = [plant.inputs.index(f"{n}.load_volume") if f"{n}.load_volume" in plant.inputs else -1
                             for n in names]
        wired = {dst: src for src, dst in (plant_spec.wires if plant_spec is not None else ())}
        #: per valve: the output its load volume is wired from (the plant's), or -1 (its own, constant)
        self._volume_i = [plant.index("output", wired[f"{n}.load_volume"]) if f"{n}.load_volume" in wired else -1
                          for n in names]
        self._volumes = [v.params.circuit.load_volume for v in valves]
        self._wired_volumes = any(i >= 0 for i in self._volume_i)
        #: per valve, what `record_values` reads: its name, its keys, the indices of its duty input, load flow
        #: (its own: input; a chamber's: the plant's output), supply input and its three outputs
        self._record_slots = [
            (n, tuple(f"{self._prefix[n]}{r}" for r in (*RECORD_INPUTS, *kernel.OUTPUTS)), self._duty_i[k],
             self._flow_i[k], plant.index("output", wired[f"{n}.{LOAD_FLOW}"]) if f"{n}.{LOAD_FLOW}" in wired else -1,
             self._supply_i[k], tuple(plant.index("output", f"{n}.{r}") for r in kernel.OUTPUTS))
            for k, n in enumerate(names)]
        self._plant_signal_i = [(name, plant.index("output", name)) for name in
                                (plant_spec.signals if plant_spec is not None else ())]
        layouts = [kernel.layout(v.params, kind) for v in valves]
        sampled = [f"{v.name}.{o}" for v, lay in zip(valves, layouts) for o in lay.outputs]
        self.signals: tuple[str, ...] = tuple(
            f"{self._prefix[v.name]}{o}" for v, lay in zip(valves, layouts) for o in lay.outputs)
        if plant_spec is not None:
            sampled += plant_spec.signals
            self.signals += plant_spec.signals
        #: Where each signal is among the composite's outputs (what the compiled sampling selects).
        self.signal_outputs = np.array([plant.index("output", s) for s in sampled], dtype=np.int64)
        #: every output, in order: the outputs are the signals (no copy of a traced block's rows)
        self._all_outputs = np.array_equal(self.signal_outputs, np.arange(len(plant.outputs)))
        self._ranges = {v.name: v.params.command.duty_range for v in valves}
        self._limiters = [FallRateLimiter(v.params.command.duty_fall_rate_limit) for v in valves]
        self._limited = [k for k, v in enumerate(valves) if v.params.command.duty_fall_rate_limit is not None]
        self._lim_step = [-1] * len(valves)     # the step each limiter's value was last taken at
        self._ramp_at = [-1] * len(valves)      # the step each ramp's next step is queued for
        #: per valve: its limits and where its pressure and current are among the signals
        self.limits = {v.name: PhysicalLimits.of(v.params) for v in valves}
        self._limit_slots = [(sampled.index(f"{v.name}.pressure"), sampled.index(f"{v.name}.current"),
                              self.limits[v.name]) for v in valves]
        #: The limits as bounds of the signals (lowest, highest; none on the others): what the
        #: compiled sampling checks, in the order of `signals`.
        lo, hi = np.full(len(sampled), -math.inf), np.full(len(sampled), math.inf)
        for jp, ji, lim in self._limit_slots:
            lo[jp], hi[jp] = lim.pressure_min, lim.pressure_max
            lo[ji], hi[ji] = -lim.current_max, lim.current_max
        self.signal_bounds = (lo, hi)
        #: The planned stretch's compiled call (`Simulator.sample_entry`: no fed row) and its fixed
        #: arguments: the arena, the tables, their layout, the step, the signals and their bounds;
        #: the device binds its stretch to them (`Device.planned_stretch`).
        fn, arrays = sim.sample_entry()
        self._planned_call = (fn, *arrays, self.dt, self.signal_outputs, lo, hi)
        self._bind_stretch()
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
            **{f"{self._prefix[v.name]}{DUTY_CYCLE}": InputKind(partial(check_duty, duty_range=self._ranges[v.name]),
                                                              partial(self._take_command, v.name)) for v in valves},
            **{f"{self._prefix[v.name]}{LOAD_FLOW}": InputKind(check_load_flow, partial(self._set_load_flow, k))
               for k, v in enumerate(valves) if self._flow_i[k] >= 0},
            **{f"{self._prefix[v.name]}{SUPPLY_PRESSURE}": InputKind(check_supply_pressure, partial(self._set_supply, k))
               for k, v in enumerate(valves)},
            **{f"{self._prefix[v]}{name}": InputKind(partial(check_temperature, name.replace("_", " ")),
                                                     partial(self.set_temperature, v, name))
               for v, name in self._option_in if name in TEMPERATURE_INPUTS},
            **{name: InputKind(check, partial(self._put_plant_input, name))
               for name, check in (plant_spec.inputs.items() if plant_spec else ())}})

    def _declare_inputs(self, inputs: Mapping[str, InputKind]) -> None:
        """The inputs `submit` takes, by name (counted from now on)."""
        self.inputs = dict(inputs)
        self.counts.declare((*inputs, FAULTS))

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
        trial.advance_sample(1, self.signal_outputs, np.empty(len(self.signal_outputs)), 1, bounds=self.signal_bounds)
        trial.run(np.zeros(0, dtype=np.int64), np.empty((0, len(trial.u))),
                  np.arange(trial.steps + 1, trial.steps + 3, dtype=np.int64))

    @property
    def has_cylinder(self) -> bool:
        """Whether the device composes a cylinder (a target of the cylinder faults)."""
        return False

    def duty_range(self, valve: str) -> tuple[float, ...]:
        """The duties `valve` takes (its command.duty_range)."""
        return self._ranges[valve]

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

    @property
    def input_names(self) -> tuple[str, ...]:
        """The inputs `submit` takes, by name."""
        return tuple(self.inputs)

    def _note(self, text: str) -> None:
        """Something for the device's log (faults, watchdogs, resets), at the present model time."""
        self.log.append((self.time, text))


def _positive_int(value: int, name: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ValueError(f"{name} {value!r}: accepted is an integer >= 1")
    return value
