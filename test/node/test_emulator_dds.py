"""The emulator node as a separate process over real DDS, driven by a test client node."""
import itertools
import math
import signal

from offline_valve import advance, at_rest, now, put

from pcv_sim.params import load_params
from pcv_sim.simulation.rest import rest_state

PARAMS = load_params()
DT_NS = 100_000
SAMPLE_EVERY = 10                 # 1 kHz samples, 0.1 ms steps
START = 30.0                      # s: node start-up and discovery on a busy 2-core machine


def rest_pressure(duty):
    return rest_state(PARAMS, PARAMS.simulation.model, duty).state[3]


def latest(client, key):
    return client.diagnostics[-1][key] if client.diagnostics else None


# --- real time: step response ----------------------------------------------------------------

def test_duty_step_follows_the_offline_model_from_the_reception_step(ros):
    """The published pressure is the model's: the node's samples equal an offline run of
    the emulator's device that applies the duty at the step the node reports (`duty_applied_stamp_ns`).

    Tolerance 1 Pa (1e-5 bar, against a 46 bar step): the two runs do the same arithmetic; they
    may differ only through the warm start of the coil-current Newton solve (reads of `current`)."""
    # max_catchup 10 s: even a badly starved run catches up (late) instead of skipping steps.
    ros.start(params={'safe_duty': 0.3, 'watchdog_timeout': 0.0, 'diagnostics_period': 0.2, 'max_catchup': 10.0})
    c = ros.client()
    assert c.wait_for_emulator(START), 'no samples from the emulator'
    c.spin_for(0.1)
    c.send_duty(0.7)
    sent_ns = c.duty_sent[-1][1]
    diag = c.wait_for_diagnostics(lambda d: d['duty_applied_stamp_ns'] != '', timeout=10)
    assert diag is not None, 'the emulator never reported the duty step'
    applied = int(diag['duty_applied_stamp_ns'])
    origin = int(diag['model_time_origin_ns'])
    assert c.spin_until(lambda: c.samples[-1].stamp_ns > applied + 150_000_000, 10)

    # Causal, and prompt: the command acts from the first step stamped at/after its reception.
    assert sent_ns - 1_000_000 <= applied <= sent_ns + 50_000_000, (sent_ns, applied)
    k_applied = (applied - origin) // DT_NS
    assert origin + k_applied * DT_NS == applied

    samples = {s.stamp_ns: s.pressure for s in c.samples}
    last = (c.samples[-1].stamp_ns - origin) // DT_NS
    ref = at_rest(PARAMS, 0.3)
    now(ref)
    now(ref)                                    # the node reads i at step 0 twice (state, first sample)
    compared, worst = 0, 0.0
    for k in range(0, last + 1, SAMPLE_EVERY):
        if k > 0:
            if k - SAMPLE_EVERY < k_applied <= k:
                advance(ref, k_applied - (k - SAMPLE_EVERY))
                put(ref, "duty_cycle", 0.7)
                advance(ref, k - k_applied)
            else:
                advance(ref, SAMPLE_EVERY)
            now(ref)
        stamp = origin + k * DT_NS
        if stamp in samples and k >= k_applied - 200:
            worst = max(worst, abs(samples[stamp] - float(ref.sim.x[3])))
            compared += 1
    assert compared >= 100, f'only {compared} samples around the step arrived'
    assert worst <= 1.0, f'published pressure deviates from the offline model by {worst} Pa'
    assert float(ref.sim.x[3]) > rest_pressure(0.3) + 40e5       # it was a real step (~46 bar)


# --- bad input --------------------------------------------------------------------------------

