"""The `rig` executable: N valves + the steering cylinder (`pcv_sim.rig`) as one ROS 2 node.

    ros2 run pcv_sim rig --ros-args -p rig_config:=config/rig.yaml
    python -m pcv_sim.node.rig --ros-args -p control_period:=0.01

This module owns the process (signals, exit status), as `pcv_sim.node.emulator` does for one
valve; the node is `pcv_sim.node.rig_node.RigNode`. Only the standard library is imported at the
top: SIGINT/SIGTERM handling is installed first, so a signal at any moment is a clean stop (exit
0); invalid parameters exit 2 with a message naming the parameter.
"""

from __future__ import annotations

import signal
import sys
from typing import Any, Callable

from pcv_sim.node.emulator import EXIT_INVALID_PARAMETERS, EXIT_OK, Stop

__all__ = ["main"]


def _parameter_help() -> str:
    from pcv_sim.node.rig_settings import RIG_PARAMETERS  # noqa: PLC0415 - after the handlers

    lines = ["parameters (--ros-args -p NAME:=VALUE, or --params-file FILE):"]
    for spec in RIG_PARAMETERS:
        lines.append(f"  {spec.name} = {spec.default!r} [{spec.unit}]")
        lines.append(f"      {spec.description}")
    lines.append("  the valves, the cylinder, the step and the watchdog are set in the rig YAML (rig_config)")
    return "\n".join(lines)


def main(args: list[str] | None = None) -> int:
    """Console entry point `rig`. Returns 0 after SIGINT/SIGTERM, 2 for invalid parameters."""
    stop = Stop()
    previous: dict[int, Callable[..., Any] | int | None] = {}
    for sig in (signal.SIGINT, signal.SIGTERM):      # first: a signal during the imports below is a clean stop
        previous[sig] = signal.signal(sig, stop)
    try:
        return _run(list(sys.argv if args is None else args), stop)
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def _run(argv: list[str], stop: Stop) -> int:
    import argparse  # noqa: PLC0415 - imports after the signal handlers, see the module docstring

    from rclpy.utilities import remove_ros_args  # noqa: PLC0415

    parser = argparse.ArgumentParser(
        prog="rig", formatter_class=argparse.RawDescriptionHelpFormatter, epilog=_parameter_help(),
        description="Steering rig: the valves of a rig YAML and the steering cylinder as one ROS 2 node. Topics "
                    "per valve: in <valve>/duty_cycle; out <valve>/pressure, current, spool_position; "
                    "cylinder/joint_states, cylinder/pressure_a|b; in faults; /diagnostics, /clock.")
    parser.parse_args(remove_ros_args(argv)[1:])
    if stop.requested:
        print(f"rig: stopped on {stop.name} while starting", file=sys.stderr)
        return EXIT_OK

    import rclpy  # noqa: PLC0415
    from rclpy.signals import SignalHandlerOptions  # noqa: PLC0415

    from pcv_sim.errors import ParameterError  # noqa: PLC0415
    from pcv_sim.node.rig_node import RigNode  # noqa: PLC0415

    rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    node = None
    try:
        try:
            node = RigNode(argv=argv)
        except ParameterError as err:
            print(f"rig: invalid parameters: {err}", file=sys.stderr)
            return EXIT_INVALID_PARAMETERS
        if stop.requested:
            print(f"rig: stopped on {stop.name} while starting", file=sys.stderr)
            return EXIT_OK
        node.run(stop)
        node.get_logger().info(f"stopping on {stop.name}" if stop.signal else "stopping")
        return EXIT_OK
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    sys.exit(main())
