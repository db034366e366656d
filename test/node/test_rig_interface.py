"""The rig node's interface beside the samples and duty commands, over real DDS (the node a separate
process): recording (record.*), the reset service, cylinder/external_force, use_sim_time.

A lockstep controller (`pcv_sim.node.client.RigClient`) answers every control period; each test
has its own ROS domain and namespace (test/node/conftest.py).
"""
import dataclasses
import itertools
import math
import signal
import time

from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from .conftest import wait_until
from .test_rig_node import _rig_status, rig_client, start_rig

START = 60.0        # s: start-up and discovery on a busy 2-core machine
HOLD = {'left': 0.5, 'right': 0.5}       # the initial duties: the rig stays at rest


def hold(t, m):
    return dict(HOLD)


def steps(t, m):
    """Duty steps on both valves (the piston moves, so the valves see a load flow)."""
    return {'left': 0.7 if 0.05 <= t + 1e-9 < 0.15 else 0.4 if t + 1e-9 >= 0.15 else 0.5,
            'right': 0.3 if t + 1e-9 >= 0.1 else 0.5}


def test_a_lockstep_run_is_recorded_per_valve_namespace_and_one_valve_replays(ros):
    """record.*: the bag holds each valve under its namespace as the emulator records one (inputs
    stamped at the step they act, outputs at their sample time: the very samples the controller got),
    the cylinder, the fault commands and events; SIGINT finalises it; `left` replays with a good fit."""
    from pcv_sim.params import load_params
    from pcv_sim.replay import load_recording, replay
    from pcv_sim.rig import load_rig

    bags = ros.tmp_path / 'bags'
    rig = start_rig(ros, params={'record.enabled': True, 'record.directory': str(bags), 'record.name': 'run',
                                 'faults.enabled': True})
    client = rig_client(ros)
    assert client.wait_for_rig(START), rig.output()
    periods = client.run(steps, 200, timeout=120)
    client.send_fault('{fault: bias, signal: right.pressure, value: 1.0e+5}')
    periods += client.run(steps, 100, timeout=120)
    assert rig.stop(signal.SIGINT) == 0
    out = rig.output()
    bag = bags / 'run'
    assert f'recording finished: bag {bag}' in out and 'dropped' not in out and 'Traceback' not in out, out

    ns = ros.ns('rig')
    with AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        got = {t: [] for t in types}
        for conn, t, raw in reader.messages():
            got[conn.topic].append((t, reader.deserialize(raw, conn.msgtype)))
    for v in ('left', 'right'):
        assert {t: types[t] for t in types if t.startswith(f'{ns}/{v}/')} == {
            f'{ns}/{v}/duty_cycle': 'std_msgs/msg/Float64', f'{ns}/{v}/load_flow': 'std_msgs/msg/Float64',
            f'{ns}/{v}/supply_pressure': 'sensor_msgs/msg/FluidPressure',
            f'{ns}/{v}/pressure': 'sensor_msgs/msg/FluidPressure', f'{ns}/{v}/current': 'std_msgs/msg/Float64',
            f'{ns}/{v}/spool_position': 'std_msgs/msg/Float64'}
    assert types[f'{ns}/cylinder/joint_states'] == 'sensor_msgs/msg/JointState'
    assert types[f'{ns}/faults'] == types[f'{ns}/rig/events'] == 'std_msgs/msg/String'

    # Outputs: every sample the controller answered, at its stamp, the same values (measured: the
    # bias on right.pressure is in both).
    for v in ('left', 'right'):
        rec = {t: m for t, m in got[f'{ns}/{v}/pressure']}
        assert all(m.header.stamp.sec * 10**9 + m.header.stamp.nanosec == t for t, m in rec.items())
        assert [rec[p.stamp_ns].fluid_pressure for p in periods] == [p.measured[f'{v}.pressure'] for p in periods]
    joint = {t: m for t, m in got[f'{ns}/cylinder/joint_states']}
    assert [joint[p.stamp_ns].position[0] for p in periods] == [p.measured['cylinder.position'] for p in periods]
    assert periods[-1].measured['cylinder.position'] > 1e-3                     # it moved
    # Inputs on change, stamped at the step they act: lockstep applies the answer to the sample at T
    # at T + dt, the first step not shown (the sample at T shows the inputs in force at T).
    dt_ns = 100_000
    first = {d: next(p.stamp_ns for p in periods if p.duties['left'] == d) for d in (0.7, 0.4)}
    assert [(t, m.data) for t, m in got[f'{ns}/left/duty_cycle']] == [(0, 0.5), (first[0.7] + dt_ns, 0.7),
                                                                      (first[0.4] + dt_ns, 0.4)]
    assert [m.fluid_pressure for _, m in got[f'{ns}/left/supply_pressure']] == [200e5]
    [(t_fault, fault)] = got[f'{ns}/faults']
    assert fault.data == '{fault: bias, signal: right.pressure, value: 1.0e+5}' and (t_fault - dt_ns) % 1_000_000 == 0
    assert any(m.data.startswith('fault bias on right.pressure') and t == t_fault for t, m in got[f'{ns}/rig/events'])

    rig_params = load_rig()
    c = rig_params.cylinder
    params = load_params()
    chamber_a = c.dead_volume_a + c.hose_volume_a + c.area_a * (c.initial_position - c.stroke_min)
    params = dataclasses.replace(params, circuit=dataclasses.replace(params.circuit, load_volume=chamber_a))
    result = replay(load_recording(bag, namespace='left'), params, model='simplified')
    fit = result.scalar_metrics()
    assert fit['pressure_fit_percent'] > 97 and fit['spool_position_fit_percent'] > 95, fit
    # The current jumps with the duty (R27): with answers acting at T (before the fix) the sample at
    # T showed the old duty's current while the bag had the new duty from T: 96 % fit; now 99.9 %.
    assert fit['current_fit_percent'] > 99, fit