def test_bad_inputs_are_rejected_and_counted_while_publishing_continues(ros):
    emu = ros.start(params={'safe_duty': 0.3, 'watchdog_timeout': 0.0, 'diagnostics_period': 0.2})
    c = ros.client()
    assert c.wait_for_emulator(START)
    c.send_duty(0.5)
    assert c.wait_for_diagnostics(lambda d: d['accepted.duty_cycle'] == '1', 10)
    n_before = len(c.samples)
    for bad in (70.0, math.nan, -0.2, math.inf):
        c.send_duty(bad)
    c.send_load_flow(math.nan)
    c.send_load_flow(1.0)                        # 60000 L/min: not a plant any rig could produce
    c.send_supply_pressure(-5.0)
    c.send_supply_pressure(2.0e9)                # 20000 bar
    diag = c.wait_for_diagnostics(
        lambda d: (d['rejected.duty_cycle'], d['rejected.load_flow'], d['rejected.supply_pressure']) == ('4', '2', '2'),
        10)
    assert diag is not None, c.diagnostics[-1:]
    assert diag['duty_command'] == '0.5'                    # the last valid command stays
    assert diag['model'] == 'ok'
    assert 'rejected inputs' in ' '.join(c.diagnostic_messages)
    assert c.spin_until(lambda: len(c.samples) > n_before + 300, 10), 'publishing stopped'
    stamps = [s.stamp_ns for s in c.samples[n_before:]]
    assert all(b > a for a, b in itertools.pairwise(stamps))
    log = emu.output()
    assert 'rejected duty_cycle: duty cycle 70 > 1: the command is a fraction 0..1, not percent' in log
    assert 'rejected load_flow' in log and 'rejected supply_pressure' in log
    # Throttled: 4 bad duty commands within a second give one log line for that topic.
    assert log.count('rejected duty_cycle') == 1


# --- watchdog ---------------------------------------------------------------------------------

def test_watchdog_fires_and_recovers(ros):
    emu = ros.start(params={'safe_duty': 0.3, 'watchdog_timeout': 0.25, 'diagnostics_period': 0.1})
    c = ros.client()
    assert c.wait_for_emulator(START)
    assert c.wait_for_diagnostics(lambda d: d['watchdog'] == 'waiting', 10)
    for _ in range(10):                           # a controller at 50 Hz, for 0.2 s
        c.send_duty(0.7)
        c.spin_for(0.02)
    assert c.wait_for_diagnostics(lambda d: d['watchdog'] == 'ok', 10)
    fired = c.wait_for_diagnostics(lambda d: d['watchdog'] == 'fired', 10)
    assert fired is not None
    # In model time, exactly watchdog_timeout after the last command took effect.
    assert int(fired['watchdog_fired_stamp_ns']) - int(fired['duty_applied_stamp_ns']) == 250_000_000
    assert fired['duty_command'] == '0.3'
    assert 'watchdog' in c.diagnostic_messages[-1]
    level, message = c.diagnostic_statuses[-1]['inputs']        # its own status: inputs, WARN
    assert level == 1 and 'watchdog' in message and c.diagnostic_statuses[-1]['model'][0] == 0
    p_rest = rest_pressure(0.3)
    assert c.spin_until(lambda: abs(c.samples[-1].pressure - p_rest) < 0.5e5, 10), 'not back to the safe duty'
    c.send_duty(0.6)
    resumed = c.wait_for_diagnostics(lambda d: d['watchdog'] == 'ok', 10)
    assert resumed is not None and resumed['duty_command'] == '0.6'
    assert c.spin_until(lambda: c.samples[-1].pressure > p_rest + 20e5, 10)
    # One log line per firing, saying what happened and what to do (not one per step).
    log = emu.output()
    assert log.count('watchdog: no valid duty_cycle command for 0.25 s') == 1, log
    assert 'ros2 topic pub -r 10 duty_cycle' in log and 'watchdog: duty commands resumed, duty 0.6' in log


# --- two instances ------------------------------------------------------------------------------

def test_two_namespaced_instances_run_side_by_side_without_crosstalk(ros):
    params = {'safe_duty': 0.3, 'watchdog_timeout': 0.0, 'diagnostics_period': 0.2}
    ros.start('left', params=params)
    ros.start('right', params=params)
    left, right = ros.client('left'), ros.client('right')
    assert left.wait_for_emulator(START) and right.wait_for_emulator(START)
    left.send_duty(0.7)
    p_rest = rest_pressure(0.3)
    assert left.spin_until(lambda: left.samples[-1].pressure > p_rest + 40e5, 10)
    right.spin_for(0.3)
    assert all(abs(s.pressure - p_rest) < 1.0 for s in right.samples)      # untouched, at rest
    # A diagnostics message built before the command may still be queued behind 1 kHz samples: wait
    # for the left one that counts it; the right one must never count anything.
    dl = left.wait_for_diagnostics(lambda d: d['accepted.duty_cycle'] == '1', timeout=10)
    dr = right.wait_for_diagnostics(timeout=10)
    assert dl is not None and dr['accepted.duty_cycle'] == '0'
    assert all(d['accepted.duty_cycle'] == '0' for d in right.diagnostics)
    assert left.emulator_name.endswith('/left/emulator') and right.emulator_name.endswith('/right/emulator')


