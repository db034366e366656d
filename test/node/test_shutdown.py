"""The emulator's stop is bounded: whatever its teardown waits for after the loop (the DDS library
waiting for a peer that was stopped or vanished, a thread that never ends, a native call that holds
the interpreter lock, a parameter change being prepared), the process ends within its bound, says
what it gave up on and prints every thread's stack (pcv_sim.node.process, pcv_sim.node.services)."""
import shutil
import signal
import sys
import time

from pcv_sim.node.process import NATIVE_STACKS_BOUND, TEARDOWN_BACKSTOP, TEARDOWN_BOUND
from pcv_sim.node.services import WORKER_STOP_BOUND

#: An emulator process whose teardown is made to hang in one of three ways (argv[1]); the node and
#: the process machinery are the real ones.
HANGING = """if True:
    import atexit, ctypes, sys, threading, time
    from pcv_sim.node.emulator import emulator_node
    from pcv_sim.node.process import main_process, serve

    how = sys.argv.pop(1)

    def make(argv):
        node = emulator_node(argv=argv)
        destroy = node.destroy_node

        def destroy_node():
            if how == 'destroy':            # a wait that releases the interpreter lock and never ends
                threading.Event().wait()
            elif how == 'native':           # a native call that holds the interpreter lock (PyDLL keeps it)
                ctypes.PyDLL(None).sleep(3600)
            destroy()

        node.destroy_node = destroy_node
        if how == 'worker':                 # a parameter change whose preparation never ends
            node._prepare = lambda params, changes: threading.Event().wait()
        if how == 'slow':                   # the construction's last steps slow (a busy machine)
            time.sleep(2.0)
        if how == 'exit':                   # the interpreter's exit would join this thread, and wait in atexit
            threading.Thread(target=threading.Event().wait, name='never ends').start()
            atexit.register(threading.Event().wait)
        return node

    sys.exit(main_process(lambda argv, stop: serve('emulator', argv, stop, make), None))
"""

#: s beside the bound for the SIGINT to reach the loop and the output to be written, under load.
MARGIN = 4.0


def _emulator(ros, how):
    from .conftest import Emulator

    cmd = [sys.executable, '-c', HANGING, how, '--ros-args', '-r', f'__ns:={ros.ns(how)}', '-p', 'watchdog_timeout:=0.0']
    emu = Emulator(cmd, ros.env, ros.tmp_path / f'{how}.log')
    ros.emulators.append(emu)
    return emu


def test_a_teardown_that_hangs_is_given_up_within_its_bound_saying_where(ros, cpu_load):
    """Three emulators beside two CPU burners, each with its teardown made to hang: in a wait that
    releases the interpreter lock (the node's destruction), in a native call that holds it, and in
    the interpreter's exit (a thread never ending, an atexit handler waiting). Each ends within its
    bound after the SIGINT with every thread's stack printed: exit 0 where the watchdog could run (it
    names the step it gave up), exit 1 from faulthandler's own thread where the lock was held."""
    emus = {how: _emulator(ros, how) for how in ('destroy', 'native', 'exit')}
    for how, emu in emus.items():
        end = time.monotonic() + 120
        while 'samples at' not in emu.output():
            assert emu.proc.poll() is None and time.monotonic() < end, (how, emu.output())
            time.sleep(0.05)
    sent = time.monotonic()
    for emu in emus.values():
        emu.proc.send_signal(signal.SIGINT)
    took = {}
    while len(took) < len(emus) and time.monotonic() - sent < TEARDOWN_BOUND + TEARDOWN_BACKSTOP + MARGIN + 10:
        for how, emu in emus.items():
            if how not in took and emu.proc.poll() is not None:
                took[how] = (time.monotonic() - sent, emu.proc.returncode)
        time.sleep(0.01)
    assert len(took) == len(emus), took
    out = {how: emu.output() for how, emu in emus.items()}
    for emu in emus.values():
        emu.wait(1)
    # The harness's PCV_SIM_STACKS: the native stacks too, gdb bounded by NATIVE_STACKS_BOUND.
    assert took['destroy'][1] == 0 and took['destroy'][0] < TEARDOWN_BOUND + NATIVE_STACKS_BOUND + MARGIN, \
        (took, out['destroy'])
    assert ('emulator: shutdown: destroying the node (its DDS publishers, subscriptions and services) did not finish '
            f'within {TEARDOWN_BOUND:g} s; exiting without it (exit 0)') in out['destroy'], out['destroy']
    assert 'in destroy_node' in out['destroy'] and 'stopping on SIGINT' in out['destroy'], out['destroy']
    if shutil.which('gdb') and shutil.which('timeout'):
        assert 'LWP ' in out['destroy'], out['destroy']      # gdb attached (all of its stacks when it is quick enough)
    assert took['native'][1] == 1 and took['native'][0] < TEARDOWN_BOUND + TEARDOWN_BACKSTOP + MARGIN, (took, out['native'])
    assert 'Timeout' in out['native'] and 'in destroy_node' in out['native'], out['native']
    assert took['exit'][1] == 0 and took['exit'][0] < MARGIN, (took, out['exit'])
    assert 'did not finish' not in out['exit'] and 'Traceback' not in out['exit'], out['exit']


def test_a_parameter_change_still_being_prepared_does_not_hold_up_the_stop(ros):
    """The worker thread prepares a parameter change that never ends: the stop waits for it
    WORKER_STOP_BOUND s, says it left the request unanswered, and the process ends (exit 0) without
    joining the thread."""
    emu = _emulator(ros, 'worker')
    c = ros.client('worker')
    assert c.wait_for_emulator(120), emu.output()
    try:
        c.set_parameters({'model.spool.mass': 0.045}, timeout=1.0)
    except Exception as err:            # never answered: the client gives up after its timeout
        print(f'set_parameters: {err!r}')
    sent = time.monotonic()
    emu.proc.send_signal(signal.SIGINT)
    rc = emu.proc.wait(WORKER_STOP_BOUND + TEARDOWN_BOUND + MARGIN + 10)
    took = time.monotonic() - sent
    out = emu.output()
    emu.wait(1)
    assert rc == 0 and took < WORKER_STOP_BOUND + MARGIN, (took, rc, out)
    assert (f'stopping: the request to emulator/set_parameters in progress is left unanswered after '
            f'{WORKER_STOP_BOUND:g} s') in out, out
    assert 'stopping on SIGINT' in out and 'did not finish' not in out and 'Traceback' not in out, out


def test_a_signal_right_after_the_start_line_is_a_clean_stop(ros):
    """The start line ("... samples at ...") is what a supervisor or a test waits for before it
    signals; it is said once a signal is the loop's stop (the teardown runs, a bag would be
    closed), not while the construction is still ending, where a signal abandons the start-up.
    Here the construction's end is made slow (2 s after the node's own constructor)."""
    emu = _emulator(ros, 'slow')
    end = time.monotonic() + 120
    while 'samples at' not in emu.output():
        assert emu.proc.poll() is None and time.monotonic() < end, emu.output()
        time.sleep(0.01)
    emu.proc.send_signal(signal.SIGINT)
    assert emu.wait(TEARDOWN_BOUND + MARGIN + 10) == 0, emu.output()
    out = emu.output()
    assert 'stopping on SIGINT' in out and 'while starting' not in out, out
