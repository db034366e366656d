"""The launch file (checked with stand-in launch modules: launch is not on PyPI), the CLI help,
and the demo client against a running emulator."""
import ast
import re
import subprocess
import sys
import types
from pathlib import Path

from pcv_sim.params import load_params
from pcv_sim.simulation.rest import rest_state

from .conftest import clean_child_env

REPO = Path(__file__).resolve().parents[2]
LAUNCH = REPO / 'launch' / 'emulator.launch.py'


class _Recorded:
    """Stands in for a launch class: remembers how it was constructed."""

    def __init__(self, *args, **kwargs):
        self.args, self.kwargs = args, kwargs


def _fake_modules(share):
    mods = {}
    for name in ('launch', 'launch.actions', 'launch.substitutions', 'launch_ros', 'launch_ros.actions',
                 'launch_ros.parameter_descriptions', 'ament_index_python', 'ament_index_python.packages'):
        mods[name] = types.ModuleType(name)
    mods['launch'].LaunchDescription = type('LaunchDescription', (_Recorded,), {})
    mods['launch.actions'].DeclareLaunchArgument = type('DeclareLaunchArgument', (_Recorded,), {})
    mods['launch.substitutions'].LaunchConfiguration = type('LaunchConfiguration', (_Recorded,), {})
    mods['launch_ros.actions'].Node = type('Node', (_Recorded,), {})
    mods['launch_ros.parameter_descriptions'].ParameterValue = type('ParameterValue', (_Recorded,), {})
    mods['ament_index_python.packages'].get_package_share_directory = (
        lambda pkg: str(share) if pkg == 'pcv_sim' else (_ for _ in ()).throw(LookupError(pkg)))
    return mods


def test_launch_file_starts_the_emulator_executable_with_the_shipped_params(monkeypatch, tmp_path):
    source = LAUNCH.read_text()
    compile(source, str(LAUNCH), 'exec')
    ast.parse(source)
    for name, module in _fake_modules(tmp_path / 'share' / 'pcv_sim').items():
        monkeypatch.setitem(sys.modules, name, module)
    namespace = {}
    exec(compile(source, str(LAUNCH), 'exec'), namespace)
    ld = namespace['generate_launch_description']()
    entities = ld.args[0]
    args = {e.args[0]: e.kwargs for e in entities if type(e).__name__ == 'DeclareLaunchArgument'}
    nodes = [e for e in entities if type(e).__name__ == 'Node']
    assert set(args) == {'namespace', 'params_file', 'use_sim_time'}
    assert args['use_sim_time']['default_value'] == 'false'
    assert args['params_file']['default_value'] == str(tmp_path / 'share/pcv_sim/config/emulator.yaml')
    (node,) = nodes
    assert node.kwargs['package'] == 'pcv_sim'
    assert node.kwargs['executable'] == 'emulator'
    assert node.kwargs['name'] == 'emulator'
    assert node.kwargs['namespace'].args == ('namespace',)
    params_file, sim_time = node.kwargs['parameters']
    assert params_file.args == ('params_file',)
    value = sim_time['use_sim_time']
    assert value.args[0].args == ('use_sim_time',) and value.kwargs == {'value_type': bool}
    # The executable and the params file it names exist: console script and installed config.
    setup = (REPO / 'setup.py').read_text()
    assert "'emulator = pcv_sim.node.emulator:main'" in setup
    assert (REPO / 'config' / 'emulator.yaml').is_file()


def test_params_file_matches_the_node_parameters():
    """config/emulator.yaml: every node parameter with its default, under `/**` (any name/namespace)."""
    import yaml

    from pcv_sim.device.settings import NODE_PARAMETERS

    data = yaml.safe_load((REPO / 'config' / 'emulator.yaml').read_text())
    params = data['/**']['ros__parameters']
    assert {p.name: p.default for p in NODE_PARAMETERS} == params


def test_help_lists_the_parameters():
    proc = subprocess.run([sys.executable, '-m', 'pcv_sim.node.emulator', '--help'], capture_output=True,
                          text=True, timeout=60, env=clean_child_env())
    assert proc.returncode == 0, proc.stderr
    for name in ('publish_rate', 'watchdog_timeout', 'time_mode', 'model.<section>.<key>'):
        assert name in proc.stdout


