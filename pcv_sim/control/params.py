"""The example steering controller's gains and settings, declared once (`pcv_sim.params.parameter`:
unit, plausible range, default, one line of doc): `PositionController`'s keywords, a scenario's
`controller_params` for it, and the `steering_controller` node's ROS parameters all come from
these declarations and are checked by them (`check_value`), with their messages.

The ranges are wide around the defaults (tuned on the shipped rig, config/rig.yaml) and refuse
what is no gain of this law: a negative gain turns the loop's sign (a setpoint step runs the
piston to its stop), a base duty outside 0.3 .. 1 is where the valve does not regulate (the law
clamps its duties to that band), the coil's supply and resistance are the valve YAML's ranges
(`solenoid.supply_voltage`, `solenoid.coil_resistance`) and the period the rig's
(`timing.control_period`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from pcv_sim.errors import ParameterError
from pcv_sim.keys import unknown_message
from pcv_sim.params import between, declarations, parameter, plausible_range, read

__all__ = ["PositionControllerParams", "controller_params"]


@dataclass(frozen=True)
class PositionControllerParams:
    """PI + velocity feedback on the steering position, split over two valves around `base`, and
    the coil monitor (pcv_sim.control.steering). `read_only`: fixed while the node runs."""

    kp: float = parameter("duty/m", "proportional gain on the position error", between(0.0, 1e4, "a gain"),
                          default=15.0)
    ki: float = parameter("duty/(m s)", "integral gain on the position error", between(0.0, 1e5, "a gain"),
                          default=30.0)
    kv: float = parameter("duty/(m/s)", "damping gain on the piston velocity", between(0.0, 1e3, "a gain"),
                          default=0.5)
    base: float = parameter("-", "duty of both valves at zero output (left base + u, right base - u)",
                            between(0.3, 1.0, "a duty where the valve regulates"), default=0.6)
    period: float = parameter("s", "control period: the rig's timing.control_period (the integral's time step)",
                              plausible_range(1e-4, 1.0), default=1e-3, read_only=True)
    fault_time: float = parameter("s", "how long a coil current below half of what its duty drives at rest "
                                  "raises fault_detected", between(0.0, 10.0, "a duration", above=True),
                                  default=0.02)
    coil_volts: float = parameter("V", "coil supply voltage: a duty D drives D V / R at rest",
                                  plausible_range(1.0, 60.0), default=12.0)
    coil_ohm: float = parameter("ohm", "nominal coil resistance R", plausible_range(0.5, 200.0), default=5.6)
    current_loop: float = parameter("s", "time constant of the trim on each coil's measured current; 0: off",
                                    between(0.0, 10.0, "a time constant"), default=0.0)


def controller_params(values: Mapping[str, Any], where: str = "PositionController") -> PositionControllerParams:
    """The declared gains and settings from `values` (by name; the defaults for those absent), each
    checked by its declaration; ParameterError naming the key (an unknown one with the key it was
    likely meant as, `where` naming what it was given to)."""
    unknown = unknown_message(where, values, declarations(PositionControllerParams))
    if unknown:
        raise ParameterError(unknown)
    return PositionControllerParams(**{f.name: read(PositionControllerParams, values, f.name)
                                       for f in dataclasses.fields(PositionControllerParams)})