# --- simulated time ---------------------------------------------------------------------------

def _duty_at(t_ns):
    """The scripted controller: its command for the sample stamped t_ns."""
    return 0.3 if t_ns < 20_000_000 else (0.7 if t_ns < 100_000_000 else 0.45)


def _simulated_run(ros, name, n_samples=200):
    ros.start(name, params={'time_mode': 'simulated', 'lockstep': True, 'watchdog_timeout': 0.0,
                            'safe_duty': 0.3})
    answered = {}

    def answer(sample):                       # answer every sample (also a re-sent one) once
        c.send_duty(_duty_at(sample.stamp_ns))
        answered.setdefault(sample.stamp_ns, sample.pressure)

    c = ros.client(name, on_pressure=answer)
    assert c.spin_until(lambda: len(answered) > n_samples, 60), f'lockstep stalled after {len(answered)} samples'
    assert ros.emulators[-1].stop() == 0            # one /clock at a time (a second one is refused)
    return sorted(answered.items())[:n_samples + 1]


def test_simulated_time_is_deterministic_and_follows_the_lockstep_semantics(ros):
    first = _simulated_run(ros, 'run1')
    second = _simulated_run(ros, 'run2')
    assert first == second                           # bit for bit, stamps and values
    assert [t for t, _ in first] == [k * 1_000_000 for k in range(len(first))]   # model time from 0
    # Semantics: the command answering the sample at T acts from the next step, T + 0.1 ms (the
    # sample at T showed the inputs in force at T).
    ref = at_rest(PARAMS, 0.3)
    now(ref)
    now(ref)
    expected = [(0, float(ref.sim.x[3]))]
    for k in range(1, len(first)):
        advance(ref, 1)
        put(ref, "duty_cycle", _duty_at((k - 1) * 1_000_000))
        advance(ref, SAMPLE_EVERY - 1)
        now(ref)
        expected.append((k * 1_000_000, float(ref.sim.x[3])))
    assert max(abs(a[1] - b[1]) for a, b in zip(first, expected)) <= 1.0


def test_simulated_time_publishes_clock(ros):
    from rosgraph_msgs.msg import Clock

    ros.start(params={'time_mode': 'simulated', 'lockstep': False, 'real_time_factor': 2.0})
    c = ros.client()
    clocks = []
    c.node.create_subscription(Clock, '/clock', lambda m: clocks.append(m.clock.sec * 10**9 + m.clock.nanosec), 10)
    assert c.spin_until(lambda: len(clocks) > 300, START)
    assert all(b > a for a, b in itertools.pairwise(clocks))
    assert c.samples and c.samples[-1].stamp_ns % 1_000_000 == 0
    assert c.samples[-1].stamp_ns < 3600 * 10**9                  # simulated epoch from 0, not wall time
    assert clocks[-1] < 3600 * 10**9


# --- parameters -------------------------------------------------------------------------------

INVALID_AT_START = [
    ({'model.spool.mass': -1.0}, 'model.spool.mass: got -1.0; accepted is a plausible value 0.001 .. 1 (kg)'),
    ({'publish_rate': 3.0}, 'is not a whole multiple of the model step'),
    ({'time_mode': 'wall'}, "time_mode: got 'wall'; accepted is one of 'real', 'simulated'"),
    ({'model.spool.mas': 1.0}, 'unknown parameter(s) model.spool.mas (did you mean model.spool.mass?)'),
    ({'watchdog_timout': 1.0}, 'unknown parameter(s) watchdog_timout (did you mean watchdog_timeout?)'),
    ({'valve_config': '/nonexistent/valve.yaml'}, 'cannot read parameter file /nonexistent/valve.yaml'),
    ({'safe_duty': 70.0}, 'safe_duty: got 70.0; accepted is a duty fraction 0..1'),
]


def test_invalid_parameters_are_refused_at_start(ros):
    procs = [(ros.start(f'bad{k}', params=params), message) for k, (params, message) in enumerate(INVALID_AT_START)]
    for emu, message in procs:
        rc = emu.wait(60)
        out = emu.output()
        assert rc == 2, f'{emu.cmd}: exit {rc}\n{out}'
        assert 'emulator: invalid parameters: ' in out and message in out, out
        assert 'Traceback' not in out
        # also through the node's logger, i.e. to /rosout as well as stderr
        assert any('[ERROR]' in line and 'invalid parameters: ' in line and message in line
                   for line in out.splitlines()), out