def test_external_force_moves_the_piston_and_reset_brings_the_rig_back_to_rest(ros):
    """cylinder/external_force (N, + extending; refused ones counted and logged, the last valid one
    stays) pushes the piston; `reset` puts valves, piston, inputs and faults back to the start with
    time going on: the periods after it are a fresh run's, bit for bit, 1 reset later."""
    rig = start_rig(ros, params={'diagnostics_period': 0.2, 'faults.enabled': True})
    client = rig_client(ros)
    assert client.wait_for_rig(START), rig.output()
    fresh = client.run(hold, 30, timeout=120)
    assert abs(fresh[-1].measured['cylinder.position']) < 1e-6                 # at rest: it stays
    client.send_external_force(5000.0)
    client.send_external_force(math.nan)
    client.send_external_force(2e6)
    client.send_fault('{fault: coil_open, valve: right}')
    pushed = client.run(hold, 100, timeout=120)
    assert pushed[-1].measured['cylinder.position'] > 5e-3                     # 5 kN extends it
    assert pushed[-1].measured['cylinder.velocity'] > 0
    diag = _rig_status(client, lambda d: d.get(f'{ros.ns("rig")}/rig: inputs', (0, '', {}))[2]
                       .get('rejected.external_force') == '2')
    assert diag is not None, rig.output()
    values = diag[f'{ros.ns("rig")}/rig: inputs'][2]
    assert values['external_force_n'] == '5000' and values['accepted.external_force'] == '1'
    assert 'coil_open@right' in values['faults_active']
    assert ('rejected cylinder/external_force: external force nan: accepted is a finite number of N within '
            '+-1e+06 N; the last valid value stays in force') in rig.output()

    t_reset = client.periods[-1].stamp_ns + 1_000_000           # the sample the rig now waits at
    response = client.reset()
    assert response.success and 'model time goes on' in response.message, response.message
    after = client.run(hold, len(fresh), timeout=120)
    assert after[0].stamp_ns == t_reset                         # shown before the reset: still pushed
    assert after[0].measured['cylinder.position'] > 5e-3
    shifted = [(p.stamp_ns - t_reset, p.measured) for p in after[1:]]
    assert shifted == [(p.stamp_ns, p.measured) for p in fresh[1:]]            # == on floats: bit for bit
    diag = _rig_status(client, lambda d: d.get(f'{ros.ns("rig")}/rig: model', (0, '', {}))[2].get('resets') == '1')
    assert diag is not None, rig.output()
    level, _, values = diag[f'{ros.ns("rig")}/rig: inputs']
    assert values['faults_active'] == '' and values['external_force_n'] == '0' and level == 0
    assert diag[f'{ros.ns("rig")}/rig: model'][0] == 0
    assert 'reset: valves at rest at their initial duty' in rig.output()


