"""The real-time engine: one valve (simplified or full model) at a fixed step (0.1 ms by default).

The node calls `advance(n)` with however many steps wall time asks for; the steps run in the
compiled core (`pcv_sim.simulation.simulator`); everything here is deterministic for a given
input sequence. Inputs are held constant over a step (zero-order hold, like the rig's sampled
controller); the duty passes the fall-rate limiter first.
"""

from __future__ import annotations

import numpy as np

from pcv_sim.errors import CommandError
from pcv_sim.model import kernel
from pcv_sim.model.kernel import INPUTS
from pcv_sim.model.valve import ValveModel
from pcv_sim.params import ValveParams
from pcv_sim.simulation.compile import INTEGRATORS
from pcv_sim.simulation.duty import DutyProfile, FallRateLimiter, check_duty
from pcv_sim.simulation.rest import rest_state
from pcv_sim.simulation.simulator import Simulator
from pcv_sim.simulation.trajectory import Trajectory
from pcv_sim.simulation.valve import (
    KINDS,
    check_load_flow,
    check_oil_step,
    check_supply_pressure,
    check_temperature,
    valve_inputs,
    valve_integrator,
    valve_system,
)
from pcv_sim.units import kelvin

__all__ = ["RealTimeStepper"]

#: Where the valve's inputs sit in `Simulator.u` (the model's input order).
DUTY, LOAD_FLOW, SUPPLY_PRESSURE, LOAD_VOLUME = (
    INPUTS.index(name) for name in ("duty_cycle", "load_flow", "supply_pressure", "load_volume"))


