"""The emulator's lockstep channel over real DDS: a controller in this process drives the emulator
node (`python -m pcv_sim.node.emulator`, time_mode simulated, lockstep) in another process, one
`lockstep/sample` and one `lockstep/command` per sample period, beside two CPU-bound processes.

The promise is the rig's (test_rig_node.py): every sample period in order from model time 0, each
answer acting from the step after the sample it answers, so that the run is bit for bit the run of
the same device stepped in this process with the same controller, and the run over the duty topic.
"""

from pcv_sim.device.settings import NodeSettings
from pcv_sim.device.valve import VALVE, ValveDevice
from pcv_sim.params import load_params

PERIODS = 300


def controller(t, m):
    """Deterministic and fed back from what it measured (a changed sample changes every later
    duty): regulates toward 60 bar, the duty kept in 0..1."""
    return {VALVE: min(max(0.5 + 2e-8 * (60e5 - m['pressure']), 0.0), 1.0)}


def in_process(periods):
    """The same device stepped here through the node-facing calls the node makes: each period's
    sample measured, the controller's duty submitted to act from the step after it, the next period run."""
    s = NodeSettings()
    params = load_params(None)
    dev = ValveDevice(params, safe_duty=s.safe_duty, watchdog_timeout=s.watchdog_timeout,
                      sample_every=s.sample_every(params.simulation.time_step), seed=s.seed)
    sample = dev.present_sample()
    out = []
    for _ in range(periods):
        measured = dict(zip(dev.signals, dev.measure(sample).tolist()))
        duty = controller(sample.step * dev.dt, measured)[VALVE]
        out.append((dev.stamp_ns(sample.step), measured, {VALVE: duty}))
        assert dev.submit('duty_cycle', duty, sample.step + 1) is None
        sample = dev.run_to(sample.step + dev.sample_every)[-1]
    return out


def channel_run(ros, name):
    from pcv_sim.node.rig_client import RigClient

    emulator = ros.start(name, params={'time_mode': 'simulated', 'lockstep': True})
    client = RigClient(ros.ns(name), (VALVE,), context=ros.context, node_name=f'lockstep_ctl_{len(ros.clients)}',
                       channel=True)
    ros.clients.append(client)
    assert client.wait_for_rig(60), emulator.output()
    run = client.run(controller, PERIODS, timeout=120)
    assert emulator.stop() == 0, emulator.output()
    assert 'published again' not in emulator.output()     # the premise of bit for bit: no lost command
    return [(p.stamp_ns, p.measured, p.duties) for p in run]


def topic_run(ros, name):
    """The same controller answering each pressure sample on the duty topic (every copy of a sample
    published again answered the same way)."""
    ros.start(name, params={'time_mode': 'simulated', 'lockstep': True})
    answered = {}

    def answer(sample):
        duty = controller(sample.stamp_ns * 1e-9, {'pressure': sample.pressure})[VALVE]
        c.send_duty(duty)
        answered.setdefault(sample.stamp_ns, sample.pressure)

    c = ros.client(name, on_pressure=answer)
    assert c.spin_until(lambda: len(answered) >= PERIODS, 120), f'lockstep stalled after {len(answered)} samples'
    assert ros.emulators[-1].stop() == 0, ros.emulators[-1].output()
    return sorted(answered.items())[:PERIODS]


def test_the_emulators_lockstep_channel_runs_bit_for_bit_as_in_process_and_as_the_duty_topic_under_load(
        ros, cpu_load):
    channel = channel_run(ros, 'chan')
    assert [stamp for stamp, _, _ in channel] == [k * 1_000_000 for k in range(PERIODS)]   # every period, in order
    assert set(channel[0][1]) == {'pressure', 'current', 'spool_position'}                 # the emulator's signals
    assert channel == in_process(PERIODS)                                                  # == on floats: bit for bit
    pressures = [p for _, p in topic_run(ros, 'topic')]
    assert pressures == [m['pressure'] for _, m, _ in channel]
    # The run is a regulation, not a constant: the answers took effect.
    assert channel[-1][1]['pressure'] > channel[1][1]['pressure'] + 5e5
