"""Shared fixtures: `colcon_install`, a real colcon build of this package; `options_rig`, a rig
YAML with a valve that has the valve options a rig takes as inputs."""
import contextlib
import os
import subprocess
import sys
import tempfile
from pathlib import Path
from types import SimpleNamespace

import kernel_warmup
import pytest
from kernel_warmup import write_options_rig

REPO = Path(__file__).resolve().parent.parent
PACKAGE = 'pcv_sim'


def pytest_addoption(parser):
    parser.addoption('--soak', action='store_true',
                     help='also run the soaks (tests marked soak: minutes each, repeating a scenario under load)')


def pytest_configure(config):
    config.addinivalue_line('markers', 'soak: a long repetition of a scenario under load; run only with --soak')


def pytest_collection_modifyitems(config, items):
    if config.getoption('--soak'):
        return
    skip = pytest.mark.skip(reason='a soak: run with --soak')
    for item in items:
        if 'soak' in item.keywords:
            item.add_marker(skip)


def clean_child_env(**extra):
    """Environment for a child process: no inherited ros_wheels_bootstrapper mark.

    The child then bootstraps itself (re-exec with LD_LIBRARY_PATH), whatever
    interpreter it is; see docs/ros_wheels.md.
    """
    env = {k: v for k, v in os.environ.items() if k != '_ROS_WHEELS_BOOTSTRAP_COMPLETE'}
    env.update(extra)
    return env


def _hook_paths(prefix, variable):
    """Paths colcon's share/<pkg>/hook/*.dsv prepend to `variable`, made absolute."""
    paths = []
    for dsv in sorted((prefix / 'share' / PACKAGE / 'hook').glob('*.dsv')):
        for line in dsv.read_text().splitlines():
            parts = line.split(';')
            if len(parts) >= 3 and parts[0].startswith('prepend') and parts[1] == variable:
                paths += [str(prefix / p) if p else str(prefix) for p in parts[2:]]
    return paths


@pytest.fixture(scope='session')
def colcon_install(tmp_path_factory):
    """Build the package with colcon into a temporary directory, once per session.

    Returns a namespace with
      prefix      -- the package's install prefix (what AMENT_PREFIX_PATH names)
      env         -- environment in which `<prefix>/lib/pcv_sim/<exe>` runs, as after
                     sourcing the install (AMENT_PREFIX_PATH, PYTHONPATH)
      executable  -- name -> Path of `<prefix>/lib/pcv_sim/<name>` (as `ros2 run` finds it)
      log         -- colcon's console output
      new_in_repo -- build/, install/, log/, *.egg-info the build added to the repo (none)
    The repository is not written to: build, install and log all go to the tmp dir.
    """
    base = tmp_path_factory.mktemp('colcon')
    before = set(os.listdir(REPO))
    cmd = [
        sys.executable, '-m', 'colcon', '--log-base', str(base / 'log'),
        'build', '--base-paths', str(REPO),
        '--build-base', str(base / 'build'), '--install-base', str(base / 'install'),
        '--event-handlers', 'console_direct+',
    ]
    proc = subprocess.run(cmd, cwd=base, env=clean_child_env(), capture_output=True,
                          text=True, timeout=300)
    log = proc.stdout + proc.stderr
    new_in_repo = sorted(n for n in set(os.listdir(REPO)) - before
                         if n in ('build', 'install', 'log') or n.endswith('.egg-info'))
    assert proc.returncode == 0, f'colcon build failed:\n{log}'
    prefix = base / 'install' / PACKAGE
    pythonpath = _hook_paths(prefix, 'PYTHONPATH')
    assert pythonpath, f'colcon wrote no PYTHONPATH hook under {prefix}:\n{log}'
    ament = _hook_paths(prefix, 'AMENT_PREFIX_PATH') or [str(prefix)]
    env = clean_child_env(AMENT_PREFIX_PATH=os.pathsep.join(ament),
                          PYTHONPATH=os.pathsep.join(pythonpath))
    return SimpleNamespace(
        base=base, prefix=prefix, env=env, log=log, new_in_repo=new_in_repo,
        executable=lambda name: prefix / 'lib' / PACKAGE / name,
    )


@contextlib.contextmanager
def burning(n):
    """n CPU-bound processes for the block's duration."""
    hogs = [subprocess.Popen([sys.executable, '-c', 'while True: pass'], env=clean_child_env())
            for _ in range(n)]
    try:
        yield hogs
    finally:
        for h in hogs:
            h.kill()
        for h in hogs:
            h.wait(5)


@pytest.fixture
def cpu_load():
    """Two CPU-bound processes beside the test for its duration: on this 2-core machine the node
    then competes for a core, as it does on a shared machine. Ordering promises must hold so."""
    with burning(2) as hogs:
        yield hogs


@pytest.fixture
def cpu_burners():
    """`cpu_burners(n)`: n CPU-bound processes beside the test from then on until it ends (a soak's
    harsher load than `cpu_load`)."""
    with contextlib.ExitStack() as stack:
        yield lambda n: stack.enter_context(burning(n))