def test_use_sim_time_follows_an_external_clock_and_simulated_time_with_it_is_refused(ros):
    """As the emulator: with time_mode real and use_sim_time the rig's model time follows /clock
    (stamps are that clock, on the control period's grid, never ahead of it; it stands still with
    the clock); with time_mode simulated it is refused (exit 2) saying what is accepted. Recorded
    in this mode too: SIGTERM finalises the bag (read back with the `mcap` package)."""
    from mcap.reader import make_reader
    from rosgraph_msgs.msg import Clock

    refused = start_rig(ros, 'both', params={'use_sim_time': True})              # time_mode simulated
    rig = start_rig(ros, params={'time_mode': 'real', 'use_sim_time': True, 'diagnostics_period': 0.2,
                                 'record.enabled': True, 'record.directory': str(ros.tmp_path)})
    client = rig_client(ros)
    pub = client.node.create_publisher(Clock, '/clock', 10)
    assert wait_until(lambda: pub.get_subscription_count() > 0, START), rig.output()
    t0 = 1000 * 10**9

    def tick(k):
        msg = Clock()
        msg.clock.sec, msg.clock.nanosec = divmod(t0 + k * 500_000, 10**9)       # 0.5 ms per tick
        pub.publish(msg)

    seen = {}

    def collect():
        client.poll()
        for stamp, part in list(client._partial.items()):
            if 'joint' in part.values:
                seen[stamp] = part.values['cylinder.position']
        return seen

    k = 0
    while not collect() and k < 10000:
        tick(k)
        k += 1
        time.sleep(0.002)
    assert seen, rig.output()
    for _ in range(200):                               # 100 ms of simulated time, at any wall pace
        tick(k)
        k += 1
        time.sleep(0.002)
    last_clock = t0 + (k - 1) * 500_000
    assert wait_until(lambda: max(collect()) >= last_clock - 1_000_000, 10), (max(seen), last_clock)
    stamps = sorted(seen)
    assert t0 <= stamps[0] and stamps[-1] <= last_clock
    assert all((s - stamps[0]) % 1_000_000 == 0 for s in stamps)              # the 1 ms control period
    n = len(seen)
    time.sleep(0.3)                                    # the clock stands still: so does the model
    assert len(collect()) == n
    diag = _rig_status(client, lambda d: d.get(f'{ros.ns("rig")}/rig: timing', (0, '', {}))[2]
                       .get('time_mode') == 'external_clock')
    assert diag is not None, rig.output()
    assert diag[f'{ros.ns("rig")}/rig: recording'][2]['recording'] == 'recording'
    assert rig.stop(signal.SIGTERM) == 0
    [bag] = ros.tmp_path.glob('rig_pcv*')                   # rig_<namespace>_<date>: the default name
    [mcap_file] = bag.glob('*.mcap')
    with open(mcap_file, 'rb') as f:
        recorded = sorted(m.log_time for _, channel, m in make_reader(f).iter_messages()
                          if channel.topic == f'{ros.ns("rig")}/cylinder/joint_states')
    assert set(stamps) <= set(recorded) and recorded[0] <= stamps[0] and recorded[-1] >= stamps[-1]
    assert all(b - a == 1_000_000 for a, b in itertools.pairwise(recorded))      # none lost in the bag
    assert refused.wait(START) == 2
    out = refused.output()
    assert ('use_sim_time: true follows another node\'s /clock, time_mode: simulated publishes /clock itself; '
            'accepted is one of them: use_sim_time with time_mode real') in out and 'Traceback' not in out


