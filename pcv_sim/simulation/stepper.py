"""The real-time engine: the simplified model (Sec. 4.3) at a fixed step (0.1 ms by default).

The node calls `advance(n)` with however many steps wall time asks for; everything here is
deterministic for a given input sequence. Inputs are held constant over a step (zero-order
hold, like the rig's sampled controller); the duty passes the fall-rate limiter first.
"""

from __future__ import annotations

import math

import numpy as np

from pcv_sim.analysis.static import equilibrium_at_flow
from pcv_sim.errors import CommandError
from pcv_sim.model.valve import ValveModel
from pcv_sim.params import ValveParams
from pcv_sim.simulation.duty import DutyProfile, FallRateLimiter, check_duty
from pcv_sim.simulation.integrators import STEPPERS
from pcv_sim.simulation.trajectory import Trajectory

__all__ = ["RealTimeStepper", "check_load_flow", "check_supply_pressure"]

# Beyond these the input is not a plant any rig could produce: refuse rather than integrate it.
MAX_LOAD_FLOW = 100.0 / 60000.0        # m^3/s, 100 L/min (the valve passes ~50 L/min fully open)
MAX_SUPPLY_PRESSURE = 400.0e5          # Pa
MIN_SUPPLY_PRESSURE = 1.0e5            # Pa: below 1 bar a value is far more likely bar than Pa


def check_load_flow(value: float) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise CommandError(f"load flow {value!r}: accepted is a finite number in m^3/s")
    if abs(value) > MAX_LOAD_FLOW:
        # Name L/min only when the number read as L/min is a flow this valve can see.
        looks_lpm = abs(value) / 60000.0 <= MAX_LOAD_FLOW
        hint = f"; the unit is m^3/s, not L/min: {value:g} L/min is {value / 60000.0:.4g} m^3/s" if looks_lpm else ""
        raise CommandError(
            f"load flow {value:g} m^3/s is beyond +-{MAX_LOAD_FLOW:.4g} m^3/s (100 L/min){hint}"
        )
    return float(value)


def check_supply_pressure(value: float) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise CommandError(f"supply pressure {value!r}: accepted is a finite number in Pa")
    if not MIN_SUPPLY_PRESSURE <= value <= MAX_SUPPLY_PRESSURE:
        # Name bar only when the number read as bar is in range (200 -> 200 bar), not for 5e8.
        looks_bar = MIN_SUPPLY_PRESSURE <= value * 1e5 <= MAX_SUPPLY_PRESSURE
        hint = f" (the unit is Pa, not bar: {value:g} bar is {value * 1e5:.4g} Pa)" if looks_bar else ""
        raise CommandError(
            f"supply pressure {value:g} Pa: accepted is {MIN_SUPPLY_PRESSURE:.4g} .. {MAX_SUPPLY_PRESSURE:.4g} Pa "
            f"({MIN_SUPPLY_PRESSURE / 1e5:g} .. {MAX_SUPPLY_PRESSURE / 1e5:g} bar){hint}"
        )
    return float(value)


