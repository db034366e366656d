"""The example steering position controller for the rig: a callable `controller(t, measurements)`.

One control law for both ways of running it: in-process by a scenario (examples/steering.py
re-exports it) and as the ROS 2 node `steering_controller` (`pcv_sim.node.steering_controller`).

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
"""

from __future__ import annotations


class PositionController:
    """PI + velocity feedback on the steering position (gains in duty per m, per m s, per m/s)."""

    def __init__(self, kp: float = 15.0, ki: float = 30.0, kv: float = 0.5, base: float = 0.6,
                 period: float = 1e-3, fault_time: float = 0.02, coil_volts: float = 12.0,
                 coil_ohm: float = 5.6, current_loop: float = 0.0) -> None:
        if not current_loop >= 0.0:
            raise ValueError(f"current_loop {current_loop!r}: accepted is a time constant in s >= 0 (0: off)")
        self.kp, self.ki, self.kv, self.base, self.period = kp, ki, kv, base, period
        self.fault_time, self.amps_per_duty = fault_time, coil_volts / coil_ohm
        self.current_loop = current_loop
        self.trim = {"left": 0.0, "right": 0.0}
        self.integral = 0.0
        self.last: dict[str, float] = {}
        self.low_since: dict[str, float | None] = {"left": None, "right": None}
        self.duty = {"left": base, "right": base}

    def __call__(self, t: float, m: dict[str, float]) -> dict[str, object]:
        last = self.last
        last.update(m)                   # a dropped sample keeps the last one seen
        error = last.get("setpoint", 0.0) - last["cylinder.position"]
        u_unsat = self.kp * error + self.ki * self.integral - self.kv * last["cylinder.velocity"]
        u = max(-0.35, min(0.35, u_unsat))
        if u == u_unsat:                 # anti-windup: integrate only while not saturated
            self.integral += error * self.period
        fault = False
        duty, low_since, amps = self.duty, self.low_since, self.amps_per_duty
        for valve, current in _CURRENTS:
            low = last[current] < 0.5 * amps * duty[valve]
            since = low_since[valve]
            start = (since if since is not None else t) if low else None
            low_since[valve] = start
            fault = fault or (start is not None and t - start >= self.fault_time)
        base = self.base
        self.duty = duty = {"left": min(1.0, max(0.3, base + u)), "right": min(1.0, max(0.3, base - u))}
        if not self.current_loop:
            return {**duty, "flags": {"fault_detected": float(fault)}}
        sent: dict[str, object] = {}
        for valve, current in _CURRENTS:          # the PI's duty as a current target, D V / R
            target = duty[valve]
            error = target - last[current] / amps
            self.trim[valve] = max(-0.2, min(0.2, self.trim[valve] + error * self.period / self.current_loop))
            sent[valve] = min(1.0, max(0.0, target + self.trim[valve]))
        return {**sent, "flags": {"fault_detected": float(fault)}}


#: Each valve with the name of its coil current's measurement.
_CURRENTS = (("left", "left.current"), ("right", "right.current"))


__all__ = ["PositionController"]