def test_real_time_reset_acts_at_an_inputs_step_and_a_real_time_run_is_recorded(ros):
    """In this process (the step a request is given is what decides it): in real time the reset acts
    at the step an input received now would, after the inputs before it, before those after it;
    a real-time run with record.enabled writes every control period's sample, finalised at the stop;
    use_sim_time cannot be switched at run time."""

    from rclpy.parameter import Parameter
    from std_srvs.srv import Trigger

    from pcv_sim.io import read_bag
    from pcv_sim.node.rig import rig_node
    from pcv_sim.simulation.clock import RealTimeSchedule

    node = rig_node(argv=['rig'], context=ros.context, parameter_overrides=[
        Parameter('time_mode', value='real'), Parameter('record.enabled', value=True),
        Parameter('record.directory', value=str(ros.tmp_path)), Parameter('record.name', value='rt')])
    ns = node.get_namespace().rstrip('/')
    try:
        rig = node.device
        assert not node.set_parameters([Parameter('use_sim_time', value=True)])[0].successful
        node._schedule = sched = RealTimeSchedule(rig.dt)
        sched.start(time.monotonic() - 0.0024)          # 2.4 ms of wall time since the start
        node._shown = 20
        node.take_input('left.duty_cycle', 'left/duty_cycle', 0.8, {'received_timestamp': 1})   # long ago: at step 21
        response = node._on_reset(Trigger.Request(), Trigger.Response())    # the worker's part: prepared
        for install in node._ready:                      # the loop's: at the step an input received now acts at
            install()
        node._ready.clear()
        reset_at = rig.timing.last('reset')
        assert reset_at >= 24                            # not before its reception (~2.4 ms)
        node.take_input('cylinder.external_force', 'cylinder/external_force', 300.0,
                        {'received_timestamp': 10**12})                               # after it: it stays
        assert not response.message and node._hold == []       # the answer waits until the reset acted
        rig.advance_to(reset_at + 10)
        assert node._hold == [True] and response.success and 'model time goes on' in response.message
        assert rig.commands['left'] == 0.5 and rig.input_values()['cylinder.external_force'] == 300.0
        assert 'reset' in rig.log[-1][1] and node.resets == 1
        rig.reset()
        node._schedule = None

        class Stop:
            """0.5 s of the real-time loop, counted from its schedule's start: the set-up before it (a
            full garbage collection of this test process's heap, which a long session makes large)
            is not the run's, and a timer started before run() charged it to the run."""
            started: float | None = None

            @property
            def requested(self) -> bool:
                if node._schedule is None:
                    return False
                if self.started is None:
                    self.started = time.monotonic()
                return time.monotonic() - self.started > 0.5

        node.run(Stop())                                 # 0.5 s of real time, then the bag is closed
    finally:
        node.destroy_node()
    bag = read_bag(ros.tmp_path / 'rt')
    assert bag.closed_cleanly
    t = bag[f'{ns}/left/pressure'].t_ns
    t = t - t[0]
    # On the 1 ms grid, in order; how many depends on the load (a backlog beyond max_catchup is skipped)
    assert len(t) > 20 and all(x % 1_000_000 == 0 for x in t) and all(b > a for a, b in itertools.pairwise(t))
    assert bag.topic_types[f'{ns}/cylinder/joint_states'] == 'sensor_msgs/msg/JointState'


