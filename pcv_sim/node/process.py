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

The stop is bounded. After the loop (worker stopped, bag closed) the node is destroyed, rclpy
shut down and its context destroyed (the DDS participant) under a watchdog (`Teardown`): a step
that has not finished within TEARDOWN_BOUND s (the DDS library waiting for a peer that was
stopped or vanished, a lock its thread holds) is given up, the process says which one and
prints every thread's stack, and exits with the code it would have had. A step stuck in native
code that holds the interpreter lock, where no Python thread can run, is ended by faulthandler's
own thread TEARDOWN_BACKSTOP s later (its stacks, exit 1). Then the process ends itself
(`os._exit`, output flushed) rather than through the interpreter's exit, which would join
leftover threads and run the DDS library's static destructors without any bound, with nothing
left to close; so does a run that ended in an exception (its traceback printed, exit 1). With
$PCV_SIM_STACKS set, SIGUSR1 prints every thread's stack at any moment (a process that seems
stuck, while it runs), and a given-up step also prints the native stacks (gdb, where installed:
the DDS library's threads).
"""

from __future__ import annotations

import contextlib
import faulthandler
import os
import signal
import sys
import threading
import traceback
from collections.abc import Callable
from typing import Any, NoReturn

__all__ = ["EXIT_INVALID_PARAMETERS", "EXIT_OK", "NATIVE_STACKS_BOUND", "STACKS_ENV", "TEARDOWN_BACKSTOP",
           "TEARDOWN_BOUND", "Stop", "Teardown", "main_process", "parameter_help", "run_node", "serve"]

EXIT_OK = 0
EXIT_INVALID_PARAMETERS = 2
#: s the node's teardown after the loop (the node destroyed, rclpy shut down: ~0.1 s, ~1 s under load)
#: may take before the process gives up on it; within the 15 s a supervisor gives a SIGINT.
TEARDOWN_BOUND = 5.0
#: s after TEARDOWN_BOUND at which faulthandler's thread ends a teardown stuck holding the interpreter lock.
TEARDOWN_BACKSTOP = 3.0
#: Set (to anything): SIGUSR1 prints every thread's stack (faulthandler), the process goes on; a
#: given-up teardown also prints the native stacks.
STACKS_ENV = "PCV_SIM_STACKS"
#: s the native stacks (gdb) may take on the way out.
NATIVE_STACKS_BOUND = 6.0


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
    if os.environ.get(STACKS_ENV):
        faulthandler.register(signal.SIGUSR1, all_threads=True)
    stop = Stop()
    previous: dict[signal.Signals, Callable[..., Any] | int | None] = {}
    for sig in (signal.SIGINT, signal.SIGTERM):      # first: a signal during the imports is a clean stop
        previous[sig] = signal.signal(sig, stop)
    try:
        code = run(list(sys.argv if args is None else args), stop)
    except SystemExit as done:            # argparse: --help (0), a usage error (2, said already)
        code = done.code if isinstance(done.code, int) else 0 if done.code is None else 1
        if isinstance(done.code, str):
            print(done.code, file=sys.stderr)
    except BaseException:                 # what the interpreter would print, and its exit status
        traceback.print_exc()
        code = 1
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    _end_process(code)


def _end_process(code: int) -> NoReturn:
    """End the process now with `code`, its output flushed. Everything was closed in order before
    (the bag, the node, rclpy): the interpreter's exit would only join leftover threads and run the
    DDS library's static destructors, neither of them bounded (see the module docstring)."""
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    os._exit(code)


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
    from rclpy.utilities import get_default_context, try_shutdown

    from pcv_sim.errors import ParameterError

    rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    node = None
    code = EXIT_OK
    ran = False
    try:
        try:
            node = make_node(argv)
        except ParameterError as err:
            print(f"{prog}: invalid parameters: {err}", file=sys.stderr)
            code = EXIT_INVALID_PARAMETERS
            return code
        stop.starting = False       # from here a signal is a flag the loop checks
        try:
            node.run(stop)          # returns at once if a signal came and was swallowed during the start
        except ParameterError as err:           # found while running (e.g. a second /clock at start)
            node.get_logger().error(f"invalid parameters: {err}")
            print(f"{prog}: invalid parameters: {err}", file=sys.stderr)
            code = EXIT_INVALID_PARAMETERS
            return code
        ran = True
        return code
    finally:
        with Teardown(prog, code) as teardown:
            if ran and node is not None:
                teardown.step("saying the stop (the log line, also to /rosout)")
                node.get_logger().info(f"stopping on {stop.name}" if stop.signal else "stopping")
            if node is not None:
                teardown.step("destroying the node (its DDS publishers, subscriptions and services)")
                node.destroy_node()
            teardown.step("shutting rclpy down")
            try_shutdown()
            # The DDS participant goes with the context (else only with the interpreter's exit, which
            # `main_process` skips): its peers are told it left instead of waiting for its lease to end.
            destroy = getattr(get_default_context(), "destroy", None)
            if destroy is not None:
                teardown.step("destroying rclpy's context (the DDS participant)")
                destroy()


class Teardown:
    """A watchdog over the steps after the loop (see the module docstring): `step(what)` names the
    one now running; one that has not ended TEARDOWN_BOUND s after the teardown began is given up
    (said on stderr with every thread's stack, the process ended with `code`). Leaving the block
    disarms it."""

    def __init__(self, prog: str, code: int, bound: float = TEARDOWN_BOUND,
                 backstop: float = TEARDOWN_BACKSTOP) -> None:
        self.prog, self.code, self.bound, self.backstop = prog, code, bound, backstop
        self.what = "starting the teardown"
        self._done = threading.Event()

    def step(self, what: str) -> None:
        self.what = what

    def __enter__(self) -> Teardown:
        # faulthandler's own C thread: fires even while a native call holds the interpreter lock.
        faulthandler.dump_traceback_later(self.bound + self.backstop, exit=True)
        threading.Thread(target=self._watch, name="pcv_sim teardown watchdog", daemon=True).start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._done.set()
        faulthandler.cancel_dump_traceback_later()

    def _watch(self) -> None:
        if self._done.wait(self.bound):
            return
        faulthandler.cancel_dump_traceback_later()      # this thread runs: it ends the process itself
        with contextlib.suppress(Exception):
            sys.stdout.flush()
        os.write(2, f"{self.prog}: shutdown: {self.what} did not finish within {self.bound:g} s; "
                    f"exiting without it (exit {self.code}); every thread's stack:\n".encode())
        faulthandler.dump_traceback(all_threads=True)
        if os.environ.get(STACKS_ENV):
            _native_stacks()
        _end_process(self.code)


def _native_stacks() -> None:
    """Every thread's native stack on stderr, by gdb where it is installed ($PCV_SIM_STACKS): the DDS
    library's threads, which faulthandler does not show. Bounded by `timeout` killing gdb: while gdb
    is attached this process is stopped and could not time it out itself. A gdb killed before it
    took the SIGSTOP of its attach leaves the process stopped (group-stop): the shell sends SIGCONT.
    (Seen once beside two CPU burners: the stop waited for `timeout` more than 30 s.)"""
    import shlex
    import shutil
    import subprocess

    gdb, timeout = shutil.which("gdb"), shutil.which("timeout")
    if gdb is None or timeout is None:
        return
    pid = str(os.getpid())
    script = (f"{shlex.quote(timeout)} -s KILL {NATIVE_STACKS_BOUND:g} {shlex.quote(gdb)} -p {pid} -batch -nx "
              f"-ex 'thread apply all bt' 2>/dev/null; kill -CONT {pid}")
    with contextlib.suppress(OSError, subprocess.SubprocessError):
        # Waited for here too: once this process runs again it leaves a gdb (or timeout) still going.
        subprocess.Popen(["/bin/sh", "-c", script], stdin=subprocess.DEVNULL, stdout=2,
                         stderr=subprocess.DEVNULL).wait(NATIVE_STACKS_BOUND + 2.0)

