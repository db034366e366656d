"""The command line of a node executable, read before the node starts: --help, params files, ROS arguments.

Shared by the `emulator` and `rig` executables. A params file that is missing, unreadable or not
YAML, or one rcl cannot read as ROS parameters, is refused with the file and the reason (exit 2
from the caller, no traceback). rclpy is imported here, after the signal handlers are in place.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable

__all__ = ["command_line_problem"]


def command_line_problem(argv: list[str], parser: argparse.ArgumentParser,
                         check: Callable[[list[str]], str | None] | None = None) -> str | None:
    """Why the command line cannot start a node (None if it can). `parser` reads the arguments
    outside --ros-args (argparse prints --help and its own errors and exits); `check(argv)` is an
    executable's own test of its params files, run before rcl reads them."""
    from rclpy.utilities import remove_ros_args

    from pcv_sim.device.parameters import check_params_files, ros_arguments_message
    from pcv_sim.errors import ParameterError

    try:
        check_params_files(argv)
    except ParameterError as err:
        return str(err)
    reason = check(argv) if check is not None else None
    if reason is not None:
        return reason
    try:
        own = remove_ros_args(argv)
    except Exception as err:          # rclpy's RCLInvalidROSArgsError: rcl refused a params file or a rule
        return f"--ros-args: {ros_arguments_message(err)}"
    parser.parse_args(own[1:])
    return None