class RealTimeStepper:
    """Fixed-step simulation of the simplified model, one valve."""

    def __init__(self, params: ValveParams, *, integrator: str | None = None, duty: float = 0.0) -> None:
        self.params = params
        self.model = ValveModel(params, "simplified")
        self.dt = params.simulation.time_step
        name = integrator or params.simulation.integrator
        if name not in STEPPERS:
            raise ValueError(f"integrator {name!r}: accepted are {', '.join(STEPPERS)}")
        self.integrator = name
        self._method = STEPPERS[name]
        self.reset(duty)

    # --- state -------------------------------------------------------------------------------

    def reset(self, duty: float = 0.0, load_flow: float = 0.0, supply_pressure: float | None = None) -> None:
        """Back to rest: the equilibrium for `duty` at `load_flow`, model time 0."""
        self.command = check_duty(duty, self.params.command.duty_range)
        self.load_flow = check_load_flow(load_flow)
        self.supply_pressure = check_supply_pressure(self.model.p_supply if supply_pressure is None else supply_pressure)
        eq = equilibrium_at_flow(self.model, self.command, self.load_flow, self.supply_pressure)
        self.state: tuple[float, ...] = self.model.initial_state(self.command, eq.spool_position, eq.pressure)
        self.limiter = FallRateLimiter(self.params.command.duty_fall_rate_limit, self.command)
        self.duty = self.command
        self.steps = 0
        self._i = eq.current

    @property
    def time(self) -> float:
        """Model time (s): an integer count of steps, so it never drifts."""
        return self.steps * self.dt

    @property
    def pressure(self) -> float:
        return self.state[3]

    @property
    def spool_position(self) -> float:
        return self.state[1]

    @property
    def current(self) -> float:
        """Coil current at the present state (A), Eqs. 1-8. Reading it changes nothing: the
        stepper's own Newton guess stays as stepping left it, so results do not depend on how
        often the current is read."""
        m = self.model
        return m.current(self.state[0], self.state[1], m.coil_voltage(self.duty, self.time), self._i)

    def finite(self) -> bool:
        return all(math.isfinite(s) for s in self.state)

    # --- inputs ------------------------------------------------------------------------------

    def set_duty(self, duty: float) -> None:
        """Raises CommandError (the last valid command stays) unless duty is within command.duty_range."""
        self.command = check_duty(duty, self.params.command.duty_range)

    def set_load_flow(self, q: float) -> None:
        self.load_flow = check_load_flow(q)

    def set_supply_pressure(self, p: float) -> None:
        self.supply_pressure = check_supply_pressure(p)

    # --- stepping ----------------------------------------------------------------------------

    def advance(self, n: int = 1) -> None:
        """n fixed steps with the present inputs.

        A state that runs away shows as `finite()` turning False, or as ArithmeticError (no coil
        current solves Eq. 2, or a float overflow) raised from here: callers treat both as a fault.
        """
        if self.integrator == "rk2":
            self._advance_heun(n)
            return
        m, h, method = self.model, self.dt, self._method
        q_l, p_s, deriv = self.load_flow, self.supply_pressure, m.derivatives
        state, steps, i_last = self.state, self.steps, self._i
        duty = self.limiter.value

        def f(t: float, y: tuple[float, ...]) -> tuple[float, ...]:
            nonlocal i_last
            dy, i_last = deriv(t, y, duty, q_l, p_s, i_last)
            return dy

        for _ in range(n):
            duty = self.limiter.update(self.command, h)
            state = self._project(method(f, steps * h, state, h))
            steps += 1
        self.state, self.steps, self._i, self.duty = state, steps, i_last, duty

    def _advance_heun(self, n: int) -> None:
        """`advance` with Heun's method (integrators.heun_step) unrolled for the 4 states: the
        default real-time path, where the tuple arithmetic is a fifth of the cost. A test checks
        it against the generic heun_step."""
        m, h, hh = self.model, self.dt, 0.5 * self.dt
        q_l, p_s, deriv = self.load_flow, self.supply_pressure, m.derivatives
        y0, y1, y2, y3 = self.state
        steps, i, command = self.steps, self._i, self.command
        update = self.limiter.update if self.limiter.rate is not None else None
        duty = self.limiter.value if update is not None else command
        x_min, x_max = m.x_min, m.x_max
        for _ in range(n):
            if update is not None:
                duty = update(command, h)
            t = steps * h
            (a0, a1, a2, a3), i = deriv(t, (y0, y1, y2, y3), duty, q_l, p_s, i)
            (b0, b1, b2, b3), i = deriv(t + h, (y0 + h * a0, y1 + h * a1, y2 + h * a2, y3 + h * a3), duty, q_l, p_s, i)
            y0, y1, y2, y3 = y0 + hh * (a0 + b0), y1 + hh * (a1 + b1), y2 + hh * (a2 + b2), y3 + hh * (a3 + b3)
            if not x_min <= y1 <= x_max:
                y1, y2 = m.project(y1, y2)
            steps += 1
        self.limiter.value = duty
        self.state, self.steps, self._i, self.duty = (y0, y1, y2, y3), steps, i, duty

    def _project(self, state: tuple[float, ...]) -> tuple[float, ...]:
        x, v = state[1], state[2]
        if self.model.x_min <= x <= self.model.x_max:
            return state
        x, v = self.model.project(x, v)
        return (state[0], x, v) + state[3:]

    def run(self, profile: DutyProfile, t_end: float, *, sample_every: int = 1) -> Trajectory:
        """Drive the stepper with a duty profile from its present state; returns the samples."""
        n = int(round(t_end / self.dt))
        times = np.array(profile.times)
        ts, duty, cur, pres, pos = [self.time], [self.duty], [self.current], [self.pressure], [self.spool_position]
        t0 = self.time
        for k in range(0, n, sample_every):
            t_rel = k * self.dt
            # Change the command exactly at the profile's switching instants.
            self.set_duty(profile.values[int(np.searchsorted(times, t_rel + 1e-12, side="right")) - 1])
            self.advance(min(sample_every, n - k))
            ts.append(self.time)
            duty.append(self.duty)
            cur.append(self.current)
            pres.append(self.pressure)
            pos.append(self.spool_position)
        return Trajectory(np.array(ts) - t0, np.array(duty), np.array(cur), np.array(pres), np.array(pos))