def test_invalid_parameters_are_refused_at_runtime_with_the_reason(ros):
    ros.start(params={'safe_duty': 0.3, 'diagnostics_period': 0.2})
    c = ros.client()
    assert c.wait_for_emulator(START)
    cases = {
        'model.spool.mass': (-1.0, 'model.spool.mass: got -1.0; accepted is a plausible value 0.001 .. 1 (kg)'),
        'publish_rate': (3.0, 'not a whole multiple of the model step'),
        'model.simulation.time_step': (5e-5, 'fixed while the node runs'),
        'time_mode': ('simulated', 'read-only'),
        'watchdog_timeout': (-0.5, 'watchdog_timeout: got -0.5; accepted is a duration in 0 .. 60 (s)'),
        'model.calibration.net_area': (1.0, 'calibration.net_area'),
        'model.nosuch.key': (1.0, 'unknown parameter(s) model.nosuch.key; accepted are'),
        'use_sim_time': (True, 'use_sim_time is fixed while the node runs'),
        'max_catchup': ('fast', "max_catchup: got 'fast' (str)"),         # text that is no number stays refused
    }
    results = c.set_parameters({k: v for k, (v, _) in cases.items()})
    for (name, (_, reason)), result in zip(cases.items(), results):
        assert not result.successful, name
        assert reason in result.reason, (name, result.reason)
    # `ros2 param set /emulator model.circuit.load_volume 2e-5` sends text (YAML 1.1 reads 2e-5 so): a number
    ok = c.set_parameters({'model.spool.mass': 0.05, 'watchdog_timeout': '1e0', 'model.circuit.load_volume': '2e-5'})
    assert all(r.successful for r in ok), ok
    n = len(c.samples)
    assert c.spin_until(lambda: len(c.samples) > n + 100, 10)
    diag = c.wait_for_diagnostics(timeout=10)
    assert diag['model'] == 'ok' and diag['watchdog_timeout_s'] == '1'


def test_fault_state_and_reset_service(ros):
    emu = ros.start(params={'safe_duty': 0.3, 'watchdog_timeout': 0.0, 'diagnostics_period': 0.1})
    c = ros.client()
    assert c.wait_for_emulator(START)
    # Bounds: a load volume that passes "> 0" but makes the model diverge is refused, named.
    refused = c.set_parameters({'model.circuit.load_volume': 1e-12})[0]
    assert not refused.successful
    assert 'model.circuit.load_volume: got 1e-12; accepted is a plausible value 1e-06 .. 1 (m^3)' in refused.reason
    # A plausible spool mass the 0.1 ms step cannot integrate at duty 0.7 (it runs at 0.3, on the end stop).
    assert c.set_parameters({'model.spool.mass': 0.01})[0].successful
    c.send_duty(0.7)
    fault = c.wait_for_diagnostics(lambda d: d['model'] == 'fault', 10)
    assert fault is not None and ('diverged' in fault['fault_reason'] or 'failed' in fault['fault_reason'])
    assert c.diagnostic_levels[-1] == 2                                  # ERROR
    assert c.diagnostic_statuses[-1]['model'][0] == 2 and c.diagnostic_statuses[-1]['inputs'][0] == 0
    c.spin_for(0.3)
    n = len(c.samples)
    c.spin_for(0.3)
    assert len(c.samples) == n, 'a faulted device must not publish samples'
    assert all(-1e5 <= s.pressure <= 800e5 for s in c.samples), 'a diverging sample was published'
    # reset with the same parameters: the model would fault again at once -> failure, said so
    response = c.reset()
    assert not response.success and 'faults again at once' in response.message, response.message
    # a good value set while faulted restarts the model, as the log says
    assert c.set_parameters({'model.spool.mass': 0.04})[0].successful
    assert c.spin_until(lambda: len(c.samples) > n + 100, 10), 'no samples after the good value'
    assert c.wait_for_diagnostics(lambda d: d['model'] == 'ok', 10)
    assert c.samples[-1].pressure > 100e5                                # at rest at duty 0.7
    assert 'model restarted at rest' in emu.output() and 'cleared fault' in emu.output()
    response = c.reset()
    assert response.success and 'model at rest at duty 0.7' in response.message


# --- process ------------------------------------------------------------------------------------

def test_sigterm_shuts_down_cleanly(ros):
    emu = ros.start()
    c = ros.client()
    assert c.wait_for_emulator(START)
    assert emu.stop(signal.SIGTERM) == 0
    out = emu.output()
    assert 'stopping on SIGTERM' in out and 'Traceback' not in out, out


