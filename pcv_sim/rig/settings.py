"""The rig node's parameters, without ROS: the rig's settings schema, beside the rig (its bag
layout and recorder are every device's, `pcv_sim.device.recording`, and so are its diagnostics,
`pcv_sim.device.diagnostics`).

Node settings follow the emulator's mechanism (`pcv_sim.params.setting`: default, unit,
description, check and read-only declared once; `SCHEMA`, a `SettingsSchema` as the emulator's,
derives the parameters and checks and changes the settings).
The physics (valves, cylinder, timing step, watchdog) comes from the rig YAML named by
`rig_config`, validated by `pcv_sim.rig.params`.
Fault commands (the `faults` topic) are the device's: `pcv_sim.device.faults.parse_fault_command`.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from pcv_sim.device.settings import (
    CommonSettings,
    SettingsSchema,
    any_value,
    non_negative,
    one_of,
)
from pcv_sim.errors import ParameterError
from pcv_sim.params import setting
from pcv_sim.rig.params import RigParams
from pcv_sim.simulation.clock import steps_per

__all__ = ["RIG_PARAMETERS", "SCHEMA", "RigNodeSettings", "check_rig_value"]


@dataclass(frozen=True)
class RigNodeSettings(CommonSettings):
    """The rig node's parameters (the physics is in the rig YAML; the loops' as every node's)."""

    rig_config: str = setting(
        "", "-", "rig YAML (valves, cylinder, timing); '' = the shipped config/rig.yaml", any_value, "str",
        read_only=True)
    time_mode: str = setting(
        "simulated", "-", "simulated: model time from 0, one /clock for the whole rig (controller CI); real: "
        "model time follows the wall clock (hardware in the loop)", one_of("real", "simulated"), "str",
        read_only=True)
    control_period: float = setting(
        0.0, "s", "samples out and commands in every control period (model time); 0 = the rig YAML's "
        "rig.control_period; a whole multiple of rig.time_step", non_negative, read_only=True)

    def check(self, rig: RigParams) -> RigNodeSettings:
        """Cross-checks against the rig (step multiples); returns self or raises ParameterError."""
        dt = rig.timing.time_step
        try:
            if self.control_period:
                steps_per(self.control_period, dt, what="control_period")
            steps_per(self.wake_period, dt, what="wake_period")
        except ValueError as err:
            raise ParameterError(f"{err} (rig.time_step of the rig YAML)") from None
        self.check_loop()
        return self

    def rig_params(self, rig: RigParams) -> RigParams:
        """`rig` with this node's control_period (when set)."""
        if not self.control_period:
            return rig
        return dataclasses.replace(rig, timing=dataclasses.replace(rig.timing, control_period=self.control_period))


SCHEMA = SettingsSchema(RigNodeSettings)
RIG_PARAMETERS = SCHEMA.parameters
check_rig_value = SCHEMA.check
