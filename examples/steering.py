"""Controllers for the example scenarios: Python callables `controller(t, measurements)`.

`PositionController` is the package's example steering position controller
(`pcv_sim.control.steering`: PI + velocity damping split over the two valves, and a coil monitor
raising the flag `fault_detected`); the same class runs in the ROS 2 node
`ros2 run pcv_sim steering_controller` (`pcv_sim.node.steering_controller`), so a scenario run
with the node (`controller: {ros: ...}`) and with this callable use one control law.

Measurements (SI): `left.pressure` (Pa), `left.current` (A), `cylinder.position` (m),
`cylinder.velocity` (m/s), `setpoint` (m), ... A missing key is a dropped sample.
"""

from __future__ import annotations

from pcv_sim.control.steering import PositionController


def hold(t: float, m: dict[str, float]) -> dict[str, float]:
    """The simplest controller: both valves at 0.5."""
    return {"left": 0.5, "right": 0.5}


__all__ = ["PositionController", "hold"]
