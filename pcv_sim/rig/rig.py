"""The rig without ROS: the valves and the steering cylinder in one `Simulator` at one fixed step.

Each valve's load port is one cylinder chamber: the valve's pressure state feeds the cylinder's
`pressure_a|b`; the chamber's displacement flow and volume feed the valve's `load_flow` and
`load_volume` (Eq. 15 with the chamber's V). Everything is integrated together at
`rig.time_step` (0.1 ms) with the valves' integrator (Heun for the simplified model), so the
load flow is never a step late.

Inputs, fault commands and watchdogs are every device's (`pcv_sim.device.device`, the
emulator's too): an input (`submit`: `<valve>.duty_cycle`, `cylinder.external_force`, a valve
option's `<valve>.<temperature>`) is checked on arrival (refused with what is accepted, counted;
the last valid one stays) and acts from its step; `set_duty` and the other setters act from the
present step on; the watchdog runs in model time: `watchdog_timeout` s after a valve's last valid
command took effect its duty falls to `safe_duty`, and the next valid command resumes. The
rig starts with each valve at rest at its `initial_duty`, its watchdog waiting for a first command
(no controller yet: it does not fire), and the piston at `initial_position`, at rest.

Faults (`pcv_sim.device.faults`) are injected and cleared at the present step; scheduled inputs
(`schedule`) act at the first step at or after their time; a fed input (`feed`: a profile's values
at given steps, the external force) takes its values at their steps inside the compiled calls,
so a profile costs the lockstep no Python call per control period. Everything is deterministic: the
same inputs at the same steps give the same numbers bit for bit. A state that runs away (non-finite)
raises RigError and is the device's fault state (`fault`, `pcv_sim.device.device`) until `reset`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from functools import partial
from typing import Any, NoReturn

import numpy as np

from pcv_sim.device.device import MODEL_FAILURES, Device, InputKind, Sample
from pcv_sim.device.faults import CYLINDER
from pcv_sim.device.inputs import NEVER, WatchdogState
from pcv_sim.device.sensors import Sensors
from pcv_sim.errors import CommandError, ParameterError, PcvSimError
from pcv_sim.io.topics import OPTION_INTERFACE
from pcv_sim.model import kernel
from pcv_sim.plant import cylinder
from pcv_sim.plant.cylinder import cylinder_system
from pcv_sim.rig.params import RigParams
from pcv_sim.simulation.duty import check_duty
from pcv_sim.simulation.rest import rest_state
from pcv_sim.simulation.simulator import Simulator
from pcv_sim.simulation.stepper import check_oil_step, check_temperature
from pcv_sim.simulation.system import compose
from pcv_sim.simulation.valve import valve_integrator, valve_system
from pcv_sim.units import kelvin

__all__ = [
    "CYLINDER_SIGNALS",
    "EXTERNAL_FORCE",
    "MAX_EXTERNAL_FORCE",
    "TEMPERATURE_INPUTS",
    "VALVE_SIGNALS",
    "InputHook",
    "Rig",
    "RigError",
    "check_external_force",
    "rig_signals",
    "signal_kind",
    "signal_names",
]

VALVE_SIGNALS = ("pressure", "current", "spool_position")
CYLINDER_SIGNALS = ("position", "velocity", "effort")


def signal_names(valve_names: Sequence[str], options: Mapping[str, Sequence[str]] | None = None) -> tuple[str, ...]:
    """The rig's sampled signals in their order: `<valve>.<VALVE_SIGNALS>` per valve and the
    outputs its options bring (`options`: valve -> names), then `cylinder.<...>`."""
    opts = options or {}
    return tuple(f"{n}.{s}" for n in valve_names for s in (*VALVE_SIGNALS, *opts.get(n, ()))) + tuple(
        f"cylinder.{s}" for s in CYLINDER_SIGNALS)


def rig_signals(params: RigParams) -> tuple[str, ...]:
    """`signal_names` of a rig's valves with the outputs of their options (docs/model.md R33-R35:
    coil_temperature and coil_resistance of a heating coil, core_position of a separate core)."""
    kind = params.valves[0].params.simulation.model
    return signal_names([v.name for v in params.valves],
                        {v.name: kernel.layout(v.params, kind).outputs[len(kernel.OUTPUTS):] for v in params.valves})


def signal_kind(signal: str) -> str:
    """The physical kind of a rig signal, a duty, the setpoint or a controller flag (`pcv_sim.units.KINDS`)."""
    if signal.startswith("controller."):
        return "number"
    tail = signal.rsplit(".", 1)[-1]
    return {"pressure": "pressure", "current": "current", "spool_position": "length", "duty": "fraction",
            "position": "length", "velocity": "velocity", "effort": "force", "setpoint": "length",
            "coil_temperature": "temperature", "core_position": "length",
            "oil_temperature": "temperature", "ambient_temperature": "temperature"}.get(tail, "number")


#: N; beyond this an external force is a unit slip (kN for N), not a steering load.
MAX_EXTERNAL_FORCE = 1.0e6
#: The input name of the external force in `Rig.on_input` (valve inputs are `<valve>.duty_cycle`,
#: `<valve>.supply_pressure`).
EXTERNAL_FORCE = "cylinder.external_force"
#: `Rig.on_input(step, name, value)`: an input of the model changed, acting from `step` on.
InputHook = Callable[[int, str, float], None]


def check_external_force(force: Any) -> float:
    """The external force (N) as the rig takes it; CommandError saying what is accepted."""
    if isinstance(force, bool) or not isinstance(force, (int, float)) or not math.isfinite(force) \
            or abs(force) > MAX_EXTERNAL_FORCE:
        raise CommandError(f"external force {force!r}: accepted is a finite number of N within "
                           f"+-{MAX_EXTERNAL_FORCE:g} N")
    return float(force)


class RigError(PcvSimError, RuntimeError):
    """The rig cannot go on: the model state ran away (non-finite), as the emulator's fault state."""


