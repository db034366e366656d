"""The example steering position controller for the rig: a callable `controller(t, measurements)`.

One control law for both ways of running it: in-process by a scenario (examples/steering.py
re-exports it) and as the ROS 2 node `steering_controller` (`pcv_sim.node.steering_controller`).
Its gains and settings (units, ranges, defaults) are declared once in `pcv_sim.control.params`.

PI on the piston position error with velocity damping, split over the two valves around a
common base duty: the valve on chamber a (left) gets base + u, the one on chamber b (right)
base - u, so a positive u pushes the piston toward +x. Duties are clamped to 0.3 .. 1.0, where
the valve regulates (below ~0.3 the spool sits on its stop). A coil monitor flags a coil
current below half of what the commanded duty drives at rest (V D / R: a coil open, a broken
driver) for `fault_time` s: the flag `fault_detected` goes to the rig's record. (The current,
not the pressure: while the piston moves the pressures leave their set points by design.)

A duty is a voltage (the coil sees V D), so with duties alone each valve's coil current, and so
its pressure, scales with 1/R of its own coil: a few per cent between the two coils (their
tolerance, or one coil warmer than the other) is a static force on the piston that only the
slow integral works away. `current_loop` (s, 0: off) closes a loop on each coil's measured
current instead, as a valve amplifier does: the PI's duty is read as a current target D V / R
(R the nominal `coil_ohm`) and a trim per valve, integrated with that time constant from the
current error (within +-0.2), is added to the duty sent. (examples/campaigns/tolerances.yaml:
with it the settling no longer depends on the coils.)

Measurements (SI): `left.pressure` (Pa), `cylinder.position` (m), `cylinder.velocity` (m/s),
`setpoint` (m), ... A missing key is a dropped sample: the controller holds its last value.

The rig's lockstep calls it in the array form as well (`lockstep_arrays`: the samples as a list,
the duties and the flag into one, no dict built or parsed each period). Both forms run one
control law (`_law`) on one state, so they give the same numbers to the last bit and may
alternate within a run (the dict form while a sensor fault is active).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

from pcv_sim.control.params import PositionControllerParams, controller_params

#: What the law reads, each with the attribute holding its last value (a dropped sample keeps it).
_HELD = (("setpoint", "setpoint"), ("cylinder.position", "position"), ("cylinder.velocity", "velocity"),
         ("left.current", "left_current"), ("right.current", "right_current"))
_UNSEEN: Any = None             # a measurement not sampled yet: the law cannot run (KeyError names it)


class PositionController:
    """PI + velocity feedback on the steering position (gains in duty per m, per m s, per m/s).

    `PositionController(params)` or by keyword, `PositionController(kp=15.0, current_loop=0.02)`:
    the gains and settings of `pcv_sim.control.params.PositionControllerParams` (their units,
    ranges and defaults), checked by their declarations (ParameterError naming the key)."""

    def __init__(self, params: PositionControllerParams | None = None, /, **values: Any) -> None:
        if params is not None and values:
            raise TypeError("PositionController: give its params or keywords, not both")
        self.retune(params if params is not None else controller_params(values))
        self.trim = {"left": 0.0, "right": 0.0}
        self.integral = 0.0
        # The last value seen of each measurement (None: none yet; a setpoint defaults to 0).
        self.setpoint = 0.0
        self.position: float = _UNSEEN
        self.velocity: float = _UNSEEN
        self.left_current: float = _UNSEEN
        self.right_current: float = _UNSEEN
        self.low_since: dict[str, float | None] = {"left": None, "right": None}
        self.left_duty = self.right_duty = self.base   # the PI's duties of the last period
        self.fault = 0.0

    @staticmethod
    def check_params(values: Mapping[str, Any]) -> PositionControllerParams:
        """Keyword values (a scenario's `controller_params`, which its loader checks with this) as the
        constructor takes them; ParameterError naming the key."""
        return controller_params(values)

    def retune(self, params: PositionControllerParams) -> None:
        """The gains and settings in force from the next period on; the state (integral, trims,
        held measurements, the coil monitor's timers) carries over."""
        self.params = params
        self.kp, self.ki, self.kv, self.base, self.period = params.kp, params.ki, params.kv, params.base, params.period
        self.fault_time, self.amps_per_duty = params.fault_time, params.coil_volts / params.coil_ohm
        self._half_amps = 0.5 * self.amps_per_duty     # the coil monitor's threshold per unit duty
        self.current_loop = params.current_loop

    @property
    def duty(self) -> dict[str, float]:
        """The PI's duty per valve, as last computed (before the current loop's trim)."""
        return {"left": self.left_duty, "right": self.right_duty}

    def __call__(self, t: float, m: Mapping[str, float]) -> dict[str, object]:
        for key, attr in _HELD:
            v = m.get(key)
            if v is not None:
                setattr(self, attr, v)
        try:
            left, right = self._law(t)
        except TypeError:
            missing = [key for key, attr in _HELD if getattr(self, attr) is None]
            if missing:                  # never sampled yet: nothing to hold
                raise KeyError(missing[0]) from None
            raise
        return {"left": left, "right": right, "flags": {"fault_detected": self.fault}}

    def lockstep_arrays(self, signals: tuple[str, ...], valves: tuple[str, ...]
                        ) -> tuple[Callable[[float, list[float], list[float]], None], tuple[str, ...],
                                   tuple[str, ...]] | None:
        """The array form for a lockstep over `signals` (the last one `setpoint`, NaN when the run has
        none) and `valves`: (step, the valves it commands, its flags); `step(t, samples, out)` writes
        the left and right duties and `fault_detected` into out. None when a signal it reads is not
        there (the dict form then says which)."""
        if "left" not in valves or "right" not in valves or any(key not in signals for key, _ in _HELD):
            return None
        isp, ipos, ivel, il, ir = (signals.index(key) for key, _ in _HELD)
        law = self._law

        def step(t: float, y: list[float], out: list[float]) -> None:
            sp = y[isp]
            if sp == sp:  # noqa: PLR0124 - NaN: the run has no setpoint (absent from the dict form)
                self.setpoint = sp
            self.position, self.velocity, self.left_current, self.right_current = y[ipos], y[ivel], y[il], y[ir]
            out[0], out[1] = law(t)
            out[2] = self.fault

        return step, ("left", "right"), ("fault_detected",)

    def _law(self, t: float) -> tuple[float, float]:
        """One period on the held measurements: the duties to send (left, right); the flag in `fault`."""
        error = self.setpoint - self.position
        u_unsat = self.kp * error + self.ki * self.integral - self.kv * self.velocity
        # max(-0.35, min(0.35, u_unsat)), as comparisons (the builtins cost more than the rest)
        u = u_unsat if u_unsat < 0.35 else 0.35
        if not u > -0.35:
            u = -0.35
        if u == u_unsat:                 # anti-windup: integrate only while not saturated
            self.integral += error * self.period
        # The coil monitor: a current below half of what the last duty drives at rest.
        half, low_since, fault_time = self._half_amps, self.low_since, self.fault_time
        fault = False
        since = low_since["left"]
        if self.left_current < half * self.left_duty:
            start = since if since is not None else t
            low_since["left"] = start
            fault = t - start >= fault_time
        elif since is not None:
            low_since["left"] = None
        since = low_since["right"]
        if self.right_current < half * self.right_duty:
            start = since if since is not None else t
            low_since["right"] = start
            fault = fault or t - start >= fault_time
        elif since is not None:
            low_since["right"] = None
        self.fault = 1.0 if fault else 0.0
        # min(1.0, max(0.3, base +- u))
        base = self.base
        left = base + u
        if not left > 0.3:
            left = 0.3
        elif not left < 1.0:
            left = 1.0
        right = base - u
        if not right > 0.3:
            right = 0.3
        elif not right < 1.0:
            right = 1.0
        self.left_duty, self.right_duty = left, right
        if not self.current_loop:
            return left, right
        trim, amps, period, tau = self.trim, self.amps_per_duty, self.period, self.current_loop
        # the PI's duty as a current target, D V / R, trimmed by the integral of the current error
        error = left - self.left_current / amps
        trim["left"] = max(-0.2, min(0.2, trim["left"] + error * period / tau))
        error = right - self.right_current / amps
        trim["right"] = max(-0.2, min(0.2, trim["right"] + error * period / tau))
        return min(1.0, max(0.0, left + trim["left"])), min(1.0, max(0.0, right + trim["right"]))


__all__ = ["PositionController"]