def test_the_rig_takes_run_time_parameter_changes_with_the_emulators_refusals(ros):
    """The parameters the rig is not built on change while it runs; the rest is refused with the
    emulator's reasons (one node base): read-only, a bad value, an unknown name (named, with the close
    one), use_sim_time; a numeric text for a float (`ros2 param set` sends 2e-1 so) is the number."""
    from pcv_sim.node.client import EmulatorClient

    rig = start_rig(ros, params={'lockstep': False, 'control_period': 0.01})
    c = EmulatorClient(ros.ns('rig'), context=ros.context, node_name='rig_params', emulator_node='rig', outputs=())
    ros.clients.append(c)
    cases = {
        'diagnostics_period': ('2e-1', None),
        'real_time_factor': (4.0, None),
        'reject_log_period': (-1.0, 'reject_log_period: got -1.0; accepted is a finite number >= 0'),
        'max_catchup': (1e-4, 'max_catchup: got 0.0001; accepted is a number >= wake_period'),
        'seed': (3, 'read-only'),
        'diagnostics_perod': (1.0, 'unknown parameter(s) diagnostics_perod (did you mean diagnostics_period?)'),
        'use_sim_time': (True, 'use_sim_time is fixed while the node runs'),
    }
    results = c.set_parameters({k: v for k, (v, _) in cases.items()}, timeout=START)
    for (name, (_, reason)), result in zip(cases.items(), results):
        assert result.successful == (reason is None), (name, result.reason)
        assert reason is None or reason in result.reason, (name, result.reason)
    assert wait_until(lambda: "parameters changed: diagnostics_period = 0.2" in rig.output(), 10), rig.output()
    assert "parameters changed: real_time_factor = 4.0" in rig.output()


def test_the_rigs_watchdog_and_safe_duty_are_parameters_at_start_and_at_run_time(ros):
    """rig.watchdog_timeout and rig.safe_duty (default: the rig YAML's) replace the YAML's when given
    at start and act from the present step when set at run time, as the emulator's watchdog_timeout
    and safe_duty; before a first command each valve's watchdog is waiting (it cannot fire); a safe
    duty no valve takes and a rig key the rig is built on are refused, named."""
    from rcl_interfaces.srv import DescribeParameters
    from std_msgs.msg import Float64

    from pcv_sim.node.client import EmulatorClient

    ns = ros.ns('rig')
    rig = start_rig(ros, params={'lockstep': False, 'control_period': 0.01, 'rig.watchdog_timeout': 0.2,
                                 'diagnostics_period': 0.2})
    client = rig_client(ros)
    c = EmulatorClient(ns, context=ros.context, node_name='rig_watchdog', emulator_node='rig', outputs=())
    ros.clients.append(c)
    assert client.wait_for_rig(START), rig.output()
    assert wait_until(lambda: 'watchdog 0.2 s' in rig.output(), 10), rig.output()
    diag = _rig_status(client, lambda d: d.get(f'{ns}/rig: left', (0, '', {}))[2].get('watchdog') == 'waiting')
    assert diag is not None, rig.output()
    assert 'watchdog fired' not in rig.output()              # 0.2 s passed long ago: no command, no firing
    request = DescribeParameters.Request(names=['rig.watchdog_timeout'])
    (described,) = c.call(DescribeParameters, f'{c.device_name}/describe_parameters', request, START).descriptors
    assert '; accepted 0 .. 60 [s] (default: the rig YAML' in described.description   # every device's declaration
    refused = c.set_parameters({'rig.safe_duty': 7.0, 'rig.time_step': 1e-5}, timeout=START)
    assert not refused[0].successful and 'rig.safe_duty: got 7.0; accepted is a duty fraction 0..1' in refused[0].reason
    assert not refused[1].successful and 'unknown parameter(s) rig.time_step' in refused[1].reason
    ok = c.set_parameters({'rig.safe_duty': 0.25, 'rig.watchdog_timeout': 0.3}, timeout=START)
    assert all(r.successful for r in ok), [r.reason for r in ok]
    assert wait_until(lambda: 'watchdog 0.3 s (0 = off) -> duty 0.25' in rig.output(), 10), rig.output()
    client.duty_pubs['left'].publish(Float64(data=0.9))     # one command, then none: fires 0.3 s later
    assert wait_until(lambda: 'left: watchdog fired, duty -> 0.25' in rig.output(), 30), rig.output()
    assert 'no valid left/duty_cycle command for 0.3 s' in rig.output()
    diag = _rig_status(client, lambda d: d.get(f'{ns}/rig: left', (0, '', {}))[2].get('watchdog') == 'fired')
    assert diag is not None and diag[f'{ns}/rig: right'][2]['watchdog'] == 'waiting', rig.output()