def test_colcon_built_executable_starts_and_publishes(ros, colcon_install):
    exe = colcon_install.executable('emulator')
    assert exe.is_file()
    emu = ros.start(executable=exe, env=colcon_install.env,
                    args=['--params-file', str(colcon_install.prefix / 'share/pcv_sim/config/emulator.yaml')])
    c = ros.client()
    assert c.wait_for_emulator(START), emu.output()
    assert c.spin_until(lambda: len(c.samples) > 100, 10)
    assert emu.stop() == 0


def test_incompatible_qos_is_logged_by_the_node(ros):
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import FluidPressure
    from std_msgs.msg import Float64

    emu = ros.start()
    c = ros.client()
    assert c.wait_for_emulator(START)
    c.node.create_subscription(FluidPressure, 'pressure', lambda m: None,
                               QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
    pub = c.node.create_publisher(Float64, 'duty_cycle',
                                  QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT))
    assert c.spin_until(lambda: "QoS incompatible on 'pressure'" in emu.output()
                        and "QoS incompatible on 'duty_cycle'" in emu.output(), 20), emu.output()
    out = emu.output()
    assert 'a subscriber has a RELIABILITY policy' in out and 'subscribe best effort' in out
    assert 'a publisher has a RELIABILITY policy' in out and 'publish reliable' in out
    assert pub is not None


# --- external clock (use_sim_time) ----------------------------------------------------------------

def test_use_sim_time_follows_an_external_clock(ros):
    """As under a Gazebo simulation: model time follows /clock, stamps are that clock."""
    from rosgraph_msgs.msg import Clock

    emu = ros.start(params={'use_sim_time': True, 'safe_duty': 0.3, 'watchdog_timeout': 0.0,
                            'diagnostics_period': 0.2})
    c = ros.client()
    pub = c.node.create_publisher(Clock, '/clock', 10)
    t0 = 1000 * 10**9                                 # the simulation's clock: 1000 s
    assert c.spin_until(lambda: pub.get_subscription_count() > 0, START), emu.output()

    def tick(k):
        msg = Clock()
        msg.clock.sec, msg.clock.nanosec = divmod(t0 + k * 1_000_000, 10**9)
        pub.publish(msg)

    k = 0
    while not c.samples and k < 20000:
        tick(k)
        k += 1
        c.spin_for(0.002)
    assert c.samples, emu.output()
    for _ in range(200):                             # 200 ms of simulated time, at any wall pace
        tick(k)
        k += 1
        c.spin_for(0.002)
    last_clock = t0 + (k - 1) * 1_000_000
    c.spin_for(0.5)
    stamps = [s.stamp_ns for s in c.samples]
    assert t0 <= stamps[0] and stamps[-1] <= last_clock, (stamps[0], stamps[-1], last_clock)
    assert stamps[-1] >= last_clock - 2_000_000         # caught up with the clock
    # On the 1 ms grid of the external clock, in order (a best-effort sample may be lost on the way,
    # so the count is checked against the node's own: samples_published).
    assert all(b > a and (b - a) % 1_000_000 == 0 and (a - t0) % 1_000_000 == 0 for a, b in itertools.pairwise(stamps))
    n = len(c.samples)
    c.spin_for(0.3)                                  # the clock stands still: so does the model
    assert len(c.samples) == n
    diag = c.wait_for_diagnostics(timeout=10)
    assert diag['time_mode'] == 'external_clock'
    # every 1 ms of model time since the first /clock published (the first sample at model time 0)
    assert int(diag['samples_published']) == round(float(diag['model_time_s']) * 1000) + 1


def test_a_second_clock_and_use_sim_time_with_simulated_time_are_refused(ros):
    first = ros.start('sim1', params={'time_mode': 'simulated', 'lockstep': True})
    c = ros.client('sim1')
    assert c.wait_for_emulator(START), first.output()
    second = ros.start('sim2', params={'time_mode': 'simulated'})
    both = ros.start('both', params={'time_mode': 'simulated', 'use_sim_time': True})
    for emu, message in ((second, 'other publisher(s) of /clock found'),
                         (both, 'use_sim_time: true follows another node')):
        rc = emu.wait(START)
        out = emu.output()
        assert rc == 2 and message in out and 'Traceback' not in out, out
    assert 'use_sim_time:=true' in second.output()
