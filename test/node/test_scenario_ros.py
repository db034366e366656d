"""Scenarios with a ROS 2 controller node: the example `steering_controller` in its own process,
the rig node hosted by the scenario runner (`pcv_sim.node.scenario_host`), over real DDS.

The same control law (`pcv_sim.control.steering.PositionController`) sees the same samples in
lockstep as the in-process callable does, so the runs are compared bit for bit. Each test has its
own ROS domain and namespace (test/node/conftest.py).
"""
import json
import sys
from pathlib import Path

import numpy as np
import yaml

from pcv_sim.cli import main
from pcv_sim.testing import run_rig_scenario

from .conftest import Emulator

REPO = Path(__file__).resolve().parents[2]
EXAMPLES = REPO / "examples"


def start_controller(ros, name='rig', args=()):
    cmd = [sys.executable, '-m', 'pcv_sim.node.steering_controller', '--ros-args', '-r', f'__ns:={ros.ns(name)}',
           *args]
    proc = Emulator(cmd, ros.env, ros.tmp_path / f'controller-{len(ros.emulators)}.log')
    ros.emulators.append(proc)       # the fixture stops it (SIGINT) and checks exit 0, no traceback
    return proc


def assert_same_run(a, b):
    for name in ('times', 'true', 'measured', 'duties', 'setpoint'):
        x, y = getattr(a, name), getattr(b, name)
        assert x.shape == y.shape and np.array_equal(x, y, equal_nan=True), name        # bit for bit
    assert a.flags.keys() == b.flags.keys()
    for name in a.flags:
        assert np.array_equal(a.flags[name], b.flags[name], equal_nan=True), name
    assert a.log == b.log


def test_the_controller_node_runs_scenarios_bit_for_bit_as_the_callable(ros):
    """The node answers every lockstep period of two scenarios in a row (the second rewinds it:
    a fresh controller), with use_sim_time following the rig's /clock."""
    ctl = start_controller(ros, args=['-p', 'use_sim_time:=true'])
    ros_ctl = {'ros': {'namespace': ros.ns('rig'), 'wait': 60}}

    step = run_rig_scenario(EXAMPLES / 'step.yaml', ros_ctl, duration=1.0)
    assert step.passed, step.summary() + ctl.output()
    assert_same_run(step.run, run_rig_scenario(EXAMPLES / 'step.yaml', duration=1.0).run)
    assert np.all(step.run.flags['controller.fault_detected'][:-1] == 0.0)

    # The coil opens at 0.5 s: the node's flag, taken from controller/flags by its stamp, lands at
    # the same instant as the callable's (20 ms of low current + one period).
    # Sensor faults on the way: samples the rig does not publish (dropout) are absent for the node
    # as for the callable, a biased and a delayed one are what both see.
    short = {'duration': 0.7, 'timeline': [
        {'t': 0.1, 'fault': 'dropout', 'target': 'cylinder.position'},
        {'t': 0.15, 'clear': 'dropout', 'target': 'cylinder.position'},
        {'t': 0.2, 'fault': 'dropout', 'target': 'right.current'},
        {'t': 0.2, 'fault': 'dropout', 'target': 'left.pressure'},
        {'t': 0.3, 'fault': 'bias', 'target': 'cylinder.velocity', 'value': 0.01},
        {'t': 0.35, 'fault': 'delay', 'target': 'right.pressure', 'delay': 0.003},
        {'t': 0.5, 'fault': 'coil_open', 'target': 'left'}],
             'assertions': [{'type': 'flag_within', 'signal': 'controller.fault_detected', 'at': 0.5, 'within': 0.06}]}
    coil = run_rig_scenario(EXAMPLES / 'coil_open.yaml', ros_ctl, **short)
    assert coil.passed, coil.summary() + ctl.output()
    assert_same_run(coil.run, run_rig_scenario(EXAMPLES / 'coil_open.yaml', **short).run)
    raised = coil.run.times[np.argmax(coil.run.flags['controller.fault_detected'] == 1.0)]
    assert 0.52 <= raised <= 0.53
    assert 'a fresh controller' in ctl.output()


def test_on_the_per_valve_topics_the_controller_node_runs_bit_for_bit_too(ros):
    """lockstep_channel false: samples from <valve>/pressure, <valve>/current and joint_states, one
    duty_cycle per valve and the flags on controller/flags; the setpoint from its topic alone."""
    ctl = start_controller(ros, args=['-p', 'lockstep_channel:=false'])
    ros_ctl = {'ros': {'namespace': ros.ns('rig'), 'wait': 60}}
    short = {'duration': 0.6, 'timeline': [{'t': 0.5, 'fault': 'coil_open', 'target': 'left'}],
             'assertions': [{'type': 'flag_within', 'signal': 'controller.fault_detected', 'at': 0.5, 'within': 0.06}]}
    coil = run_rig_scenario(EXAMPLES / 'coil_open.yaml', ros_ctl, **short)
    assert coil.passed, coil.summary() + ctl.output()
    assert_same_run(coil.run, run_rig_scenario(EXAMPLES / 'coil_open.yaml', **short).run)
    assert np.nanmax(coil.run.flags['controller.fault_detected']) == 1.0