class RealTimeStepper:
    """One valve at the fixed step on the compiled core: the emulator's and replay's engine.

    `kind` (default: the config's `simulation.model`) is the simplified or the full model; the
    integrator defaults to the config's (`auto`: Heun for simplified, exponential Heun for full).
    Inputs are held over a step; the duty passes the fall-rate limiter first.
    """

    def __init__(self, params: ValveParams, *, integrator: str | None = None, duty: float = 0.0,
                 kind: str | None = None, load_flow: float = 0.0, supply_pressure: float | None = None) -> None:
        self.params = params
        self.kind = kind or params.simulation.model
        if self.kind not in KINDS:
            raise ValueError(f"model kind {self.kind!r}: accepted are {', '.join(KINDS)}")
        self.model = ValveModel(params, self.kind)  # type: ignore[arg-type]
        self.dt = params.simulation.time_step
        name = integrator or valve_integrator(params, self.kind)
        if name not in INTEGRATORS:
            raise ValueError(f"integrator {name!r}: accepted are {', '.join(INTEGRATORS)}")
        self.integrator = name
        self.sim = Simulator(valve_system(params, self.kind), self.dt, name)
        if params.fluid.oil_temperature_model:
            self._check_oil(kelvin(params.fluid.oil_temperature_c))
        self.reset(duty, load_flow, supply_pressure)

    # --- state -------------------------------------------------------------------------------

    def reset(self, duty: float = 0.0, load_flow: float = 0.0, supply_pressure: float | None = None) -> None:
        """Back to rest (`pcv_sim.simulation.rest.rest_state`) for these inputs, model time 0."""
        self.command = check_duty(duty, self.params.command.duty_range)
        self.load_flow = check_load_flow(load_flow)
        self.supply_pressure = check_supply_pressure(self.model.p_supply if supply_pressure is None else supply_pressure)
        rest = rest_state(self.params, self.kind, self.command, self.load_flow, self.supply_pressure,
                          integrator=self.integrator)
        sim = self.sim
        sim.x[:] = rest.state
        sim.W[0] = rest.current
        sim.steps = 0
        # limiter.value: the duty of the last computed step; self.duty: the duty in force from
        # the present step on (what a sample at the present time shows: right-continuous).
        self.limiter = FallRateLimiter(self.params.command.duty_fall_rate_limit, self.command)
        self.duty = self.command
        self._inputs()

    def _inputs(self) -> None:
        # A single valve: the configured load volume (and temperatures, with the options on).
        self.sim.u[:] = valve_inputs(self.params, self.duty, self.load_flow, self.supply_pressure)

    @property
    def steps(self) -> int:
        return self.sim.steps

    @property
    def state(self) -> tuple[float, ...]:
        return tuple(float(v) for v in self.sim.x)

    @property
    def _i(self) -> float:
        """The last coil current of the model's solve (the Newton start of the next)."""
        return float(self.sim.W[0])

    @property
    def time(self) -> float:
        """Model time (s): an integer count of steps, so it never drifts."""
        return self.sim.time

    @property
    def pressure(self) -> float:
        return float(self.sim.x[3])

    @property
    def spool_position(self) -> float:
        return float(self.sim.x[1])

    @property
    def current(self) -> float:
        """Coil current at the present state (A), Eqs. 1-8, with the duty in force from now on.
        Reading it changes nothing (the model's Newton start stays as stepping left it)."""
        return float(self.sim.outputs()[1])

    def finite(self) -> bool:
        return self.sim.finite()

    # --- inputs ------------------------------------------------------------------------------

    def set_duty(self, duty: float) -> None:
        """The command from the present step on. Raises CommandError (the last valid command stays)
        unless duty is within command.duty_range. The effective duty (after the fall-rate limiter)
        changes at once, so outputs at the present time already see the new coil voltage."""
        self.command = check_duty(duty, self.params.command.duty_range)
        self.duty = self.limiter.peek(self.command, self.dt)
        self.sim.u[DUTY] = self.duty

    def set_load_flow(self, q: float) -> None:
        self.load_flow = check_load_flow(q)
        self.sim.u[LOAD_FLOW] = self.load_flow

    def set_supply_pressure(self, p: float) -> None:
        self.supply_pressure = check_supply_pressure(p)
        self.sim.u[SUPPLY_PRESSURE] = self.supply_pressure

    def set_input(self, name: str, value: float) -> None:
        """An option's input by its name (`ambient_temperature`, `oil_temperature`, K) from the
        present step on; CommandError for an input this valve's layout does not have."""
        inputs = self.sim.plant.inputs
        if f"valve.{name}" not in inputs or name in ("duty_cycle", "load_flow", "supply_pressure", "load_volume"):
            extra = [i.partition(".")[2] for i in inputs[4:]]
            raise CommandError(f"input {name!r}: accepted are {', '.join(extra) or 'none'} (the valve YAML's "
                               "options bring them: solenoid.coil_temperature: lumped, fluid.temperature: input)")
        value = check_temperature(name.replace("_", " "), value)
        if name == "oil_temperature":
            self._check_oil(value)
            if self.sim.plant.rate_parameters:
                self.sim.P[kernel.V_RATE] = kernel.spool_rate(value, self.sim.P[: kernel.N_PARAMS])
                self.sim.refresh_rates()
        self.sim.u[inputs.index(f"valve.{name}")] = value

    def _check_oil(self, temperature: float) -> None:
        check_oil_step(self.params, self.sim.P[: kernel.N_PARAMS], self.dt,
                       self.integrator == "erk2" and bool(self.sim.plant.rate_parameters), temperature)

    def output(self, name: str) -> float:
        """An output by its name at the present state (e.g. coil_temperature, core_position)."""
        return float(self.sim.outputs()[self.sim.plant.index("output", f"valve.{name}")])

    # --- stepping ----------------------------------------------------------------------------

    def advance(self, n: int = 1) -> None:
        """n fixed steps with the present inputs (compiled; one step at a time only while the
        fall-rate limiter is ramping the duty).

        A state that runs away shows as `finite()` turning False, or as ArithmeticError (no coil
        current solves Eq. 2) raised from here: callers treat both as a fault.
        """
        limiter, sim = self.limiter, self.sim
        while n > 0:
            if limiter.rate is None or self.duty == self.command:
                sim.advance(n)
                limiter.value = self.duty
                return
            sim.advance(1)
            n -= 1
            limiter.value = self.duty
            self.duty = limiter.peek(self.command, self.dt)
            sim.u[DUTY] = self.duty

    def run(self, profile: DutyProfile, t_end: float, *, sample_every: int = 1) -> Trajectory:
        """Drive the stepper with a duty profile from its present state; returns the samples.

        Each command takes effect at the first step at or after its switching instant; a sample
        at time t shows the state at t and the inputs in force from t on (right-continuous).
        """
        n = round(t_end / self.dt)
        times = np.array(profile.times)
        t0 = self.time
        switch = np.ceil(times / self.dt - 1e-9).astype(int)       # step at which each value takes effect
        ts, duty, cur, pres, pos = [], [], [], [], []
        k_next, k = 0, 0
        while True:
            while k_next < len(switch) and switch[k_next] <= k:
                self.set_duty(profile.values[k_next])
                k_next += 1
            if k % sample_every == 0 or k == n:
                ts.append(self.time)
                duty.append(self.duty)
                cur.append(self.current)
                pres.append(self.pressure)
                pos.append(self.spool_position)
            if k >= n:
                break
            nxt = min(n, k + sample_every - k % sample_every)
            if k_next < len(switch):
                nxt = min(nxt, int(switch[k_next]))
            self.advance(nxt - k)
            k = nxt
        return Trajectory(np.array(ts) - t0, np.array(duty), np.array(cur), np.array(pres), np.array(pos))
