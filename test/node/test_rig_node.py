"""The rig node (`python -m pcv_sim.node.rig`) as a separate process over real DDS.

A small lockstep controller (`pcv_sim.node.client.RigClient`) answers every control period
for both valves. Each test has its own ROS domain and namespace (test/node/conftest.py).
"""
import itertools
import signal
import subprocess
import sys
import time

import pytest

from .conftest import Emulator, _ros_value, clean_child_env, wait_until

VALVES = ('left', 'right')


def start_rig(ros, name='rig', *, params=None, args=()):
    cmd = [sys.executable, '-m', 'pcv_sim.node.rig', '--ros-args', '-r', f'__ns:={ros.ns(name)}']
    for key, value in (params or {}).items():
        cmd += ['-p', f'{key}:={_ros_value(value)}']
    cmd += list(args)
    proc = Emulator(cmd, ros.env, ros.tmp_path / f'{name}-{len(ros.emulators)}.log')
    ros.emulators.append(proc)      # the fixture stops it (SIGINT) and checks exit 0, no traceback
    return proc


def rig_client(ros, name='rig', **kw):
    from pcv_sim.node.client import RigClient

    client = RigClient(ros.ns(name), VALVES, context=ros.context, node_name=f'rig_ctl_{len(ros.clients)}', **kw)
    ros.clients.append(client)
    return client


def controller(t, m):
    """Deterministic, and dependent on what it measured (so a changed sample changes the run):
    left regulates toward 90 bar, right toward 50 bar; the cylinder is pushed toward b (+x)."""
    left = min(max(0.6 + 2e-8 * (90e5 - m['left.pressure']), 0.0), 1.0)
    right = min(max(0.4 + 2e-8 * (50e5 - m['right.pressure']), 0.0), 1.0)
    return {'left': left, 'right': right}


def hogs():
    return [subprocess.Popen([sys.executable, '-c', 'while True: pass'], env=clean_child_env()) for _ in range(2)]


def lockstep_run(ros, name, periods, load=False):
    rig = start_rig(ros, name)
    client = rig_client(ros, name)
    assert client.wait_for_rig(60), rig.output()
    loaders = hogs() if load else []
    try:
        run = client.run(controller, periods, timeout=120)
    finally:
        for h in loaders:
            h.kill()
            h.wait(5)
    assert rig.stop() == 0, rig.output()
    assert 'published again' not in rig.output()       # the premise of bit for bit: no lost command
    client.close()
    ros.clients.remove(client)
    return run


def test_lockstep_repeats_bit_for_bit_under_load_and_the_cylinder_moves_toward_the_lower_pressure(ros):
    quiet = lockstep_run(ros, 'rig', 300)
    loaded = lockstep_run(ros, 'rig', 300, load=True)     # two CPU-bound processes on the 2 cores
    assert [p.stamp_ns for p in quiet] == [k * 1_000_000 for k in range(300)]   # every 1 ms period, in order
    assert [(p.stamp_ns, p.measured, p.duties) for p in quiet] == \
        [(p.stamp_ns, p.measured, p.duties) for p in loaded]                 # == on floats: bit for bit
    last = quiet[-1].measured
    assert last['left.pressure'] > last['right.pressure'] + 20e5
    # Chamber a (left) at the higher pressure pushes the piston toward b: x > 0 and rising.
    assert last['cylinder.position'] > quiet[100].measured['cylinder.position'] > 1e-3
    assert last['cylinder.velocity'] > 0


