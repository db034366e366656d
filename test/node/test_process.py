"""The emulator as a process: signals at any moment of the start-up stop it cleanly (exit 0)."""
import signal
import time

import pytest

from pcv_sim.io import read_bag

SIGTERM_BIT = 1 << (signal.SIGTERM - 1)


def _catches_sigterm(pid):
    """True once the process has a handler for SIGTERM (/proc/<pid>/status SigCgt): `main` has begun.

    Before that the interpreter is still starting (the wheels' bootstrap re-exec, site imports),
    where no Python code of ours runs; from `main`'s first line on a signal must be a clean stop."""
    try:
        with open(f'/proc/{pid}/status') as f:
            for line in f:
                if line.startswith('SigCgt:'):
                    return bool(int(line.split()[1], 16) & SIGTERM_BIT)
    except FileNotFoundError:
        return False
    return False


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM])
def test_a_signal_at_any_moment_of_the_start_stops_cleanly(ros, sig):
    """Signals 0 ms .. 1.5 s after `main` began (imports, rclpy.init, node construction, first
    wakes): exit 0, no traceback; a bag whose recording had started is finalized."""
    delays = (0.0, 0.05, 0.2, 0.5, 1.0, 1.5)
    runs = []
    for k, delay in enumerate(delays):
        emu = ros.start(f'early{k}', params={'record.enabled': True, 'record.directory': str(ros.tmp_path),
                                             'record.name': f'early{k}'})
        end = time.monotonic() + 30
        while not _catches_sigterm(emu.proc.pid):
            assert emu.proc.poll() is None and time.monotonic() < end, emu.output()
            time.sleep(0.001)
        time.sleep(delay)
        emu.proc.send_signal(sig)
        runs.append((delay, emu))
    for delay, emu in runs:
        rc = emu.wait(30)
        out = emu.output()
        assert rc == 0 and 'Traceback' not in out, f'{sig.name} {delay} s after main began: exit {rc}\n{out}'
    for k, (delay, emu) in enumerate(runs):
        out = emu.output()
        if 'recording ' in out:                  # the recording had started: it is finalized
            assert 'recording finished' in out, out
            bag = read_bag(ros.tmp_path / f'early{k}')
            assert not bag.warnings, (delay, bag.warnings)


#: s from a signal to the exit, at any moment of the start-up (~1 s measured; 2-3 s under load).
STOP_WITHIN = 8.0


def test_a_signal_while_the_kernels_compile_or_in_the_first_wakes_stops_at_once(ros, cpu_load):
    """Empty kernel caches (the first start after an install or an edit) and two CPU burners:
    loading and compiling the kernels then takes 20-60 s. A signal during it, and one right
    after the start line (the first wakes, where no kernel may be compiled any more), stops the
    emulator within STOP_WITHIN s, exit 0: the start-up is abandoned, not finished first."""
    for k, delay in enumerate((2.0, 6.0, 12.0, None)):
        emu = ros.start(f'cold{k}', params={'watchdog_timeout': 0.0},
                        env={**ros.env, 'PCV_SIM_CACHE': str(ros.tmp_path / f'cache{k}')})
        end = time.monotonic() + 300
        while not (_catches_sigterm(emu.proc.pid) if delay is not None else 'samples at' in emu.output()):
            assert emu.proc.poll() is None and time.monotonic() < end, emu.output()
            time.sleep(0.001)
        if delay is not None:
            time.sleep(delay)
        sent = time.monotonic()
        emu.proc.send_signal(signal.SIGINT)
        rc = emu.wait(120)
        took = time.monotonic() - sent
        out = emu.output()
        assert rc == 0 and 'Traceback' not in out, out
        assert took < STOP_WITHIN, f'SIGINT {delay} s after main began: stopped after {took:.1f} s\n{out}'


def test_the_entry_module_imports_nothing_heavy_before_main_installs_the_handlers():
    """`main` installs the handlers first; what it imports afterwards (rclpy, numpy, the model: ~1 s)
    is then covered. The module itself must import only the standard library."""
    import subprocess
    import sys

    from node.conftest import clean_child_env

    code = ("import sys, pcv_sim.node.emulator; "
            "print(sorted(m for m in ('rclpy', 'numpy', 'scipy', 'yaml', 'pcv_sim.node.device_node') if m in sys.modules))")
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, env=clean_child_env(),
                         timeout=60)
    assert out.returncode == 0 and out.stdout.strip() == '[]', out


def test_a_signal_inside_a_native_callback_of_the_start_up_still_stops_it():
    """The kernel compiler calls back into Python from native code (llvmlite's object cache, a
    ctypes callback): an exception raised there by a signal handler is swallowed ("Exception
    ignored") and the start-up went on with numba's cache half written (a traceback, exit 1,
    under CPU load). The start-up is abandoned from the handler itself: exit 0, the reason said,
    no traceback, nothing after the signal runs."""
    import subprocess
    import sys

    from node.conftest import clean_child_env

    code = """if True:
        import ctypes, signal, sys
        from pcv_sim.node.process import main_process

        def start(argv, stop):
            callback = ctypes.CFUNCTYPE(None)(lambda: signal.raise_signal(signal.SIGINT))
            callback()                                   # the handler runs inside the native call
            print('the start-up went on')
            return 5

        sys.exit(main_process(start, ['emulator']))
    """
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, env=clean_child_env(),
                         timeout=60)
    assert out.returncode == 0, out
    assert 'stopped on SIGINT while starting' in out.stderr and 'Traceback' not in out.stderr, out
    assert 'the start-up went on' not in out.stdout, out
