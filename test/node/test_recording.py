"""Recording from inside the emulator node: the node as a separate process over real DDS.

The bags are read back with three independent readers: rosbags (AnyReader), the `mcap`
package (seeking reader with the summary; stream reader for an unclosed file) and
pcv_sim.io.read_bag. The replay of such a bag is in test/replay/test_emulator_bag.py.
"""
import itertools
import os
import signal

import numpy as np
from mcap.reader import make_reader
from mcap.records import Message
from mcap.stream_reader import StreamReader
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from pcv_sim.io import read_bag
from pcv_sim.io.topics import ROLE_TYPES
from pcv_sim.params import load_params
from pcv_sim.simulation.rest import rest_state

from .conftest import wait_until

PARAMS = load_params()
START = 30.0                      # s: node start-up and discovery on a busy 2-core machine
DT_NS = 100_000
#: Duty steps (fraction, hold in s of wall time) driven over DDS after the start at safe_duty 0.3.
STEPS = [(0.6, 0.25), (0.9, 0.25), (0.45, 0.25), (0.75, 0.2), (0.3, 0.3)]
RECORD = {'safe_duty': 0.3, 'watchdog_timeout': 0.0, 'diagnostics_period': 0.2, 'max_catchup': 10.0,
          'record.enabled': True, 'record.name': 'run', 'record.rate_hz': 10000.0}


def drive(client):
    for duty, hold in STEPS:
        client.send_duty(duty)
        client.spin_for(hold)


def test_recorded_bag_reads_back_with_rosbags_mcap_and_pcv_sim(ros):
    emu = ros.start(params={**RECORD, 'record.directory': str(ros.tmp_path / 'bags')})
    c = ros.client()
    assert c.wait_for_emulator(START), emu.output()
    diag = c.wait_for_diagnostics(lambda d: d.get('recording') == 'recording' and int(d['recording_messages']) > 0)
    assert diag is not None, emu.output()
    bag_path = ros.tmp_path / 'bags' / 'run'
    assert diag['recording_path'] == str(bag_path) and diag['recording_dropped'] == '0'
    assert diag['recording_error'] == '' and int(diag['recording_bytes']) >= 0
    drive(c)
    last_seen = c.samples[-1].stamp_ns
    assert emu.stop(signal.SIGINT) == 0
    out = emu.output()
    assert f'recording finished: bag {bag_path}' in out and 'dropped' not in out and 'Traceback' not in out, out

    ns = ros.ns()
    topics = {f'{ns}/{role}': msgtype for role, msgtype in ROLE_TYPES.items()}
    duties = [0.3] + [d for d, _ in STEPS]

    # rosbags
    typestore = get_typestore(Stores.ROS2_JAZZY)
    with AnyReader([bag_path], default_typestore=typestore) as reader:
        assert {x.topic: x.msgtype for x in reader.connections} == topics
        counts = {x.topic: x.msgcount for x in reader.connections}
        got = {t: [] for t in topics}
        for conn, t, raw in reader.messages():
            got[conn.topic].append((t, reader.deserialize(raw, conn.msgtype)))
    n = counts[f'{ns}/pressure']
    assert n == counts[f'{ns}/current'] == counts[f'{ns}/spool_position'] > 1.2 * 10_000   # > 1.2 s at 10 kHz
    t_p = np.array([t for t, _ in got[f'{ns}/pressure']])
    assert np.all(np.diff(t_p) == DT_NS)                               # every 0.1 ms step, none missing
    assert t_p[-1] >= last_seen                                        # up to the stop
    assert all(m.header.stamp.sec * 10**9 + m.header.stamp.nanosec == t for t, m in got[f'{ns}/pressure'])
    assert all(m.header.frame_id == 'load_port' for _, m in got[f'{ns}/pressure'][:10])
    p = np.array([m.fluid_pressure for _, m in got[f'{ns}/pressure']])
    i = np.array([m.data for _, m in got[f'{ns}/current']])
    x = np.array([m.data for _, m in got[f'{ns}/spool_position']])
    assert p.min() > 5e5 and p.max() < 200e5                           # Pa, between tank and supply
    assert i.min() > 0.0 and i.max() < 2.5                             # A
    assert x.min() >= -0.55e-3 - 1e-12 and x.max() <= 0.85e-3 + 1e-12  # m, within the stroke
    assert abs(p[-1] - rest_state(PARAMS, PARAMS.simulation.model, 0.3).state[3]) < 1e5   # back at rest at 0.3
    duty = got[f'{ns}/duty_cycle']
    assert [m.data for _, m in duty] == duties                          # each change once, the effective duty
    assert duty[0][0] == t_p[0] and all(b[0] > a[0] for a, b in itertools.pairwise(duty))
    assert [m.data for _, m in got[f'{ns}/load_flow']] == [0.0]
    assert [m.fluid_pressure for _, m in got[f'{ns}/supply_pressure']] == [PARAMS.circuit.supply_pressure]

    # mcap: the seeking reader uses the summary section that close() wrote
    [mcap_file] = bag_path.glob('*.mcap')
    with open(mcap_file, 'rb') as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics.message_count == sum(counts.values())
        per_topic = dict.fromkeys(topics, 0)
        last = dict.fromkeys(topics, -1)
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            assert schema.name == topics[channel.topic] and schema.encoding == 'ros2msg'
            assert message.log_time >= last[channel.topic]
            last[channel.topic] = message.log_time
            per_topic[channel.topic] += 1
    assert per_topic == counts

    # pcv_sim
    bag = read_bag(bag_path)
    assert bag.closed_cleanly and bag.warnings == (), bag.warnings
    assert {t: len(s) for t, s in bag.topics.items()} == counts
    assert np.array_equal(bag[f'{ns}/pressure'].value, p)