def test_the_lockstep_channel_runs_bit_for_bit_as_the_topics_under_load_and_the_topics_still_reach_others(ros):
    """One message each way per period (lockstep/sample, lockstep/command) gives the run the
    per-valve topics give, beside two CPU burners; a client subscribed to the per-valve topics
    meanwhile gets every period's samples, the same numbers."""
    topics = lockstep_run(ros, 'rig', 300)
    rig = start_rig(ros, 'chan')
    watcher = rig_client(ros, 'chan')                       # subscribed to the topics; never answers
    client = rig_client(ros, 'chan', channel=True)
    assert client.wait_for_rig(60), rig.output()

    def watched_first_sample():
        watcher.poll()
        return any('joint' in part.values for part in watcher._partial.values())

    # The rig writes a topic to matched readers only: the first sample, published again every 0.5 s
    # while unanswered, tells that the rig has matched the watcher. The copies the channel client
    # then answers again are answers to an earlier sample for the rig: left (else the run would differ).
    assert wait_until(watched_first_sample, 30), rig.output()
    loaders = hogs()
    try:
        channel = client.run(controller, 300, timeout=120)
    finally:
        for h in loaders:
            h.kill()
            h.wait(5)
    assert rig.stop() == 0, rig.output()
    keys = topics[0].measured.keys()
    assert {'left.spool_position', 'cylinder.effort'} < channel[0].measured.keys()      # every signal of the rig
    assert [(p.stamp_ns, {k: p.measured[k] for k in keys}, p.duties) for p in channel] == \
        [(p.stamp_ns, p.measured, p.duties) for p in topics]                           # == on floats: bit for bit
    watcher.poll()
    seen = {s: part.values for s, part in watcher._partial.items() if 'joint' in part.values}
    assert len(seen) >= 290                                  # best effort: a few may be lost under load
    for p in channel:
        if p.stamp_ns in seen:
            assert all(seen[p.stamp_ns][k] == p.measured[k] for k in keys)


def _rig_status(client, predicate, timeout=10.0):
    """The first diagnostics message (from now) whose statuses satisfy predicate."""
    start = len(client.statuses)
    found = []

    def check():
        client.poll()
        found[:] = [d for d in client.statuses[start:] if predicate(d)]
        return bool(found)

    return found[0] if wait_until(check, timeout) else None


def test_a_fault_over_the_topic_acts_and_shows_in_diagnostics_and_clears(ros):
    rig = start_rig(ros, params={'control_period': 0.001, 'faults.enabled': True})
    client = rig_client(ros, currents=True)
    assert client.wait_for_rig(60), rig.output()
    hold = lambda t, m: {'left': 0.6, 'right': 0.6}      # noqa: E731
    client.run(hold, 100, timeout=60)
    i_before = client.currents['left'][-1][1]
    assert i_before > 0.5
    client.send_fault('{fault: coil_opn, valve: left}')            # misspelt: refused, nothing changes
    client.send_fault('{fault: coil_open, valve: left}')
    client.run(hold, 250, timeout=60)                             # 250 ms: many coil time constants
    left = [i for _, i in client.currents['left'][-20:]]
    right = [i for _, i in client.currents['right'][-20:]]
    assert max(abs(i) for i in left) < 0.02 * i_before             # the open coil carries no current
    assert min(right) > 0.9 * i_before                             # the other valve is untouched
    diag = _rig_status(client, lambda d: 'coil_open@left' in d.get(f'{ros.ns("rig")}/rig: inputs', (0, '', {}))[2]
                       .get('faults_active', ''))
    assert diag is not None, rig.output()
    rig_level, rig_message, rig_values = diag[f'{ros.ns("rig")}/rig: inputs']
    assert rig_level == 1 and 'coil_open@left' in rig_message
    assert rig_values['rejected.faults'] == '1'
    left_level, left_message, _ = diag[f'{ros.ns("rig")}/rig: left']
    assert left_level == 1 and 'coil_open@left' in left_message
    assert diag[f'{ros.ns("rig")}/rig: right'][0] == 0
    out = rig.output()
    assert "rejected faults: fault: kind 'coil_opn'; accepted are supply_drop" in out
    assert 'fault coil_open on left' in out
    # every command is logged with the node that sent it
    assert f"fault command '{{fault: coil_open, valve: left}}' from node {ros.ns('rig')}/rig_ctl_0" in out
    client.send_fault('{clear: coil_open, valve: left}')
    client.run(hold, 250, timeout=60)
    assert client.currents['left'][-1][1] == pytest.approx(i_before, rel=0.02)


@pytest.mark.parametrize('params, args, message', [
    ({'control_period': 0.00015}, (), 'control_period 0.00015 s is not a whole multiple of the model step'),
    ({'time_mode': 'fast'}, (), "time_mode: got 'fast'; accepted is one of 'real', 'simulated'"),
    ({'rig_config': '/nonexistent/rig.yaml'}, (), 'cannot read rig file /nonexistent/rig.yaml'),
    ({'contol_period': 0.01}, (), 'unknown parameter(s) contol_period (did you mean control_period?)'),
    ({}, ('--params-file', 'config/rig.yaml'),
     '--params-file config/rig.yaml: a rig YAML (valves, cylinder), not a ROS parameter file; accepted is '
     '-p rig_config:=config/rig.yaml'),
])
def test_invalid_parameters_exit_2_naming_the_parameter(ros, params, args, message):
    rig = start_rig(ros, params=params, args=args)
    assert rig.wait(60) == 2
    out = rig.output()
    assert message in out and 'rig: invalid parameters' in out and 'Traceback' not in out


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM])
def test_real_time_publishes_and_a_signal_stops_it_cleanly(ros, sig):
    rig = start_rig(ros, params={'time_mode': 'real'})
    client = rig_client(ros)
    assert client.wait_for_rig(60), rig.output()
    got = []

    def two_samples():
        client.poll()
        got[:] = [s for s, part in client._partial.items() if 'joint' in part.values]
        return len(got) >= 2

    assert wait_until(two_samples, 30), rig.output()
    time.sleep(0.2)
    assert rig.stop(sig) == 0
    assert 'Traceback' not in rig.output()