def _scenario_file(tmp_path, name, controller, duration=0.5):
    data = yaml.safe_load((EXAMPLES / 'step.yaml').read_text())
    data.update(name=name, rig=str(REPO / 'config' / 'rig.yaml'), duration=duration, controller=controller)
    data['assertions'] = [a for a in data['assertions'] if 'after' not in a]
    path = tmp_path / f'{name}.yaml'
    path.write_text(yaml.safe_dump(data))
    return path


def test_a_ros_controller_that_never_appears_fails_cleanly_with_exit_1(ros, tmp_path, capsys):
    """--ros replaces the file's (callable) controller by a node the user was to start."""
    path = _scenario_file(tmp_path, 'absent', 'steering:PositionController')
    assert main(['scenario', 'run', str(path), '--json', '--ros', ros.ns('nobody'), '--wait', '2']) == 1
    out = json.loads(capsys.readouterr().out)
    assert out['passed'] is False and out['status'] == 1
    assert out['error'].startswith(f"no ROS controller answered within 2 s (namespace {ros.ns('nobody')}, "
                                   f"ROS_DOMAIN_ID {ros.domain})")
    assert f"{ros.ns('nobody')}/left/duty_cycle" in out['error']


def test_a_directory_starts_each_scenarios_controller_in_its_own_domain(ros, tmp_path, capsys):
    """Two scenarios in parallel start the example node in the same namespace (their own ROS
    domains keep them apart) and stop it; a command that exits before answering fails its run."""
    folder = tmp_path / 'scenarios'
    folder.mkdir()
    cmd = ['{python}', '-m', 'pcv_sim.node.steering_controller', '--ros-args', '-r', '__ns:={namespace}']
    for name in ('first', 'second'):
        _scenario_file(folder, name, {'ros': {'namespace': '/steer', 'command': cmd, 'wait': 60}})
    _scenario_file(folder, 'broken', {'ros': {'command': ['{python}', '-c', 'raise SystemExit(3)'], 'wait': 60}})
    bags = tmp_path / 'bags'
    assert main(['scenario', 'run', str(folder), '--json', '--jobs', '2', '--bag', str(bags)]) == 1
    out = {r['name']: r for r in json.loads(capsys.readouterr().out)['scenarios']}
    assert out['first']['passed'] and out['second']['passed'], out
    assert out['broken']['status'] == 1
    assert out['broken']['error'].startswith('the controller command exited with 3 before answering'), out['broken']
    assert (bags / 'first').is_dir() and (bags / 'second').is_dir()


def test_the_node_refuses_invalid_parameters_with_exit_2(ros):
    ctl = start_controller(ros, args=['-p', 'period:=0.0'])
    assert ctl.wait(60) == 2
    assert 'invalid parameters: period: got 0.0; accepted is a plausible value 0.0001 .. 1 (s)' in ctl.output()


def test_a_directory_with_a_node_the_user_started_runs_its_scenarios_one_after_the_other(ros, tmp_path, capsys):
    """Both scenarios use the one node (and the one /clock of the domain): not in parallel. The
    second has no setpoint: the node, started afresh, must not hold the first one's 20 mm."""
    ctl = start_controller(ros)
    folder = tmp_path / 'scenarios'
    folder.mkdir()
    spec = {'ros': {'namespace': ros.ns('rig'), 'wait': 60}}
    _scenario_file(folder, 'a_step', spec, duration=0.5)
    data = {'name': 'b_hold', 'rig': str(REPO / 'config' / 'rig.yaml'), 'duration': 0.3, 'controller': spec,
            'assertions': [{'type': 'never_above', 'signal': 'cylinder.position', 'max': 1e-3},
                           {'type': 'never_below', 'signal': 'cylinder.position', 'min': -1e-3}]}
    (folder / 'b_hold.yaml').write_text(yaml.safe_dump(data))
    assert main(['scenario', 'run', str(folder), '--jobs', '2']) == 0, capsys.readouterr().out + ctl.output()
    assert '2 scenarios: 2 passed' in capsys.readouterr().out
    assert 'a fresh controller' in ctl.output()


def test_the_lockstep_with_the_node_holds_bit_for_bit_under_load(ros, cpu_load):
    """Two CPU-bound processes beside the rig and the node on the two cores (the machine is shared:
    more load may come on top): slower, the same run. 0.2 s of the step, 200 periods."""
    start_controller(ros)
    ros_ctl = {'ros': {'namespace': ros.ns('rig'), 'wait': 60}}
    short = {'duration': 0.2, 'setpoint': [{'t': 0.0, 'value': 0.0}, {'t': 0.05, 'value': 0.02}],
             'assertions': []}
    loaded = run_rig_scenario(EXAMPLES / 'step.yaml', ros_ctl, **short)
    assert loaded.error is None, loaded.summary()
    assert_same_run(loaded.run, run_rig_scenario(EXAMPLES / 'step.yaml', **short).run)
    assert loaded.run.signal('cylinder.position')[-1] > 1e-3          # it moved toward the 20 mm
