"""The package installs the ament way, and the model stays free of ROS imports."""
import ast
import os
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
PACKAGE = 'pcv_sim'

ROS_MODULES = {'rclpy', 'std_msgs', 'sensor_msgs', 'diagnostic_msgs', 'rosgraph_msgs',
               'std_srvs'}
EXECUTABLES = ('emulator', 'pcv-sim', 'demo', 'rig', 'steering_controller')


# --- (a) package.xml matches setup.py -------------------------------------------------

def _setup_name():
    """The name passed to setup() in setup.py, read with ast (no setup.py side effects)."""
    tree = ast.parse((REPO / 'setup.py').read_text())
    strings = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.Assign) and isinstance(node.value, ast.Constant):
            for target in node.targets:
                if isinstance(target, ast.Name):
                    strings[target.id] = node.value.value
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and getattr(node.func, 'id', None) == 'setup':
            for kw in node.keywords:
                if kw.arg == 'name':
                    if isinstance(kw.value, ast.Constant):
                        return kw.value.value
                    return strings[kw.value.id]
    raise AssertionError('setup.py has no setup(name=...)')


def test_package_xml_format_and_name():
    root = ET.parse(REPO / 'package.xml').getroot()
    assert root.tag == 'package'
    assert root.get('format') == '3'
    assert root.findtext('name') == PACKAGE == _setup_name()
    assert root.findtext('export/build_type') == 'ament_python'
    assert root.findtext('license') == 'MIT'
    exec_deps = {e.text for e in root.findall('exec_depend')}
    assert ROS_MODULES | {'python3-numpy', 'python3-scipy', 'python3-yaml'} <= exec_deps
    assert 'python3-pytest' in {e.text for e in root.findall('test_depend')}
    assert (REPO / 'resource' / PACKAGE).is_file()


# --- (b) colcon build, then resolve executables as `ros2 run` does ---------------------

def _get_package_prefix(env):
    """ament_index_python.get_package_prefix in a child, so our own env stays clean."""
    code = ('from ament_index_python.packages import get_package_prefix\n'
            f'print(get_package_prefix({PACKAGE!r}))')
    proc = subprocess.run([sys.executable, '-c', code], env=env, capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    return Path(proc.stdout.strip().splitlines()[-1])


def test_colcon_install_resolves_like_ros2_run(colcon_install):
    prefix = _get_package_prefix(colcon_install.env)
    assert prefix.resolve() == colcon_install.prefix.resolve()
    assert (prefix / 'share' / 'ament_index' / 'resource_index' / 'packages' / PACKAGE).is_file()
    assert (prefix / 'share' / PACKAGE / 'package.xml').is_file()
    for name in EXECUTABLES:
        exe = prefix / 'lib' / PACKAGE / name
        assert exe.is_file() and os.access(exe, os.X_OK), f'{exe} missing or not executable'
    for config in sorted((REPO / 'config').glob('*.yaml')):
        assert (prefix / 'share' / PACKAGE / 'config' / config.name).is_file()
    for launch in sorted((REPO / 'launch').glob('*.launch.py')):
        assert (prefix / 'share' / PACKAGE / 'launch' / launch.name).is_file()


def test_colcon_build_leaves_repo_clean(colcon_install):
    """build, install, log and egg-info all went to the tmp dir, none into the repo."""
    assert colcon_install.base in colcon_install.prefix.parents
    assert not colcon_install.new_in_repo, (
        f'colcon build wrote into the repository: {colcon_install.new_in_repo}')


def test_installed_pcv_sim_help_runs(colcon_install):
    exe = colcon_install.executable('pcv-sim')
    proc = subprocess.run([str(exe), '--help'], env=colcon_install.env, cwd=colcon_install.base,
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, f'{exe} --help exited {proc.returncode}:\n{proc.stderr}'
    assert proc.stdout.strip()


# --- (c) the model never imports ROS -------------------------------------------------

def _imported_roots(tree):
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield node.lineno, alias.name.split('.')[0]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            yield node.lineno, node.module.split('.')[0]
        elif (isinstance(node, ast.Call) and node.args
              and isinstance(node.args[0], ast.Constant) and isinstance(node.args[0].value, str)
              and (getattr(node.func, 'id', None) == '__import__'
                   or getattr(node.func, 'attr', None) == 'import_module')):
            yield node.lineno, node.args[0].value.split('.')[0]


def test_model_packages_never_import_ros():
    pkg = REPO / PACKAGE
    assert (pkg / '__init__.py').is_file(), f'{pkg}/__init__.py is missing'
    node_dir = pkg / 'node'
    checked, offenders = 0, []
    for path in sorted(pkg.rglob('*.py')):
        if node_dir in path.parents:
            continue
        tree = ast.parse(path.read_text(), filename=str(path))
        checked += 1
        offenders += [f'{path.relative_to(REPO)}:{line} imports {mod}'
                      for line, mod in _imported_roots(tree) if mod in ROS_MODULES]
    assert checked, 'no model modules found'
    assert not offenders, 'ROS imports outside pcv_sim/node/:\n' + '\n'.join(offenders)


# --- the venv's rclpy works under `python -m pytest` (ros_wheels_bootstrapper) --------

def test_rclpy_pub_sub_in_pytest(monkeypatch):
    import time

    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from std_msgs.msg import Float64

    assert os.environ.get('_ROS_WHEELS_BOOTSTRAP_COMPLETE') == '1'
    # Isolated from other ROS traffic on the machine (docs/ros_wheels.md).
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=100 + os.getpid() % 100)
    try:
        node = rclpy.create_node('layout_probe', context=context)
        got = []
        node.create_subscription(Float64, 'layout_probe', lambda m: got.append(m.data), 10)
        pub = node.create_publisher(Float64, 'layout_probe', 10)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        deadline = time.monotonic() + 10.0
        while not got and time.monotonic() < deadline:
            pub.publish(Float64(data=0.25))
            executor.spin_once(timeout_sec=0.05)
        executor.shutdown()
        node.destroy_node()
        assert got and got[0] == 0.25
    finally:
        rclpy.shutdown(context=context)

