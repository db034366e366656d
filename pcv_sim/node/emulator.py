"""The `emulator` executable: the valve emulator node as a process.

    ros2 run pcv_sim emulator --ros-args --params-file config/emulator.yaml
    python -m pcv_sim.node.emulator --ros-args -r __ns:=/left -p watchdog_timeout:=2.0

The process (signals, exit status, the command line) is `pcv_sim.node.process`'s; the node is
`pcv_sim.node.device_node.DeviceNode` over one valve (`pcv_sim.node.kinds.EMULATOR`). Only the
standard library is imported at the top, so a signal at any moment stops the emulator cleanly
(exit 0; a recording that had started is finalized).
"""

from __future__ import annotations

import sys
from typing import Any

from pcv_sim.node.process import EXIT_INVALID_PARAMETERS, EXIT_OK, Stop, main_process, parameter_help, run_node

__all__ = ["EXIT_INVALID_PARAMETERS", "EXIT_OK", "Stop", "emulator_node", "main"]

DESCRIPTION = ("Hydraulic proportional pressure control valve emulator (ROS 2 node). Topics: in duty_cycle, "
               "load_flow, supply_pressure; out pressure, current, spool_position, /diagnostics.")


def _epilog() -> str:
    from pcv_sim.device.settings import MODEL_PREFIX, NODE_PARAMETERS

    return parameter_help(NODE_PARAMETERS, "config/emulator.yaml",
                          f"{MODEL_PREFIX}<section>.<key>: the valve model's scalar and vector parameters "
                          "(config/valve.yaml), e.g. model.spool.mass")


def emulator_node(**kwargs: Any) -> Any:
    """The emulator node in this process (`argv`, `context`, `namespace`, `parameter_overrides`... as for
    an rclpy Node); the caller runs and destroys it."""
    from pcv_sim.node.device_node import DeviceNode
    from pcv_sim.node.kinds import EMULATOR

    return DeviceNode(EMULATOR, **kwargs)


def _node(argv: list[str]) -> Any:
    return emulator_node(argv=argv)


def main(args: list[str] | None = None) -> int:
    """Console entry point `emulator`. Returns 0 after SIGINT/SIGTERM, 2 for invalid parameters."""
    return main_process(lambda argv, stop: run_node("emulator", argv, stop, description=DESCRIPTION,
                                                    epilog=_epilog, make_node=_node), args)


if __name__ == "__main__":
    sys.exit(main())