def test_sigkill_of_the_node_leaves_a_finalized_bag_missing_at_most_the_last_second(ros):
    """The writer process sees the node gone, writes what it had been handed and finalizes the bag."""
    emu = ros.start(params={**RECORD, 'record.directory': str(ros.tmp_path / 'bags')})
    c = ros.client()
    assert c.wait_for_emulator(START), emu.output()
    drive(c)
    c.spin_for(1.0)
    seen = c.samples[-1].stamp_ns                     # a sample the node published just now
    emu.proc.kill()
    emu.wait()
    bag_path = ros.tmp_path / 'bags' / 'run'
    assert wait_until(lambda: read_bag(bag_path).closed_cleanly, 60, 0.2), read_bag(bag_path).warnings

    bag = read_bag(bag_path)
    assert not bag.warnings, bag.warnings
    t_p = bag[f'{ros.ns()}/pressure'].t_ns
    assert len(t_p) > 10_000 and np.all(np.diff(t_p) == DT_NS)
    assert seen - t_p[-1] <= 1_000_000_000, f'lost {(seen - t_p[-1]) / 1e9:.3f} s'

    # the mcap package's stream reader reads the same messages, to the footer
    [mcap_file] = bag_path.glob('*.mcap')
    n = 0
    with open(mcap_file, 'rb') as f:
        for record in StreamReader(f, skip_magic=False).records:
            n += isinstance(record, Message)
    assert n == sum(len(s) for s in bag.topics.values())


def test_a_writer_process_that_dies_is_an_error_in_the_diagnostics_and_the_node_runs_on(ros):
    emu = ros.start(params={**RECORD, 'record.directory': str(ros.tmp_path / 'bags')})
    c = ros.client()
    assert c.wait_for_emulator(START), emu.output()
    assert c.wait_for_diagnostics(lambda d: int(d.get('recording_messages', 0)) > 0) is not None, emu.output()
    [writer] = _children(emu.proc.pid)
    os.kill(writer, signal.SIGKILL)
    diag = c.wait_for_diagnostics(lambda d: d.get('recording') == 'failed')
    assert diag is not None, emu.output()
    assert 'writer process exited unexpectedly' in diag['recording_error'], diag
    n = len(c.samples)
    c.spin_for(0.5)
    assert len(c.samples) > n + 100                    # still publishing
    assert emu.stop(signal.SIGINT) == 0
    out = emu.output()
    assert 'recording failed (the bag writer process exited unexpectedly' in out and 'Traceback' not in out, out


def _children(pid):
    out = []
    for task in os.listdir(f'/proc/{pid}/task'):
        with open(f'/proc/{pid}/task/{task}/children') as f:
            out += [int(p) for p in f.read().split()]
    return out


def test_simulated_time_bag_uses_model_time_and_is_complete(ros):
    emu = ros.start(params={**RECORD, 'time_mode': 'simulated', 'lockstep': False, 'real_time_factor': 0.0,
                            'record.directory': str(ros.tmp_path / 'bags')})
    c = ros.client()
    assert c.wait_for_emulator(START), emu.output()
    c.send_duty(0.7)
    c.spin_for(1.0)
    assert emu.stop(signal.SIGINT) == 0
    out = emu.output()
    assert 'recording finished' in out and 'dropped' not in out, out
    bag = read_bag(ros.tmp_path / 'bags' / 'run')
    assert bag.closed_cleanly, bag.warnings
    ns = ros.ns()
    t_p = bag[f'{ns}/pressure'].t_ns
    assert t_p[0] == 0 and np.all(np.diff(t_p) == DT_NS)             # model time from 0, complete
    assert t_p[-1] < 3600 * 10**9
    assert bag[f'{ns}/duty_cycle'].value.tolist() == [0.3, 0.7]
    assert bag[f'{ns}/duty_cycle'].t_ns[0] == 0


def test_recording_parameters_are_checked_at_start(ros):
    (ros.tmp_path / 'bags' / 'taken').mkdir(parents=True)
    cases = [
        ({'record.signals': '[pressure, torque]'}, "record.signals: record signal 'torque' is not a device signal"),
        ({'record.rate_hz': 3000.0}, 'record.rate_hz 3000: record period 0.000333333 s is not a whole multiple of the model step 0.0001 s'),
        ({'record.name': 'a/b'}, "record.name: got 'a/b'; accepted is ''"),
        ({'record.name': 'taken'}, 'exists already; the recorder never overwrites a bag'),
    ]
    base = {'record.enabled': True, 'record.directory': str(ros.tmp_path / 'bags')}
    procs = [(ros.start(f'bad{k}', params={**base, **params}), message) for k, (params, message) in enumerate(cases)]
    for emu, message in procs:
        rc = emu.wait(60)
        out = emu.output()
        assert rc == 2 and 'emulator: invalid parameters: ' in out and message in out, out
    assert sorted(p.name for p in (ros.tmp_path / 'bags').iterdir()) == ['taken']
