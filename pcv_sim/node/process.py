"""A node as a process, shared by the `emulator` and `rig` executables: signals, exit status,
the rclpy lifetime of one node.

Only the standard library is imported at the top: `main_process` installs SIGINT/SIGTERM
handling as the first thing a process does, before rclpy, numpy and the model are imported
(~1 s), so a signal at any moment is a clean stop (exit 0). Invalid parameters exit 2.

Two phases. While the process starts (imports, rclpy, the node's construction: kernels loaded
or compiled, rest states solved, which takes a minute on a busy machine with an empty kernel
cache) a signal *abandons* that work at once: the handler says so and ends the process (exit 0)
with `os._exit`. A flag alone would only be looked at once the start-up is done, and an
exception raised from the handler is not safe there: inside a ctypes callback of the kernel
compiler it is swallowed ("Exception ignored") and leaves numba's cache half written, inside
an extension module's initialisation it becomes an ImportError. Nothing of the start-up needs
closing: no bag is open yet, the kernel cache is written by rename. From
`node.run` on, the signal only sets the flag, which the loop checks at every wake: it finishes
the wake and closes the bag with everything up to the stop.
"""

from __future__ import annotations

import contextlib
import faulthandler
import os
import signal
import sys
from collections.abc import Callable
from typing import Any

__all__ = ["EXIT_INVALID_PARAMETERS", "EXIT_OK", "Stop", "main_process", "parameter_help",
           "run_node", "serve"]

EXIT_OK = 0
EXIT_INVALID_PARAMETERS = 2


class Stop:
    """Set by SIGINT/SIGTERM; the node's loop checks it at every wake. While `starting`, the
    handler abandons the start-up (see the module docstring)."""

    def __init__(self) -> None:
        self.requested = False
        self.signal: int | None = None
        self.starting = True

    def __call__(self, signum: int, _frame: Any) -> None:
        self.requested = True
        self.signal = signum
        if self.starting:
            self.starting = False
            _abandon(self.name)

    @property
    def name(self) -> str:
        return signal.Signals(self.signal).name if self.signal else ""


def main_process(run: Callable[[list[str], Stop], int], args: list[str] | None) -> int:
    """Install the signal handlers, then `run(argv, stop)`; the previous handlers come back after."""
    faulthandler.enable()      # a crash in the ROS libraries prints the Python stack that led to it
    stop = Stop()
    previous: dict[signal.Signals, Callable[..., Any] | int | None] = {}
    for sig in (signal.SIGINT, signal.SIGTERM):      # first: a signal during the imports is a clean stop
        previous[sig] = signal.signal(sig, stop)
    try:
        return run(list(sys.argv if args is None else args), stop)
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def _abandon(name: str) -> None:
    """End the process now, exit 0, saying why (what was printed before is flushed first)."""
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):     # the handler may have interrupted a write to it
            stream.flush()
    os.write(2, f"stopped on {name} while starting\n".encode())
    os._exit(EXIT_OK)


def run_node(prog: str, argv: list[str], stop: Stop, *, description: str, epilog: Callable[[], str],
             make_node: Callable[[list[str]], Any],
             check: Callable[[list[str]], str | None] | None = None) -> int:
    """An executable's whole run: its command line checked (`--help` with `description` and the
    `epilog()` parameter list; `check(argv)`: its own test of the params files), then `serve`."""
    import argparse

    from pcv_sim.node.command_line import command_line_problem

    parser = argparse.ArgumentParser(prog=prog, formatter_class=argparse.RawDescriptionHelpFormatter,
                                     epilog=epilog(), description=description)
    reason = command_line_problem(argv, parser, check)
    if reason is not None:
        print(f"{prog}: invalid parameters: {reason}", file=sys.stderr)
        return EXIT_INVALID_PARAMETERS
    if stop.requested:
        print(f"{prog}: stopped on {stop.name} while starting", file=sys.stderr)
        return EXIT_OK
    return serve(prog, argv, stop, make_node)


def parameter_help(specs: Any, params_file: str, *tail: str) -> str:
    """The parameter list of an executable's --help: each declared parameter with its default, unit,
    read-only flag and description, then the lines of `tail`."""
    lines = [f"parameters (--ros-args -p NAME:=VALUE, or --params-file {params_file}):"]
    for spec in specs:
        lines.append(f"  {spec.name} = {spec.default!r} [{spec.unit}]{' (read-only)' if spec.read_only else ''}")
        lines.append(f"      {spec.description}")
    lines.extend(f"  {line}" for line in tail)
    return "\n".join(lines)


def serve(prog: str, argv: list[str], stop: Stop, make_node: Callable[[list[str]], Any]) -> int:
    """rclpy up, the node made (`make_node(argv)`; a ParameterError -> exit 2 naming it), run until
    the stop (`node.run(stop)`), then destroyed and rclpy shut down, whatever happened."""
    import rclpy
    from rclpy.signals import SignalHandlerOptions
    from rclpy.utilities import try_shutdown

    from pcv_sim.errors import ParameterError

    rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    node = None
    try:
        try:
            node = make_node(argv)
        except ParameterError as err:
            print(f"{prog}: invalid parameters: {err}", file=sys.stderr)
            return EXIT_INVALID_PARAMETERS
        stop.starting = False       # from here a signal is a flag the loop checks
        try:
            node.run(stop)          # returns at once if a signal came and was swallowed during the start
        except ParameterError as err:           # found while running (e.g. a second /clock at start)
            node.get_logger().error(f"invalid parameters: {err}")
            print(f"{prog}: invalid parameters: {err}", file=sys.stderr)
            return EXIT_INVALID_PARAMETERS
        node.get_logger().info(f"stopping on {stop.name}" if stop.signal else "stopping")
        return EXIT_OK
    finally:
        if node is not None:
            node.destroy_node()
        try_shutdown()