#: The valve options' temperature inputs (R33, R34) and the valve YAML's switch that brings each.
TEMPERATURE_INPUTS = {"ambient_temperature": "solenoid.coil_temperature: lumped",
                      "oil_temperature": "fluid.temperature: input"}


class Rig(Device):
    """N valves + one cylinder at one fixed step (a `Device` of valves and a plant; see the module
    docstring). Its queue holds inputs (`submit`), fault commands (`submit_fault`) and actions
    (`schedule`)."""

    params: RigParams

    def __init__(self, params: RigParams, *, seed: int = 0) -> None:
        valves = params.valves
        super().__init__(params.timing.time_step, [v.name for v in valves],
                         round(params.timing.watchdog_timeout / params.timing.time_step),
                         safe_duty=params.timing.safe_duty)
        self.params = params
        kind = valves[0].params.simulation.model
        self.kind = kind
        systems = [valve_system(v.params, kind, v.name) for v in valves]
        systems.append(cylinder_system(params.cylinder, "cylinder"))
        wires = []
        for v in valves:
            c = v.chamber
            if c not in ("a", "b"):
                continue                    # on its own load volume: load_flow and load_volume stay inputs
            wires += [(f"{v.name}.pressure", f"cylinder.pressure_{c}"), (f"cylinder.flow_{c}", f"{v.name}.load_flow"),
                      (f"cylinder.volume_{c}", f"{v.name}.load_volume")]
        self.plant = compose(systems, wires)
        # One integrator for all: erk2 when a valve's spool pole needs it (oil temperature, R34).
        methods = {valve_integrator(v.params, kind) for v in valves}
        self.sim = Simulator(self.plant, self.dt, "erk2" if "erk2" in methods else valves[0].params.simulation.method)
        plant = self.plant
        self._duty_i = [plant.index("input", f"{n}.duty_cycle") for n in self.valve_names]
        #: per valve: (its command.duty_range, its duty's input index): set_duty's look-up
        self._duty_slot = {v.name: (v.params.command.duty_range, self._duty_i[k]) for k, v in enumerate(valves)}
        self._supply_i = [plant.index("input", f"{n}.supply_pressure") for n in self.valve_names]
        self._force_i = plant.index("input", "cylinder.external_force")
        #: Valves on their own load volume: (input index of load_flow, of load_volume, the volume).
        self._own_volume = [(plant.index("input", f"{v.name}.load_flow"), plant.index("input", f"{v.name}.load_volume"),
                             v.params.circuit.load_volume) for v in valves if v.chamber not in ("a", "b")]
        self.signals = rig_signals(params)
        self.sample_every = params.steps_per_period
        self._signal_i = np.array([plant.index("output", s) for s in self.signals])
        #: per valve: the output its load volume is wired from (the chamber's), or -1 (its own, constant)
        self._volume_i = [plant.index("output", f"cylinder.volume_{v.chamber}") if v.chamber in ("a", "b") else -1
                          for v in valves]
        self._volumes = [v.params.circuit.load_volume for v in valves]
        #: The valve options' inputs (ambient and oil temperature, K; R33, R34) at their configured
        #: values: (input index, value) per valve that has them.
        self._option_inputs = [(plant.index("input", f"{v.name}.{name}"), value) for v in valves
                               for name, value in zip(kernel.layout(v.params, kind).inputs[len(kernel.INPUTS):],
                                                      kernel.option_inputs(v.params), strict=True)]
        #: The valve options' signals the valves have (`<valve>.<name>`, io.topics.OPTION_INTERFACE):
        #: inputs (temperatures, K: `set_temperature`) and outputs, which are among `signals` (their
        #: true values at the last `sample()`: `option_sample`).
        self.option_inputs = tuple(f"{v.name}.{name}" for v in valves
                                   for name in kernel.layout(v.params, kind).inputs[len(kernel.INPUTS):])
        outputs = {e.name for e in OPTION_INTERFACE if e.direction == "out"}
        self.option_outputs = tuple(s for s in self.signals if s.partition(".")[2] in outputs)
        self._option_in_i = [plant.index("input", name) for name in self.option_inputs]
        self._option_out_i = np.array([plant.index("output", name) for name in self.option_outputs], dtype=np.int64)
        self.option_sample: list[float] = []
        #: per valve: whether the erk2 step takes its spool's damping pole exactly (set_temperature)
        self._exact_spool = [self.sim.integrator == "erk2" and bool(s.rate_parameters) for s in systems[:-1]]
        for k, v in enumerate(valves):
            if v.params.fluid.oil_temperature_model:      # the YAML's oil, as set_temperature checks one
                try:
                    check_oil_step(v.params, systems[k].p, self.dt, self._exact_spool[k],
                                   kelvin(v.params.fluid.oil_temperature_c))
                except CommandError as err:
                    raise ParameterError(f"valves.{v.name}: fluid.oil_temperature_c: {err}") from None
        self._state_off = plant.offsets("states")
        self._configured = [s.p.copy() for s in systems[:-1]]     # the valves' YAML (at reset)
        self._healthy = [s.p.copy() for s in systems[:-1]]        # and the temperatures set since
        self._healthy_cylinder = systems[-1].p.copy()
        self._supply0 = [v.params.circuit.supply_pressure for v in valves]
        self.sensors = Sensors(self.signals, params.timing.control_period, seed)
        #: Called whenever an input of the model (a duty in force, a supply pressure, the external
        #: force) changes, with the step it acts from (a recorder's hook); None: nobody listens.
        self.on_input: InputHook | None = None
        self._rest: list[tuple[np.ndarray, float]] | None = None     # the valves' initial rest states
        #: Fed inputs (`feed`): their names, input indices, and one row per step at which any of
        #: them changes (NaN: that input does not change there); rows from _feed_next on are pending.
        self._feed_names: tuple[str, ...] = ()
        self._feed_i = np.zeros(0, dtype=np.int64)
        self._feed_steps: list[int] = []
        self._feed_v = np.zeros((0, 0))
        self._feed_next = 0
        self._declare_inputs({
            **{f"{v.name}.duty_cycle": InputKind(partial(check_duty, duty_range=v.params.command.duty_range),
                                                 partial(self._take_command, v.name)) for v in valves},
            EXTERNAL_FORCE: InputKind(check_external_force, self._put_external_force),
            **{f"{v.name}.{name}": InputKind(partial(check_temperature, name.replace('_', ' ')),
                                             partial(self.set_temperature, v.name, name))
               for v in valves for name in kernel.layout(v.params, kind).inputs[len(kernel.INPUTS):]
               if name in TEMPERATURE_INPUTS}})
        self.reset()
        # Compile (or load from the cache) the composite's functions now, not in the first run
        # (whose speed would then count the compile): each one the lockstep and the node call.
        self.sim.outputs()
        self.sim.advance(1)
        self.sim.advance_sample(1, self._signal_i, np.empty(len(self._signal_i)), 1)
        self.reset()

    # --- state -------------------------------------------------------------------------------

    def reset(self, *, keep_time: bool = False) -> None:
        """Valves at rest at their initial duty, piston at rest at its initial position, no faults,
        no scheduled inputs; t = 0, or with `keep_time` the present time goes on (the watchdogs
        wait for a first command again, as at a start; the log and the refused commands are kept, inputs scheduled for later
        still act, and the reset is logged)."""
        sim = self.sim
        steps = sim.steps
        if self._rest is None:              # the same every time (the valves' YAML): solved once
            self._rest = []
            for v in self.params.valves:
                rest = rest_state(v.params, self.kind, v.initial_duty, 0.0, v.params.circuit.supply_pressure,
                                  integrator=self.sim.integrator)
                self._rest.append((rest.state, rest.current))
        x = [state for state, _ in self._rest]
        w = [current for _, current in self._rest]
        x.append(np.array([self.params.cylinder.initial_position, 0.0]))
        sim.x[:] = np.concatenate(x)
        sim.W[:] = 0.0
        sim.W[:len(w)] = w
        sim.steps = steps if keep_time else 0
        self._healthy = [p.copy() for p in self._configured]
        self.commands = {v.name: v.initial_duty for v in self.params.valves}
        self.duties = dict(self.commands)
        for k, v in enumerate(self.params.valves):
            sim.set_parameters(k, self._healthy[k])
            sim.u[self._duty_i[k]] = v.initial_duty
            sim.u[self._supply_i[k]] = self._supply0[k]
        sim.set_parameters(len(self.params.valves), self._healthy_cylinder)
        sim.u[self._force_i] = 0.0
        for i_flow, i_volume, volume in self._own_volume:
            sim.u[i_flow], sim.u[i_volume] = 0.0, volume
        for i, value in self._option_inputs:
            sim.u[i] = value
        self._restart_watchdogs()
        self.clear_fault()
        self.faults = {}
        self.sensors.reset()
        if keep_time:
            self.log.append((self.time, "reset: valves at rest at their initial duty, piston at rest at its initial "
                                        "position, faults cleared"))
        else:
            self.rejected = []
            self.log = []
            self.shown = -1
            self.counts.clear()
            self.queue.clear()
            self._set_feed({})
        self._inputs_changed()

    def _inputs_changed(self) -> None:
        """Every input to the hook (at a reset: they may all have changed)."""
        hook = self.on_input
        if hook is None:
            return
        steps, u = self.sim.steps, self.sim.u
        for k, name in enumerate(self.valve_names):
            hook(steps, f"{name}.duty_cycle", float(u[self._duty_i[k]]))
            hook(steps, f"{name}.supply_pressure", float(u[self._supply_i[k]]))
        hook(steps, EXTERNAL_FORCE, float(u[self._force_i]))
        for name, i in zip(self.option_inputs, self._option_in_i):
            hook(steps, name, float(u[i]))

    def input_values(self) -> dict[str, float]:
        """The inputs in force now, by the names `on_input` uses (SI)."""
        u = self.sim.u
        out = {}
        for k, name in enumerate(self.valve_names):
            out[f"{name}.duty_cycle"] = float(u[self._duty_i[k]])
            out[f"{name}.supply_pressure"] = float(u[self._supply_i[k]])
        out[EXTERNAL_FORCE] = float(u[self._force_i])
        for name, i in zip(self.option_inputs, self._option_in_i):
            out[name] = float(u[i])
        return out

    @property
    def steps(self) -> int:
        return self.sim.steps

    @steps.setter
    def steps(self, steps: int) -> None:
        self.sim.steps = steps

    @property
    def watchdog_fired(self) -> dict[str, bool]:
        """Per valve: has its watchdog fired (and no command come since)."""
        return {name: w.state == WatchdogState.FIRED for name, w in self.watchdogs.items()}


    def sample(self) -> np.ndarray:
        """The true values of `signals` now (SI: Pa, A, m per valve; m, m/s, N for the cylinder),
        with the inputs in force from now on. A new array."""
        y = self.sim.outputs()
        self._volumes = [float(y[i]) if i >= 0 else v for i, v in zip(self._volume_i, self._volumes)]
        if len(self._option_out_i):
            self.option_sample = y[self._option_out_i].tolist()
        return np.asarray(y[self._signal_i])

    def load_volumes(self) -> list[float]:
        """Each valve's load volume at the last `sample()` (not updated by `advance_sample`'s fused
        path; m^3: its chamber's, or its own), in the
        order of `valve_names`. Its change over an interval / the interval is the valve's mean load
        flow there (the chamber's displacement flow is dV/dt)."""
        return list(self._volumes)

    # --- inputs ------------------------------------------------------------------------------

    def set_duty(self, valve: str, duty: Any) -> None:
        """The duty command of `valve` from the present step on; CommandError (logged, the last
        valid command stays) unless it is within the valve's command.duty_range."""
        slot = self._duty_slot.get(valve)
        if slot is None:
            self.valve_names.index(valve)              # ValueError naming it, as for any unknown valve
        assert slot is not None
        lo, hi = slot[0]
        if type(duty) is float and lo <= duty <= hi:   # the common case: what check_duty would return
            d = duty
        else:
            try:
                d = check_duty(duty, (lo, hi))
            except CommandError as err:
                self._reject(f"{valve}.duty_cycle", str(err))
                raise
        self._take_command(valve, d)

    def duty_range(self, valve: str) -> tuple[float, ...]:
        return self._duty_slot[valve][0]

    def _put_duty(self, valve: str, duty: float) -> None:
        sim = self.sim
        sim.u[self._duty_slot[valve][1]] = duty
        if self.on_input is not None:
            self.on_input(sim.steps, f"{valve}.duty_cycle", duty)

    def _waiting_duty(self, valve: str) -> float:
        return self.params.valve(valve).initial_duty

    @property
    def has_cylinder(self) -> bool:
        return True

    def set_external_force(self, force: Any) -> None:
        """The external force on the rod (N, + toward +x: extending) from the present step on."""
        self._put_external_force(check_external_force(force))

    def _put_external_force(self, force: float) -> None:
        self.sim.u[self._force_i] = force
        if self.on_input is not None:
            self.on_input(self.sim.steps, EXTERNAL_FORCE, force)

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
        params = self.params.valves[k].params
        inputs = kernel.layout(params, self.kind).inputs
        if name not in inputs[len(kernel.INPUTS):]:
            if name not in TEMPERATURE_INPUTS:
                raise CommandError(f"{valve}: temperature input {name!r}: accepted are {', '.join(TEMPERATURE_INPUTS)}")
            raise CommandError(f"{valve}: no {name.replace('_', ' ')} input; the valve YAML's "
                               f"{TEMPERATURE_INPUTS[name]} brings it")
        value = check_temperature(f"{valve}: {name.replace('_', ' ')}", temperature)
        if name == "oil_temperature":
            off = self.plant.offsets("p")[k]
            p = self.sim.P[off:off + kernel.N_PARAMS]
            check_oil_step(params, p, self.dt, self._exact_spool[k], value)
            if self._exact_spool[k]:
                rate = kernel.spool_rate(value, p)
                self._healthy[k][kernel.V_RATE] = rate
                self.sim.P[off + kernel.V_RATE] = rate
                self.sim.refresh_rates()
        self.sim.u[self.plant.index("input", f"{valve}.{name}")] = value
        if self.on_input is not None:
            self.on_input(self.sim.steps, f"{valve}.{name}", value)

    def _apply_plant_faults(self) -> None:
        """The cylinder's parameter vector: healthy, then every active fault on it."""
        p = self._healthy_cylinder.copy()
        for (target, kind), f in self.faults.items():
            if target != CYLINDER:
                continue
            if kind == "cylinder_friction":
                friction = f.values["friction"]
                p[cylinder.F_C] = friction
                # The friction's slope at v = 0 (F / v_s) kept at most m / dt: a steeper one is a
                # stiffer piston than the explicit step can hold (as the sticking spool's).
                p[cylinder.V_S] = max(p[cylinder.V_S], friction * self.dt / p[cylinder.MASS])
            elif kind == "cylinder_jam":
                p[cylinder.JAMMED] = 1.0
                self.sim.x[self._state_off[-2] + 1] = 0.0      # seized where it is: no velocity
        self.sim.set_parameters(len(self.valve_names), p)

    def _healthy_parameters(self, valve: str) -> np.ndarray:
        return self._healthy[self.valve_names.index(valve)]

    def _supply_in_force(self, valve: str) -> float:
        return self._supply0[self.valve_names.index(valve)]

    def _put_valve(self, valve: str, parameters: np.ndarray, supply: float, stuck: bool) -> None:
        k = self.valve_names.index(valve)
        if stuck:
            self.sim.x[self._state_off[k] + 2] = 0.0
        self.sim.set_parameters(k, parameters)
        self.sim.u[self._supply_i[k]] = supply
        if self.on_input is not None:
            self.on_input(self.sim.steps, f"{valve}.supply_pressure", supply)

    def schedule(self, t: float, action: Callable[[], None]) -> int:
        """Run `action` (e.g. `lambda: rig.inject(f)`) at the first step at or after time t (s); returns
        that step."""
        return self.schedule_step(math.ceil(t / self.dt - 1e-9), action)

    def schedule_step(self, step: int, action: Callable[[], None]) -> int:
        """Run `action` at `step` (the present one if that has passed); returns the step."""
        step = max(self.sim.steps, step)
        self.queue.push(step, action)
        return step

    def feed(self, name: str, steps: Sequence[int], values: Sequence[float]) -> None:
        """The input `name` (only `EXTERNAL_FORCE`, N) takes `values[j]` from step `steps[j]` on
        (increasing steps; one before the present step acts at the present step), in place of any
        earlier feed of it; CommandError for a value `set_external_force` refuses. The values are
        put into the model inside the compiled calls (a profile of the timeline, sampled at the
        control instants); `on_input` hears each one as it acts."""
        if name != EXTERNAL_FORCE:
            raise CommandError(f"feed {name!r}: accepted is {EXTERNAL_FORCE}")
        st = np.asarray(steps, dtype=np.int64)
        vs = np.asarray(values, dtype=np.float64)
        if st.ndim != 1 or st.shape != vs.shape or np.any(np.diff(st) < 0):
            raise CommandError(f"feed {name}: accepted are as many values as steps, the steps increasing")
        for v in vs[~(np.isfinite(vs) & (np.abs(vs) <= MAX_EXTERNAL_FORCE))][:1]:
            check_external_force(float(v))          # raises, naming the value
        pending = self._pending_feed()
        now = self.sim.steps
        pending[name] = {int(k): float(v) for k, v in zip(np.maximum(st, now), vs)}   # a later value at a step wins
        self._set_feed(pending)

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
        self._feed_names = tuple(tracks)
        self._feed_i = np.array([self.plant.index("input", n) for n in tracks], dtype=np.int64)
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
                if hook is not None:
                    hook(step, name, v)
        self._feed_next = r + 1

    # --- the node-facing stepping and restarts (pcv_sim.device.device) --------------------------

    def first_open_step(self) -> int:
        """The present step, or the one after the last sample handed out (`run_to`, `present_sample`)."""
        return max(self.sim.steps, self.shown + 1)

    def run_to(self, step: int) -> list[Sample]:
        """`Device.run_to`: `advance_to` each multiple of `sample_every` on the way (its `sample()`
        taken there) and then `step`; a RigError ends it with `fault` set. While `fault` is set
        model time passes without computing (inputs still act at their steps)."""
        out: list[Sample] = []
        per = self.sample_every
        if self.fault is not None:
            self._idle_to(step)
            return out
        try:
            while self.sim.steps < step:
                boundary = (self.sim.steps // per + 1) * per
                if boundary > step:
                    self.advance_to(step)
                    break
                self.advance_to(boundary)
                out.append(Sample(boundary, self.sample()))
        except RigError:
            self._idle_to(step)
        if out:
            self.shown = out[-1].step
        return out

    def _idle_to(self, step: int) -> None:
        """To `step` without computing (the fault state): what falls due acts at its step."""
        sim = self.sim
        while sim.steps < step:
            sim.steps = min(step, self._next_due())
            self._due()

    def present_sample(self) -> Sample:
        self.shown = self.sim.steps
        return Sample(self.sim.steps, self.sample())

    def prepare(self, params: RigParams | None = None) -> RigParams:
        """The rig's rest state is its YAML's (solved once): nothing to compute. New parameters are
        refused (ParameterError): the rig's physics is set at its start."""
        if params is not None and params is not self.params:
            raise ParameterError("the rig's parameters cannot change while it runs; restart it with the new rig YAML")
        return self.params

    def install(self, prepared: RigParams) -> str:
        """`reset(keep_time=True)`: valves at rest at their initial duty, the piston at its initial
        position, faults cleared, the watchdogs waiting; model time goes on."""
        failure = self.fault
        self.reset(keep_time=True)
        what = (f"the rig is at rest at t = {self.time:.4f} s (valves at their initial duty, piston at its "
                "initial position, faults cleared; model time goes on)")
        return f"{what} (cleared fault: {failure})" if failure else what

    # --- stepping ------------------------------------------------------------------------------

    def advance_to(self, step: int) -> None:
        """Integrate to `step`, running scheduled inputs and the watchdog at their steps; inputs
        due at `step` itself are applied (they act from there on). RigError if the state runs away."""
        sim = self.sim
        while True:
            self._due()
            if sim.steps >= step:
                break
            try:
                sim.advance(min(step, self._next_due()) - sim.steps)
            except MODEL_FAILURES as err:
                self._fail(f"model step failed ({type(err).__name__}: {err})")
            self._check_finite()

    def advance_sample(self, step: int, after: int = 0, out: np.ndarray | None = None) -> np.ndarray:
        """`advance_to(step)`, `sample()`, then `after` more steps with the same inputs: the same
        numbers as those calls, in one compiled call when no input falls due before the last step
        (the lockstep's hot path: a call costs about as much as five steps). Returns the sample at
        `step` (in `out` when given: a float64 array of the signals' length); the rig is then at
        `step + after`, or at `step` if an input fell due on the way (the caller checks `steps`)."""
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
                return out
        self.advance_to(step)
        if out is None:
            return self.sample()
        out[:] = self.sample()
        return out

    def _next_due(self) -> int:
        """The first step after the present one at which a scheduled input, a watchdog deadline or
        a fed input falls (a large number if none): where a batch of compiled steps must stop."""
        return max(self._due_step(), self.sim.steps + 1)

    def _due_step(self, *, feed: bool = True) -> int:
        """The first step at which a scheduled input, a watchdog deadline or (with `feed`) a fed
        input falls, pending now or later (NEVER if none)."""
        nxt = self.next_due()                       # the queue and the watchdogs (Device)
        if feed and self._feed_next < len(self._feed_steps):
            nxt = min(nxt, self._feed_steps[self._feed_next])
        return nxt

    def _check_finite(self) -> None:
        x = self.sim.x
        if not math.isfinite(float(np.dot(x, x))):       # any inf or NaN makes the sum so (cheaper than isfinite().all())
            self._fail("the model state ran away (non-finite)")

    def _fail(self, problem: str) -> NoReturn:
        """The fault state (`fault`, until a reset) and RigError, naming the time and the active faults."""
        reason = (f"{problem} before t = {self.sim.time:.6g} s; "
                  f"active faults: {', '.join(f'{k}@{t}' for t, k in self.faults) or 'none'}")
        self.set_fault(reason)
        raise RigError(reason)

    def _due(self) -> None:
        """What falls due at the present step, in the devices' order: queued inputs and actions,
        fed inputs, then the watchdogs."""
        self._apply_due_inputs()
        steps = self.sim.steps
        while self._feed_next < len(self._feed_steps) and self._feed_steps[self._feed_next] <= steps:
            self._feed_row(self._feed_next, steps)
        self._check_watchdogs()