def test_demo_prints_the_step_table(ros):
    """Every sample the emulator published for a step is counted: the samples of a 0.4 s step are
    ~400 at 1 kHz, less those of the steps the emulator skipped, far behind wall time on a loaded
    machine (it says so in its timing diagnostics), and a few lost on the way (best effort)."""
    ros.start(params={'safe_duty': 0.3, 'diagnostics_period': 0.2})
    c = ros.client()
    assert c.wait_for_emulator(60)
    before = c.wait_for_diagnostics(timeout=10)
    demo = subprocess.Popen(
        [sys.executable, '-m', 'pcv_sim.node.demo', '--namespace', ros.ns(), '--duties', '0.5,0.7', '--hold', '0.4',
         '--timeout', '30'],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ros.env)
    try:
        assert c.spin_until(lambda: demo.poll() is not None, 90)
    finally:
        if demo.poll() is None:
            demo.kill()
        out, err = demo.communicate(timeout=10)
    proc = subprocess.CompletedProcess(demo.args, demo.returncode, out, err)
    after = c.wait_for_diagnostics(timeout=10)
    assert before is not None and after is not None
    skipped = int(after['skipped_steps']) - int(before['skipped_steps'])      # 0.1 ms steps; 10 to a sample
    assert proc.returncode == 0, proc.stdout + proc.stderr
    rows = [line.split() for line in proc.stdout.splitlines() if re.match(r'\s+\d+\s+0\.\d\d\s', line)]
    assert [r[1] for r in rows] == ['0.50', '0.70']
    params = load_params()
    for row, duty in zip(rows, (0.5, 0.7)):
        settled = float(row[2])
        # 0.4 s holds: the response is within 1 bar of the rest equilibrium by then (demo settles in ~0.1 s).
        assert abs(settled - rest_state(params, params.simulation.model, duty).state[3] / 1e5) < 1.0, row
        assert 1.0 < float(row[3]) < 100.0                   # rise time, ms
        assert int(row[5]) > 300 - skipped / 10, (row, skipped)     # samples


def test_demo_without_an_emulator_says_so(ros):
    proc = subprocess.run([sys.executable, '-m', 'pcv_sim.node.demo', '--namespace', ros.ns('nobody'),
                           '--timeout', '1'], capture_output=True, text=True, timeout=60, env=ros.env)
    assert proc.returncode == 1
    assert 'no emulator answering' in proc.stderr and 'make run' in proc.stderr


def _samples(stamps_ns, pressure):
    from pcv_sim.node.client import PressureSample

    return [PressureSample(int(t), float(p), int(t), int(t)) for t, p in zip(stamps_ns, pressure)]


def test_demo_measures_steps_by_stamp_and_says_what_it_could_not_measure():
    """A lagging emulator: step 2's samples are all stamped before step 2 began (a burst of step
    1's caught-up samples arrived during it), step 3 has none. Step 1 is measured from its samples
    whatever their arrival; steps 2 and 3 say why not; the run measured something: exit 0."""
    import io

    import numpy as np

    from pcv_sim.node.demo import exit_status, measure_steps

    t0 = 1_795_628_971_000_000_000
    t = t0 - 100_000_000 + np.arange(600) * 1_000_000               # 0.1 s before step 1 .. 0.5 s into it
    p = np.where(t < t0, 10e5, 10e5 + 20e5 * (1 - np.exp(-(t - t0) / 20e6)))
    steps = [(0.5, t0, t0 + 400_000_000), (0.7, t0 + 600_000_000, t0 + 1_000_000_000),
             (0.5, t0 + 1_000_000_000, t0 + 1_400_000_000)]
    rows = measure_steps(steps, _samples(t, p)[::-1])                 # order of arrival does not matter
    assert rows[0]['samples'] == 400 and abs(rows[0]['settled_bar'] - 30.0) < 0.1 and 'reason' not in rows[0]
    assert 30 < rows[0]['rise_time_ms'] < 60                          # 10-90 % of a 20 ms lag: 44 ms
    for row in rows[1:]:
        assert row['samples'] == 0 and 'emulator published none for it' in row['reason'], row
    err = io.StringIO()
    assert exit_status(rows, err) == 0 and 'step(s) 2, 3 not measured' in err.getvalue()
    assert exit_status(rows[1:], err) == 1 and 'measured none of the 2 steps' in err.getvalue()


def test_demo_against_an_emulator_that_stops_says_so(ros):
    """The emulator stops (SIGSTOP: a process that gets no CPU) once the demo found it: the steps
    after that have no sample and say so; exit 1 exactly when no step was measured."""
    import signal
    import time

    emu = ros.start(params={'safe_duty': 0.3})
    demo = subprocess.Popen(
        [sys.executable, '-m', 'pcv_sim.node.demo', '--namespace', ros.ns(), '--duties', '0.5,0.7,0.5',
         '--hold', '0.3', '--timeout', '60'], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ros.env)
    try:
        first = demo.stdout.readline()
        assert first.startswith('demo: emulator'), first + demo.stderr.read()
        emu.proc.send_signal(signal.SIGSTOP)
        out, err = demo.communicate(timeout=60)
    finally:
        emu.proc.send_signal(signal.SIGCONT)
        if demo.poll() is None:
            demo.kill()
    time.sleep(0.1)
    assert 'Traceback' not in err, err
    rows = [line for line in out.splitlines() if re.match(r'\s+\d\s+0\.\d\d\s', line)]
    assert len(rows) == 3, out
    for row in rows[1:]:
        assert 'not measured' in row and 'emulator published none for it' in row, out
    measured_first = 'not measured' not in rows[0]
    assert demo.returncode == (0 if measured_first else 1), (out, err)
    assert ('step(s) 2, 3 not measured' if measured_first else 'measured none of the 3 steps') in err, err