_WARM_UP = pytest.StashKey()


def pytest_sessionstart(session):
    """Start the kernels' second warm-up process (`compiled_kernels`) now: it compiles its share
    while the tests are collected."""
    if session.config.option.collectonly:
        return
    log = tempfile.TemporaryFile()
    proc = subprocess.Popen([sys.executable, str(Path(__file__).with_name('kernel_warmup.py')), *kernel_warmup.BESIDE],
                            stdout=log, stderr=subprocess.STDOUT, env=clean_child_env())
    session.config.stash[_WARM_UP] = (proc, log)


def pytest_sessionfinish(session):
    proc, log = session.config.stash.get(_WARM_UP, (None, None))
    if proc is not None and proc.poll() is None:     # the run ended before a test waited for it
        proc.kill()
        proc.wait()
    if log is not None:
        log.close()


@pytest.fixture(scope='session', autouse=True)
def compiled_kernels(request):
    """Compile the core's kernels (both valve models, the shipped rig's composite: two valves and the
    cylinder, a kernel of its own, the options rig and the valve with every option:
    `kernel_warmup.BUILDS`) once, before any test starts an emulator or a rig node process: the
    processes then load them from the disk cache (~1 s) instead of each compiling them (several
    seconds, minutes on a busy machine after a model change), which would eat into their start
    timeouts. Two processes compile them, each its share (`pytest_sessionstart` started the other),
    on the machine's two cores: with an empty cache about half the wait."""
    kernel_warmup.build(kernel_warmup.IN_SESSION)
    proc, log = request.config.stash.get(_WARM_UP, (None, None))
    if proc is not None:
        proc.wait()
        log.seek(0)
        assert proc.returncode == 0, f"the kernels' warm-up process failed:\n{log.read().decode(errors='replace')}"
    kernel_warmup.build(kernel_warmup.BESIDE)       # loaded from the cache: this process has them all


@pytest.fixture(scope='session')
def options_rig_writer():
    """`write_options_rig`, for fixtures of other scopes."""
    return write_options_rig


@pytest.fixture
def options_rig(tmp_path):
    """`write_options_rig` in the test's own directory."""
    return write_options_rig(tmp_path)


#: The example controller whose array form raises from `fail_at` s on (never when < 0): a
#: controller that fails mid-run, as a module a campaign names (`fragile:Fragile`).
FRAGILE_CONTROLLER = '''
from pcv_sim.control.steering import PositionController


class Fragile(PositionController):
    """The example controller whose array form raises from `fail_at` s on (never when < 0)."""

    def __init__(self, fail_at):
        super().__init__()
        self.fail_at = fail_at

    def lockstep_arrays(self, signals, valves):
        step, commanded, flags = super().lockstep_arrays(signals, valves)

        def fragile(t, y, out):
            if 0 <= self.fail_at <= t:
                raise ZeroDivisionError("the controller divided by zero")
            step(t, y, out)

        return fragile, commanded, flags
'''


@pytest.fixture
def fragile_controller(tmp_path):
    """`FRAGILE_CONTROLLER` written as `fragile.py` in the test's directory; returns its class."""
    path = tmp_path / 'fragile.py'
    path.write_text(FRAGILE_CONTROLLER)
    namespace = {}
    exec(compile(FRAGILE_CONTROLLER, str(path), 'exec'), namespace)
    return namespace['Fragile']


def make_emulator_recorder(directory, *, name=None, signals=None, options=(), every=1, dt_ns=100_000, namespace='/',
                           frame_id='', faults=False, max_queue_s=10.0, writing=None):
    """The emulator's recorder (`pcv_sim.device.recording`) made from its names, without a device:
    one valve on its own load volume, `options` the valve options' signals it has (inputs and outputs
    by name), `signals` the roles it records (default all)."""
    from pcv_sim.device.recording import RECORDABLE, BagLayout, DeviceRecorder
    from pcv_sim.io.recorder import WRITER_DEFAULTS
    from pcv_sim.io.topics import INPUT_ROLES, OPTION_INTERFACE, OUTPUT_ROLES

    inputs = [e.name for e in OPTION_INTERFACE if e.direction == 'in' and e.name in options]
    outputs = [e.name for e in OPTION_INTERFACE if e.direction == 'out' and e.name in options]
    layout = BagLayout.of_names(('valve',), (*OUTPUT_ROLES, *outputs), (*INPUT_ROLES, *inputs), namespace=namespace,
                                every=every, record=RECORDABLE if signals is None else signals, frame_id=frame_id,
                                faults=faults, events=False, lone_valve=True)
    return DeviceRecorder(directory, layout, name=name, dt_ns=dt_ns, namespace=namespace, max_queue_s=max_queue_s,
                          writing=writing or WRITER_DEFAULTS)


@pytest.fixture
def emulator_recorder():
    """`make_emulator_recorder`."""
    return make_emulator_recorder