def test_real_time_inputs_act_at_the_step_of_their_reception_never_before(ros):
    """The rule of the emulator, on the node itself (in this process; the step an input is given
    is what decides it): the first step stamped at or after the DDS reception, after the last
    sample shown, and two inputs on one valve never at the same step."""
    from rclpy.parameter import Parameter

    from pcv_sim.node.rig import rig_node
    from pcv_sim.simulation.clock import RealTimeSchedule

    node = rig_node(argv=['rig'], context=ros.context, parameter_overrides=[Parameter('time_mode', value='real')])
    try:
        rig = node.device
        node._schedule = sched = RealTimeSchedule(rig.dt)
        sched.start(time.monotonic() - 1.0)            # 1 s of wall time since the start: nothing is "future"
        rig.origin_ns = 1_000_000_000_000
        node._shown = 20                               # the sample at step 20 has been published
        steps = []

        def acted_at(valve, received_ns):
            node.take_input(f'{valve}.duty_cycle', f'{valve}/duty_cycle', 0.7,
                            {'received_timestamp': received_ns})
            steps.append(rig.timing.last(f'{valve}.duty_cycle'))   # the step the one just given acts at

        acted_at('left', rig.origin_ns + 2_345_000)     # received at 2.345 ms: step 24 (2.4 ms), not 23
        acted_at('left', rig.origin_ns + 2_345_000)     # the same instant again: the step after
        acted_at('right', rig.origin_ns + 500_000)      # received before the last sample shown: step 21
        acted_at('right', rig.origin_ns + 3_000_000)    # exactly on step 30
        assert steps == [24, 25, 21, 30]
        rig.advance_to(40)
        assert rig.commands == {'left': 0.7, 'right': 0.7}
    finally:
        node.destroy_node()


def test_free_running_simulated_time_runs_without_a_controller_and_takes_commands(ros):
    rig = start_rig(ros, params={'lockstep': False, 'control_period': 0.01, 'rig.watchdog_timeout': 0.5})
    client = rig_client(ros)
    assert client.wait_for_rig(60), rig.output()
    # the fault topic is off unless faults.enabled: nobody on the domain can break this bench
    assert client.node.count_subscribers(f"{ros.ns('rig')}/faults") == 0
    seen = {}

    def collect():
        client.poll()
        for stamp, part in list(client._partial.items()):
            if 'joint' in part.values and 'left.pressure' in part.values:
                seen[stamp] = part.values['left.pressure']
        return len(seen) >= 50

    assert wait_until(collect, 60), rig.output()
    stamps = sorted(seen)
    assert all(b - a == 10_000_000 for a, b in itertools.pairwise(stamps))   # every 10 ms period, none missing
    from std_msgs.msg import Float64

    sent_after = max(seen)
    before = max(seen.values())          # at the initial duty 0.5 (the watchdog waits for a first command)
    client.duty_pubs['left'].publish(Float64(data=0.9))

    def raised() -> bool:
        # As fast as possible, the rig is ahead of what this client has read by an amount that depends
        # on the load: the command acts at the model time it arrives, so wait for its effect, not for
        # a count of samples after the publish.
        return collect() and any(p > before + 20e5 for t, p in seen.items() if t > sent_after)

    assert wait_until(raised, 60), (before, max(seen.values()), rig.output())   # 0.9 raised the left pressure
    # no controller after the 0.9: the model-time watchdog fires 0.5 s after it took effect (it waited
    # for that first command), which may be after the 100 samples above; the log line follows
    assert wait_until(lambda: 'left: watchdog fired' in rig.output(), 30), rig.output()
    assert 'fault topic off (faults.enabled: false)' in rig.output()
