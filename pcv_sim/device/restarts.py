"""A device's restarts: a fresh start (`reset`: each valve at rest at its initial duty, the plant at
its start state) and a restart at a step boundary (`prepare` builds the model at rest, with new
parameters when given, after a trial run, off the stepping thread; `install` swaps it in). Rest
states are solved once per inputs (`pcv_sim.simulation.rest`). No ROS.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from pcv_sim.device.composition import Composition
from pcv_sim.device.limits import TRIAL_STEPS, PhysicalLimits
from pcv_sim.device.sensors import Sensors
from pcv_sim.device.spec import (
    MODEL_FAILURES,
    Prepared,
    ValveSpec,
)
from pcv_sim.errors import CommandError, ParameterError
from pcv_sim.io.topics import DUTY_CYCLE, LOAD_FLOW, SUPPLY_PRESSURE
from pcv_sim.model import kernel
from pcv_sim.params import ValveParams
from pcv_sim.simulation.duty import check_duty
from pcv_sim.simulation.rest import rest_state
from pcv_sim.simulation.simulator import Simulator
from pcv_sim.simulation.system import compose
from pcv_sim.simulation.valve import valve_integrator, valve_system
from pcv_sim.units import bar

__all__ = ["Restarts"]


class Restarts(Composition):
    """Reset, prepare and install of a device (see the module docstring)."""

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
            sim.u[i("input", f"{v.name}.{DUTY_CYCLE}")] = duties[k]
            sim.u[i("input", f"{v.name}.{SUPPLY_PRESSURE}")] = supply
            if f"{v.name}.{LOAD_FLOW}" in sim.plant.inputs:
                sim.u[i("input", f"{v.name}.{LOAD_FLOW}")] = flow
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
            # The inputs in force now (taken since `prepare` too) act on the new model from now on.
            inputs = self.input_values()
            supply, supply0, flow = list(self._supply), list(self._supply0), list(self._load_flow)
            steps = self.sim.steps
            new = prepared.sim
            if self.sim.runs_like(new):
                self.sim.arena[:] = new.arena      # the simulator's arrays stay (their compiled call is kept)
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
            self._healthy = [p.copy() for p in self._configured]
            self.faults = {}
            self.sensors.reset()
            if self.restart_at_start:
                self.reset(keep_time=True)
            else:
                self._put_inputs(inputs, [s if s != s0 else new0 for s, s0, new0 in zip(supply, supply0, self._supply0)],
                                 flow)
            what = prepared.what
            self._inputs_changed()
        self.clear_fault()
        return f"{what} (cleared fault: {was})" if was else what

    def _put_inputs(self, inputs: Mapping[str, float], supply: Sequence[float], flow: Sequence[float]) -> None:
        """After a restart at the present operating point: the duties in force (the limiters at rest
        there), supplies, load flows and the options' and plant's inputs of `inputs` (as
        `input_values` names them) into the model."""
        u = self.sim.u
        for k, name in enumerate(self.valve_names):
            try:
                check_duty(self.duties[name], self._ranges[name])
            except CommandError as err:      # e.g. duty_range narrowed: keep what prepare() checked
                self.counts.last_rejection = f"after a model restart: {err}"
            else:
                u[self._duty_i[k]] = self.duties[name]
            self._limiters[k].value = float(u[self._duty_i[k]])
            self._lim_step[k] = self.sim.steps
            self._supply[k] = supply[k]
            u[self._supply_i[k]] = supply[k]
            if self._flow_i[k] >= 0:
                self._load_flow[k] = flow[k]
                u[self._flow_i[k]] = flow[k]
        for name, i in self._plant_i.items():
            u[i] = inputs.get(name, 0.0)
        for (valve, name), full in zip(self._option_in, self.option_inputs):
            if full in inputs:
                try:    # the oil's: the spool's pole follows it (R34)
                    self.set_temperature(valve, name, inputs[full])
                except CommandError as err:     # too cold for the new step: the YAML's stays
                    self.counts.last_rejection = f"after a model restart: {err}"


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
