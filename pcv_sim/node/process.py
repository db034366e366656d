"""A node as a process, shared by the `emulator` and `rig` executables: signals, exit status,
the rclpy lifetime of one node.

Only the standard library is imported at the top: `main_process` installs SIGINT/SIGTERM
handling as the first thing a process does, before rclpy, numpy and the model are imported
(~1 s), so a signal at any moment is a clean stop (exit 0). Invalid parameters exit 2.

Two phases. While the process starts (imports, rclpy, the node's construction: kernels loaded
or compiled, rest states solved, which takes a minute on a busy machine with an empty kernel
cache) a signal *interrupts* that work at once (`StartInterrupted`, raised by the handler) and
the process exits 0: a flag alone would only be looked at once the start-up is done. From
`node.run` on, the signal only sets the flag, which the loop checks at every wake: it finishes
the wake and closes the bag with everything up to the stop.
"""

from __future__ import annotations

import faulthandler
import signal
import sys
from collections.abc import Callable
from typing import Any

__all__ = ["EXIT_INVALID_PARAMETERS", "EXIT_OK", "StartInterrupted", "Stop", "main_process", "parameter_help",
           "run_node", "serve"]

EXIT_OK = 0
EXIT_INVALID_PARAMETERS = 2


class StartInterrupted(BaseException):  # not an Exception: the stop the user asked for
    """A signal arrived while the process was starting (see the module docstring)."""


class Stop:
    """Set by SIGINT/SIGTERM; the node's loop checks it at every wake. While `starting`, the
    handler also raises StartInterrupted (once) to abandon the start-up."""

    def __init__(self) -> None:
        self.requested = False
        self.signal: int | None = None
        self.starting = True

    def __call__(self, signum: int, _frame: Any) -> None:
        self.requested = True
        self.signal = signum
        if self.starting:
            self.starting = False
            raise StartInterrupted

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
        try:
            return run(list(sys.argv if args is None else args), stop)
        except BaseException as exc:
            if not _interrupted(exc):
                raise
            stop.starting = False
            print(f"stopped on {stop.name} while starting", file=sys.stderr)
            return EXIT_OK
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def _interrupted(exc: BaseException) -> bool:
    """Whether `exc` is the start-up interruption, or an error raised because of it: a signal that
    lands while an extension module initialises (pybind11's, e.g. scipy's HiGHS) comes out as
    "ImportError: initialization failed" with the StartInterrupted as its cause."""
    seen: set[int] = set()
    e: BaseException | None = exc
    while e is not None and id(e) not in seen:
        if isinstance(e, StartInterrupted):
            return True
        seen.add(id(e))
        e = e.__cause__ or e.__context__
    return False


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
