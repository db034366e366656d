"""Soak (opt-in: `pytest --soak test/node/test_shutdown_soak.py`, PCV_SIM_SOAK_RUNS runs per variant,
default 10): the stop of an emulator that was SIGSTOPped while the demo ran against it, as in
test_launch_and_demo.py's `test_demo_against_an_emulator_that_stops_says_so`, made harsher and
repeated beside four CPU burners. The emulator once logged "stopping on SIGINT" there and did not
exit within 15 s (a hang after its loop). Variants:

- `demo_exits`: the test's own sequence: the demo ends while the emulator is stopped, SIGCONT,
  SIGINT 0-0.3 s later (its timers late, its loop far behind wall time);
- `sigint_while_stopped`: SIGINT sent while it is stopped, then SIGCONT: the signal is the first
  thing it sees;
- `twice`: SIGINT, and another 50 ms later (the second one during the teardown);
- `demo_killed`: the demo SIGKILLed while the emulator is stopped (a peer that vanishes without
  saying so: its DDS participant is only dropped when its lease runs out);
- `overlap`: a short stop, then SIGINT while the demo still publishes (the teardown while a peer
  delivers samples).

Each stop must end within the harness's 15 s with exit 0, and without a teardown step given up
(`pcv_sim.node.process.Teardown`): every such case is collected with its stacks (the harness's
PCV_SIM_STACKS: Python and native) and the counts are printed (`-s`)."""
import os
import random
import signal
import subprocess
import sys
import time

import pytest

from .conftest import GIVEN_UP

pytestmark = pytest.mark.soak

RUNS = int(os.environ.get('PCV_SIM_SOAK_RUNS', '10'))
HOGS = 4
STOP_WITHIN = 15.0                          # s, as the harness's Emulator.stop


def _demo(ros, name):
    return subprocess.Popen(
        [sys.executable, '-m', 'pcv_sim.node.demo', '--namespace', ros.ns(name), '--duties', '0.5,0.7,0.5', '--hold',
         '0.3', '--timeout', '120'], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ros.env)


def _end(proc, timeout=60):
    try:
        proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate()


def _one(ros, variant, k):
    """One run; returns (seconds from the SIGINT to the exit or None, exit code, the emulator's output)."""
    name = f'{variant}{k}'
    emu = ros.start(name, params={'safe_duty': 0.3})
    demo = _demo(ros, name)
    try:
        first = demo.stdout.readline()
        assert first.startswith('demo: emulator'), first + demo.stderr.read()
        emu.proc.send_signal(signal.SIGSTOP)
        if variant in ('demo_exits', 'sigint_while_stopped', 'twice'):
            _end(demo)
        elif variant == 'demo_killed':
            time.sleep(1.0)
            demo.kill()
            demo.wait()
        else:                                   # overlap
            time.sleep(0.5)
        sent = time.monotonic()
        if variant == 'sigint_while_stopped':
            emu.proc.send_signal(signal.SIGINT)
            emu.proc.send_signal(signal.SIGCONT)
        else:
            emu.proc.send_signal(signal.SIGCONT)
            time.sleep(random.uniform(0.0, 0.3))
            sent = time.monotonic()
            emu.proc.send_signal(signal.SIGINT)
            if variant == 'twice':
                time.sleep(0.05)
                emu.proc.send_signal(signal.SIGINT)
        try:
            rc = emu.proc.wait(STOP_WITHIN - (time.monotonic() - sent))
        except subprocess.TimeoutExpired:
            try:
                emu.stop(timeout=0.1)           # the harness's: native stacks, then SIGABRT (Python stacks)
            except AssertionError as hang:
                return None, None, str(hang)
        took = time.monotonic() - sent
        return took, rc, emu.output()
    finally:
        emu.proc.send_signal(signal.SIGCONT)
        if demo.poll() is None:
            _end(demo)


@pytest.mark.parametrize('variant', ['demo_exits', 'sigint_while_stopped', 'twice', 'demo_killed', 'overlap'])
def test_an_emulator_stopped_and_resumed_under_load_stops_on_sigint(ros, cpu_burners, variant):
    cpu_burners(HOGS)
    results = [_one(ros, variant, k) for k in range(RUNS)]
    hangs = [out for took, _, out in results if took is None]
    given_up = [out for took, _, out in results if took is not None and GIVEN_UP in out]
    failed = [out for took, rc, out in results if took is not None and (rc != 0 or 'Traceback' in out)]
    times = sorted(took for took, _, _ in results if took is not None)
    print(f'\n{variant}: {RUNS} runs, {len(hangs)} not stopped within {STOP_WITHIN:g} s, {len(given_up)} with a '
          f'teardown step given up, {len(failed)} with exit != 0 or a traceback; stop took '
          f'{times[0] if times else float("nan"):.2f}..{times[-1] if times else float("nan"):.2f} s '
          f'(median {times[len(times) // 2] if times else float("nan"):.2f}); load {os.getloadavg()[0]:.1f}')
    assert not hangs and not given_up and not failed, '\n\n'.join(hangs + given_up + failed)
