"""The `rig` executable: N valves + the steering cylinder (`pcv_sim.rig`) as one ROS 2 node.

    ros2 run pcv_sim rig --ros-args -p rig_config:=config/rig.yaml
    python -m pcv_sim.node.rig --ros-args -p control_period:=0.01

This module owns the process (signals, exit status), as `pcv_sim.node.emulator` does for one
valve; the node is `pcv_sim.node.device_node.DeviceNode` over the rig (`pcv_sim.node.kinds.RIG`).
Only the standard library is imported at the top: SIGINT/SIGTERM handling is installed first, so
a signal at any moment is a clean stop (exit 0); invalid parameters exit 2 with a message naming
the parameter.
"""

from __future__ import annotations

import sys
from typing import Any

from pcv_sim.node.process import main_process, parameter_help, run_node

__all__ = ["main", "rig_node"]

DESCRIPTION = ("Steering rig: the valves of a rig YAML and the steering cylinder as one ROS 2 node. Topics per valve: "
               "in <valve>/duty_cycle; out <valve>/pressure, current, spool_position; cylinder/joint_states, "
               "cylinder/pressure_a|b; in faults, cylinder/external_force; service reset; /diagnostics, /clock (out "
               "in simulated time, in with use_sim_time); record.enabled records a bag.")


def _epilog() -> str:
    from pcv_sim.rig.settings import RIG_PARAMETERS

    return parameter_help(RIG_PARAMETERS, "FILE",
                          "the valves, the cylinder and the step are set in the rig YAML (rig_config); "
                          "rig.watchdog_timeout and rig.safe_duty default to its rig.watchdog_timeout and "
                          "rig.safe_duty and may change while the rig runs")


def _rig_yaml_as_params_file(argv: list[str]) -> str | None:
    """The rig YAML (config/rig.yaml) given as `--params-file`: rcl cannot read it (it is not a
    ROS parameter file) and would fail with a parse error; say what to write instead."""
    import yaml

    from pcv_sim.device.parameters import params_files

    for name in params_files(argv):
        try:
            with open(name, encoding="utf-8") as f:
                data = yaml.safe_load(f)
        except (OSError, yaml.YAMLError):
            continue                               # rcl reports it
        if isinstance(data, dict) and "valves" in data and "cylinder" in data:
            return (f"--params-file {name}: a rig YAML (valves, cylinder), not a ROS parameter file; accepted is "
                    f"-p rig_config:={name}, or a parameter file `rig: {{ros__parameters: {{rig_config: {name}}}}}`")
    return None


def _node(argv: list[str]) -> Any:
    return rig_node(argv=argv)


def rig_node(**kwargs: Any) -> Any:
    """The rig node in this process (`argv`, `context`, `namespace`, `parameter_overrides`... as for an
    rclpy Node); the caller runs and destroys it."""
    from pcv_sim.node.device_node import DeviceNode
    from pcv_sim.node.kinds import RIG

    return DeviceNode(RIG, **kwargs)


def main(args: list[str] | None = None) -> int:
    """Console entry point `rig`. Returns 0 after SIGINT/SIGTERM, 2 for invalid parameters."""
    return main_process(lambda argv, stop: run_node("rig", argv, stop, description=DESCRIPTION, epilog=_epilog,
                                                    make_node=_node, check=_rig_yaml_as_params_file), args)


if __name__ == "__main__":
    sys.exit(main())
