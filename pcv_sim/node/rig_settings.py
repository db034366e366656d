"""The rig node's parameters and its fault commands, without ROS.

Node settings follow the emulator's mechanism (`pcv_sim.params.setting`: default, unit,
description, check and read-only declared once; `RIG_PARAMETERS` is derived from the fields).
The physics (valves, cylinder, timing step, watchdog) comes from the rig YAML named by
`rig_config`, validated by `pcv_sim.rig.params`.

A fault command (the `faults` topic, std_msgs/String) is a one-line YAML mapping:

    {fault: coil_open, valve: left}                              # a physical fault on a valve
    {fault: supply_drop, valve: right, pressure: 8.0e+6}         # with its values (SI)
    {fault: bias, signal: left.pressure, value: 1.0e+5}          # a sensor fault on a signal
    {clear: coil_open, valve: left}

validated with the rig's own fault table (`pcv_sim.rig.faults.parse_fault`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import yaml

from pcv_sim.device.settings import (
    CommonSettings,
    any_value,
    bag_name_check,
    non_negative,
    one_of,
    parameters_of,
    real_time_factor,
)
from pcv_sim.errors import ParameterError
from pcv_sim.params import check_value, int_range, setting
from pcv_sim.rig.faults import Fault, FaultError, parse_fault
from pcv_sim.rig.params import RigParams
from pcv_sim.simulation.clock import steps_per

__all__ = ["RIG_PARAMETERS", "FaultCommand", "RigNodeSettings", "check_rig_value", "parse_fault_command",
           "rig_settings_with", "settings_from"]


_seed = int_range(0, 2**32 - 1, "an integer 0 .. 2^32 - 1")


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
    lockstep: bool = setting(
        True, "-", "simulated time: publish the samples of a control period, then wait for one duty_cycle "
        "command of every valve before computing the next period (deterministic bit for bit)", any_value, "bool",
        read_only=True)
    real_time_factor: float = setting(
        0.0, "-", "simulated time without lockstep: model seconds per wall second; 0 or inf = as fast as "
        "possible", convert=real_time_factor)
    control_period: float = setting(
        0.0, "s", "samples out and commands in every control period (model time); 0 = the rig YAML's "
        "rig.control_period; a whole multiple of rig.time_step", non_negative, read_only=True)
    seed: int = setting(0, "-", "seed of the sensor-noise faults (a run repeats bit for bit)", _seed, "int",
                        read_only=True)
    allow_unknown_parameters: bool = setting(
        False, "-", "false: a parameter name nobody declares (a typo) stops the node at start (exit 2); true: "
        "warn and ignore it", any_value, "bool", read_only=True)
    faults_enabled: bool = setting(
        False, "-", "take fault commands on the `faults` topic; off unless asked, since any node on the ROS "
        "domain could then break the bench; each command is logged with its publisher's node name", any_value,
        "bool", name="faults.enabled", read_only=True)
    record_enabled: bool = setting(
        False, "-", "record every valve (under its namespace, as the emulator records one), the cylinder, the "
        "fault commands and the rig's events to a rosbag2/MCAP bag from the start (the rig at rest) until "
        "SIGINT/SIGTERM; outputs at every published sample (control_period), inputs on change at the step they "
        "act", any_value, "bool", name="record.enabled", read_only=True)
    record_name: str = setting(
        "", "-", "bag directory name; '' = rig[_<namespace>]_YYYYmmdd-HHMMSS; an existing bag is never "
        "overwritten", bag_name_check, "str", name="record.name", read_only=True)

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


RIG_PARAMETERS = parameters_of(RigNodeSettings)
_BY_NAME = {p.name: p for p in RIG_PARAMETERS}


def check_rig_value(name: str, value: Any) -> Any:
    """Convert and check one rig node parameter; ParameterError naming it if refused."""
    spec = _BY_NAME.get(name)
    if spec is None:
        raise ParameterError(f"unknown parameter {name!r}; accepted are: {', '.join(_BY_NAME)}")
    return check_value(name, spec.meta, value)


def settings_from(values: Mapping[str, Any]) -> RigNodeSettings:
    return RigNodeSettings(**{_BY_NAME[k].attr: v for k, v in values.items()})


def rig_settings_with(settings: RigNodeSettings, changes: Mapping[str, Any]) -> RigNodeSettings:
    """A copy of settings with parameters changed, each checked (not yet cross-checked)."""
    return dataclasses.replace(settings, **{_BY_NAME[k].attr: check_rig_value(k, v) for k, v in changes.items()})


# --- fault commands ------------------------------------------------------------------------------


@dataclass(frozen=True)
class FaultCommand:
    """`fault` to inject, or (`target`, `kind`) to clear."""

    clear: bool
    kind: str
    target: str
    fault: Fault | None


_TARGET_KEYS = ("valve", "signal", "target")


def parse_fault_command(text: str, *, valves: tuple[str, ...], signals: tuple[str, ...]) -> FaultCommand:
    """A validated fault command from one line of YAML; FaultError saying what is accepted."""
    example = "accepted is a YAML mapping such as {fault: coil_open, valve: left} or {clear: coil_open, valve: left}"
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError:
        raise FaultError(f"fault command {text!r} is not YAML; {example}") from None
    if not isinstance(data, Mapping):
        raise FaultError(f"fault command {text!r}: {example}")
    actions = [k for k in ("fault", "clear") if k in data]
    if len(actions) != 1:
        raise FaultError(f"fault command {text!r}: needs exactly one of 'fault' or 'clear'; {example}")
    action = actions[0]
    targets = [k for k in _TARGET_KEYS if k in data]
    if len(targets) != 1:
        raise FaultError(f"fault command {text!r}: needs exactly one of 'valve' (a physical fault: "
                         f"{', '.join(valves)}) or 'signal' (a sensor fault: {', '.join(signals)})")
    kind, target = data[action], data[targets[0]]
    values = {k: v for k, v in data.items() if k not in (action, targets[0])}
    if action == "clear":
        if values:
            raise FaultError(f"fault command {text!r}: clear takes no values ({', '.join(map(str, values))})")
        # Validated as a fault with no values would be: the kind and target must exist.
        try:
            parse_fault(kind, target, None, valves=valves, signals=signals, where="clear")
        except FaultError as err:
            if "needs" not in str(err):            # a kind that takes values: those are not needed to clear it
                raise
        return FaultCommand(True, str(kind), str(target), None)
    fault = parse_fault(kind, target, values, valves=valves, signals=signals, where="fault")
    return FaultCommand(False, fault.kind, fault.target, fault)
