"""The emulator's lockstep channel over real DDS: a controller in this process drives the emulator
node (`python -m pcv_sim.node.emulator`, time_mode simulated, lockstep) in another process, one
`lockstep/sample` and one `lockstep/command` per sample period, beside two CPU-bound processes.

The promise is the rig's (test_rig_node.py): every sample period in order from model time 0, each
answer acting from the step after the sample it answers, so that the run is bit for bit the run of
the same device stepped in this process with the same controller, and the run over the duty topic. The controller is the one client's lockstep
(`pcv_sim.node.client.DeviceClient.run`), the rig's.
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


def lockstep_run(ros, name, channel):
    """The controller run by the one client's lockstep (`DeviceClient.run`, the rig's), on the
    lockstep channel or on the emulator's topics (its `pressure` completes a period)."""
    from pcv_sim.node.client import DeviceClient

    emulator = ros.start(name, params={'time_mode': 'simulated', 'lockstep': True})
    client = DeviceClient(ros.ns(name), context=ros.context, node_name=f'lockstep_ctl_{len(ros.clients)}',
                          lockstep=True, channel=channel)
    ros.clients.append(client)
    assert client.wait_for_device(60), emulator.output()
    run = client.run(controller, PERIODS, timeout=120)
    assert emulator.stop() == 0, emulator.output()
    assert 'published again' not in emulator.output()     # the premise of bit for bit: no lost command
    return [(p.stamp_ns, p.measured, p.duties) for p in run]


def test_the_emulators_lockstep_channel_runs_bit_for_bit_as_in_process_and_as_the_duty_topic_under_load(
        ros, cpu_load):
    channel = lockstep_run(ros, 'chan', channel=True)
    assert [stamp for stamp, _, _ in channel] == [k * 1_000_000 for k in range(PERIODS)]   # every period, in order
    assert set(channel[0][1]) == {'pressure', 'current', 'spool_position'}                 # the emulator's signals
    assert channel == in_process(PERIODS)                                                  # == on floats: bit for bit
    topics = lockstep_run(ros, 'topic', channel=False)
    assert [(stamp, m['pressure'], d) for stamp, m, d in topics] == \
        [(stamp, m['pressure'], d) for stamp, m, d in channel]
    # The run is a regulation, not a constant: the answers took effect.
    assert channel[-1][1]['pressure'] > channel[1][1]['pressure'] + 5e5
