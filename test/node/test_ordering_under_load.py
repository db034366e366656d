"""Ordering promises with two CPU-bound processes beside the node (the normal case here).

An input acts at the first model step at or after its reception, never before, however late
the loop wakes: the bag the node records stamps each duty change at the step it took effect,
and that stamp must not precede the moment the client published the command.
"""
import random
import signal
import time

import numpy as np

from pcv_sim.io.bag import read_bag


def test_commands_never_act_before_they_were_published_under_cpu_load(ros, cpu_load):
    # max_catchup 10 s: a starved node catches up instead of skipping (inputs within a skipped
    # interval would collapse into one change at its end, which this test would count as lost).
    emu = ros.start(params={'safe_duty': 0.3, 'watchdog_timeout': 0.0, 'max_catchup': 10.0, 'record.enabled': True,
                            'record.directory': str(ros.tmp_path), 'record.name': 'order'})
    c = ros.client()
    assert c.wait_for_emulator(60.0), emu.output()
    # Discovery is symmetric only eventually: until the node has matched this publisher, a
    # reliable volatile message is not delivered. Prime with 0.32 until the pressure moves.
    rest = c.samples[-1].pressure
    for _ in range(150):
        c.send_duty(0.32)
        if c.spin_until(lambda: c.samples[-1].pressure > rest + 0.5e5, 0.2):
            break
    else:
        raise AssertionError(f'the emulator never acted on a duty command:\n{emu.output()}')
    rng = random.Random(7)
    sent = []                                   # (system time before publishing, duty)
    for k in range(60):
        duty = round(0.35 + 0.01 * (k % 2) + 0.005 * k, 4)       # every command differs from the last
        sent.append((time.time_ns(), duty))
        c.send_duty(duty)
        c.spin_for(rng.uniform(0.02, 0.08))
    # Stop only once the node's model time has passed the last command (under load it may lag).
    end_ns = sent[-1][0] + 300_000_000
    assert c.spin_until(lambda: c.samples[-1].stamp_ns > end_ns, 60), 'the emulator stopped publishing'
    assert emu.stop(signal.SIGINT) == 0, emu.output()

    duty = read_bag(ros.tmp_path / 'order')[f'{ros.ns()}/duty_cycle']
    assert duty.value.tolist() == [0.3, 0.32] + [d for _, d in sent], 'a command was lost or reordered'
    effect = duty.t_ns[2:]
    before = np.array([t for t, _ in sent])
    early = effect - before
    assert np.all(early >= 0), (
        f'{np.count_nonzero(early < 0)} of {len(sent)} commands took effect before they were published, '
        f'by up to {-early.min() / 1e6:.3f} ms')
