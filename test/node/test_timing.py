"""Real-time loop accounting: no stall from model restarts; the overrun choice when it falls behind."""
import itertools
import os
import signal
import time

import pytest

START = 60.0


def _diag_after(c, timeout=10):
    """The next diagnostics message."""
    n = len(c.diagnostics)
    assert c.spin_until(lambda: len(c.diagnostics) > n, timeout)
    return c.diagnostics[-1]


def test_resets_and_model_changes_do_not_stall_the_loop(ros):
    """Before: each restart computed its rest state inside the loop (25-56 ms) and skipped 510-650
    steps even on a quiet machine. Now a worker thread computes it and the loop swaps it in.

    Judged by the loop thread's own CPU time per wake (the node's `max_wake_cpu_ms`), which other
    jobs on the machine cannot inflate: a rest state computed in the loop is 25-56 ms of it in one
    wake. max_catchup 10 s keeps a starved machine from skipping steps for reasons of its own."""
    ros.start(params={'safe_duty': 0.3, 'watchdog_timeout': 0.0, 'diagnostics_period': 0.2, 'max_catchup': 10.0})
    c = ros.client()
    assert c.wait_for_emulator(START)
    c.send_duty(0.6)
    _diag_after(c)
    first = _diag_after(c)            # the period before starts after the first one (start-up work)
    n_diag = len(c.diagnostics)
    n0 = len(c.samples)
    for k in range(4):
        response = c.reset()
        assert response.success and 'model at rest at duty 0.6' in response.message, response.message
        assert c.set_parameters({'model.spool.mass': 0.045 if k % 2 == 0 else 0.04})[0].successful
    _diag_after(c)
    last = _diag_after(c)             # its period starts after a message received after the phase
    assert last['skipped_steps'] == first['skipped_steps'], (first['skipped_steps'], last['skipped_steps'])
    during = [float(d['period_max_wake_cpu_ms']) for d in c.diagnostics[n_diag:]]   # every wake since `first`
    assert max(during) < 10.0, during
    stamps = [s.stamp_ns for s in c.samples[n0:]]
    assert len(stamps) > 100 and all(b > a for a, b in itertools.pairwise(stamps))


@pytest.mark.parametrize(('overrun', 'skipped'), [('catch_up', False), ('skip', True)])
def test_overrun_choice_when_the_process_is_stopped(ros, overrun, skipped):
    """SIGSTOP for 0.3 s puts the loop 300 ms behind. catch_up (max_catchup 10 s here) computes the
    backlog late, nothing skipped; skip holds the model over all but the last wake period."""
    emu = ros.start(params={'safe_duty': 0.3, 'watchdog_timeout': 0.0, 'diagnostics_period': 0.2,
                            'overrun': overrun, 'max_catchup': 10.0})
    c = ros.client()
    assert c.wait_for_emulator(START)
    first = _diag_after(c)
    os.kill(emu.proc.pid, signal.SIGSTOP)
    time.sleep(0.3)
    os.kill(emu.proc.pid, signal.SIGCONT)
    c.spin_for(0.5)
    last = _diag_after(c)
    new_skipped = int(last['skipped_steps']) - int(first['skipped_steps'])
    new_late = int(last['late_steps']) - int(first['late_steps'])
    if skipped:
        assert new_skipped >= 2900, new_skipped            # 300 ms of 0.1 ms steps, less one wake period
        assert 'overrun: skip' in emu.output()
    else:
        assert new_skipped == 0 and new_late >= 2900, (new_skipped, new_late)
