"""Fixtures for the node tests: emulator processes and a client, isolated per test.

Each test gets its own ROS_DOMAIN_ID (from the pid and a counter), discovery limited to
localhost, and a namespace unique to the test, so parallel test runs on the machine do not see
each other. The emulator runs as a separate process with this venv's python; the
ros_wheels_bootstrapper mark is cleared from its environment (docs/ros_wheels.md).
"""
import itertools
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
_counter = itertools.count()


def clean_child_env(**extra):
    """os.environ without the ros_wheels_bootstrapper mark (as test/conftest.py's helper), plus extra."""
    env = {k: v for k, v in os.environ.items() if k != '_ROS_WHEELS_BOOTSTRAP_COMPLETE'}
    env.update(extra)
    return env


#: What a node says when it gives up a step of its teardown (pcv_sim.node.process.Teardown).
GIVEN_UP = 'did not finish within'


def _domain_id():
    # 1..99: apart from the layout test's 100..199 and from the default domain 0.
    return 1 + (os.getpid() * 13 + next(_counter) * 7) % 99


class Emulator:
    """One emulator process; `stop()` sends SIGINT and returns the exit code."""

    def __init__(self, cmd, env, log_path):
        self.cmd = cmd
        self.log_path = log_path
        self._log = open(log_path, 'w')
        self.proc = subprocess.Popen(cmd, env=env, stdout=self._log, stderr=subprocess.STDOUT, cwd=REPO)

    def output(self):
        if not self._log.closed:
            self._log.flush()
        return Path(self.log_path).read_text()

    def wait(self, timeout=30):
        try:
            return self.proc.wait(timeout)
        finally:
            self._log.close()

    def stop(self, sig=signal.SIGINT, timeout=15):
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        try:
            return self.wait(timeout)
        except subprocess.TimeoutExpired:
            # The native stacks (the DDS library's threads), then SIGABRT: the child's faulthandler
            # (PYTHONFAULTHANDLER, RosTest's env) writes every Python thread's stack into the log, so a
            # hang names where it hangs.
            native = native_stacks(self.proc.pid)
            self.proc.send_signal(signal.SIGABRT)
            try:
                self.proc.wait(5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)
            raise AssertionError(f'emulator did not stop on {sig!r} within {timeout} s:\n{self.output()}\n'
                                 f'native stacks:\n{native}') from None


def native_stacks(pid):
    """Every thread's native stack of a running process (gdb; '' where gdb is not installed)."""
    gdb = shutil.which('gdb')
    if gdb is None:
        return ''
    try:
        return subprocess.run([gdb, '-p', str(pid), '-batch', '-nx', '-ex', 'thread apply all bt'], capture_output=True,
                              text=True, timeout=60, stdin=subprocess.DEVNULL).stdout
    except subprocess.TimeoutExpired:
        return 'gdb did not answer within 60 s'


class RosTest:
    """Per-test ROS environment: domain, namespace prefix, emulator processes, clients."""

    def __init__(self, tmp_path, monkeypatch):
        import rclpy

        self.domain = _domain_id()
        self.prefix = f'/pcv{os.getpid()}_{next(_counter)}'
        self.tmp_path = tmp_path
        # PCV_SIM_STACKS: a node whose teardown is given up prints its native stacks too (pcv_sim.node.process).
        self.env = clean_child_env(ROS_DOMAIN_ID=str(self.domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
                                   PYTHONFAULTHANDLER='1', PCV_SIM_STACKS='1')
        monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
        monkeypatch.setenv('ROS_DOMAIN_ID', str(self.domain))
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=self.domain)
        self.emulators = []
        self.clients = []

    def ns(self, name='valve'):
        return f'{self.prefix}/{name}'

    def start(self, name='valve', *, params=None, args=(), executable=None, env=None):
        """Start an emulator in namespace ns(name) with `-p key:=value` for each param."""
        cmd = [str(executable)] if executable else [sys.executable, '-m', 'pcv_sim.node.emulator']
        cmd += ['--ros-args', '-r', f'__ns:={self.ns(name)}']
        for key, value in (params or {}).items():
            cmd += ['-p', f'{key}:={_ros_value(value)}']
        cmd += list(args)
        run_env = dict(self.env if env is None else {**env, **{k: self.env[k] for k in
                                                              ('ROS_DOMAIN_ID', 'ROS_AUTOMATIC_DISCOVERY_RANGE')}})
        emulator = Emulator(cmd, run_env, self.tmp_path / f'{name}-{len(self.emulators)}.log')
        self.emulators.append(emulator)
        return emulator

    def client(self, name='valve', **kw):
        from pcv_sim.node.client import EmulatorClient

        c = EmulatorClient(self.ns(name), context=self.context, node_name=f'test_client_{len(self.clients)}', **kw)
        self.clients.append(c)
        return c

    def close(self):
        import rclpy

        errors = []
        for e in self.emulators:
            if e.proc.poll() is None:
                try:
                    rc = e.stop()
                except AssertionError as hang:          # the others are still stopped (none left running)
                    errors.append(str(hang))
                    continue
                out = e.output()
                # A teardown given up after its bound (pcv_sim.node.process) is a failure too, with its stacks.
                if rc != 0 or 'Traceback' in out or GIVEN_UP in out:
                    errors.append(f'{e.cmd}: exit {rc} on SIGINT:\n{out}')
            else:
                e.wait()
        for c in self.clients:
            c.close()
        rclpy.try_shutdown(context=self.context)
        assert not errors, '\n'.join(errors)


def _ros_value(value):
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, float):
        return repr(value)
    return str(value)


@pytest.fixture
def ros(tmp_path, monkeypatch):
    env = RosTest(tmp_path, monkeypatch)
    yield env
    env.close()


def wait_until(predicate, timeout, step=0.01):
    end = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > end:
            return False
        time.sleep(step)
    return True
