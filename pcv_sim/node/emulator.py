"""The `emulator` executable: the valve emulator node as a process.

    ros2 run pcv_sim emulator --ros-args --params-file config/emulator.yaml
    python -m pcv_sim.node.emulator --ros-args -r __ns:=/left -p watchdog_timeout:=2.0

This module owns the process (signals, exit status); the node is `pcv_sim.node.adapter.EmulatorNode`.
It imports only the standard library at the top: SIGINT/SIGTERM handling is installed as the first
thing `main` does, before rclpy, numpy and the model are imported (~1 s), so a signal at any
moment stops the emulator cleanly (exit 0; a recording that had started is finalized).
"""

from __future__ import annotations

import sys

from pcv_sim.node.process import EXIT_INVALID_PARAMETERS, EXIT_OK, Stop, main_process, serve

__all__ = ["EXIT_INVALID_PARAMETERS", "EXIT_OK", "Stop", "main"]


def _parameter_help() -> str:
    from pcv_sim.device.settings import MODEL_PREFIX, NODE_PARAMETERS

    lines = ["parameters (--ros-args -p NAME:=VALUE, or --params-file config/emulator.yaml):"]
    for spec in NODE_PARAMETERS:
        lines.append(f"  {spec.name} = {spec.default!r} [{spec.unit}]{' (read-only)' if spec.read_only else ''}")
        lines.append(f"      {spec.description}")
    lines.append(f"  {MODEL_PREFIX}<section>.<key>: the valve model's scalar and vector parameters "
                 "(config/valve.yaml), e.g. model.spool.mass")
    return "\n".join(lines)


def main(args: list[str] | None = None) -> int:
    """Console entry point `emulator`. Returns 0 after SIGINT/SIGTERM, 2 for invalid parameters."""
    return main_process(_run, args)


def _run(argv: list[str], stop: Stop) -> int:
    import argparse

    from pcv_sim.node.command_line import command_line_problem

    parser = argparse.ArgumentParser(
        prog="emulator", formatter_class=argparse.RawDescriptionHelpFormatter, epilog=_parameter_help(),
        description="Hydraulic proportional pressure control valve emulator (ROS 2 node). Topics: in duty_cycle, "
                    "load_flow, supply_pressure; out pressure, current, spool_position, /diagnostics.")
    reason = command_line_problem(argv, parser)
    if reason is not None:
        print(f"emulator: invalid parameters: {reason}", file=sys.stderr)
        return EXIT_INVALID_PARAMETERS
    if stop.requested:
        print(f"emulator: stopped on {stop.name} while starting", file=sys.stderr)
        return EXIT_OK
    from pcv_sim.node.adapter import EmulatorNode

    return serve("emulator", argv, stop, lambda argv: EmulatorNode(argv=argv))


if __name__ == "__main__":
    sys.exit(main())
