"""A scenario whose controller is a ROS 2 node: the runner hosts the rig node in lockstep.

`pcv-sim scenario run` and `pcv_sim.testing` come here for `controller: {ros: {namespace, command, wait}}`
(`pcv_sim.rig.scenario.run_scenario` runs callables and refuses these).
The rig is the real rig node (`rig_node`, as `ros2 run pcv_sim rig` in simulated lockstep time) in
this process, in the scenario's namespace; a small hook (`DeviceNode.hook`) makes it a scenario:

- the timeline (duties, external force, faults, sensor faults) is scheduled on `node.device` as for a
  callable (`schedule_timeline`), so it acts at the same steps;
- at each control instant the scenario's setpoint goes with the period's sample on the lockstep
  channel (`setpoint`, m: `pcv_sim.node.lockstep_channel`), and is published on `setpoint`
  (std_msgs/Float64, m; the node holds the latest) before the period's samples: at every instant
  for a controller on the per-valve topics, where it changed for one on the channel;
- the true and measured samples of every instant and the duties in force once every valve
  answered are collected into the same `RigRun` a callable run gives, so the assertions and
  `pcv_sim.rig.record` (bag, report) work unchanged;
- the controller's flags are taken from its lockstep command (`controller.<name>`), or from
  `controller/flags` (diagnostic_msgs/DiagnosticArray, header.stamp = the answered sample's model
  time, each KeyValue `name: float`) for a controller on the per-valve topics, into
  `controller.<name>` at that instant;
- the run stops after the duration's last sample.

The controller is a node the user started (in the ROS domain of $ROS_DOMAIN_ID) or the scenario's
`command`, started here with ROS_DOMAIN_ID = `domain` and stopped (SIGINT, then SIGKILL after
10 s) after the run. Until `wait` s pass the rig waits for a controller (matched): a publisher on lockstep/command and a
subscriber of lockstep/sample, or a publisher on every valve's duty_cycle and a subscriber of
cylinder/joint_states; during the run, `wait` s without an answer
end it. Both, and a command that exits, fail the run with the reason (`ScenarioResult.error`).
"""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from pcv_sim.errors import PcvSimError
from pcv_sim.io.topics import CONTROLLER_FLAGS, JOINT_STATES, SETPOINT, cylinder_topic
from pcv_sim.rig.lockstep import RigRun
from pcv_sim.rig.scenario import RosController, Scenario, ScenarioResult, scenario_result, schedule_timeline
from pcv_sim.units import NS_PER_S

__all__ = ["FLAGS_TOPIC", "SETPOINT_TOPIC", "run_ros_scenario"]

SETPOINT_TOPIC = SETPOINT
FLAGS_TOPIC = CONTROLLER_FLAGS
_STOP_GRACE = 10.0          # s a started controller has to exit after SIGINT
_OPTIONAL_MATCH = 2.0       # s more for the setpoint's subscriber and the flags' publisher
_SETTLE = 0.1               # s after the matching, before the first sample
_PROC_CHECK = 0.2           # s between checks that a started command still runs


class ScenarioAborted(Exception):
    """The run could not start or go on (no controller, its command exited, another rig); the message says why."""


class _Host:
    """The hook on the rig node, and the stop flag its loop polls."""

    def __init__(self, node: Any, scenario: Scenario, ros: RosController, proc: Any, log_path: Path | None) -> None:
        from std_msgs.msg import Float64

        from pcv_sim.node.qos_events import topic_qos

        self.node, self.scenario, self.ros, self.proc, self.log_path = node, scenario, ros, proc, log_path
        rig = node.device
        self.per = rig.params.steps_per_period
        self.period_ns = self.per * node.device.dt_ns
        self.n = n = round(scenario.duration / rig.params.timing.control_period)
        names, self.valves = rig.signals, rig.valve_names
        self.true = np.full((n + 1, len(names)), np.nan)
        self.meas = np.full((n + 1, len(names)), np.nan)
        self.duties = np.full((n + 1, len(self.valves)), np.nan)
        self.sp = np.full(n + 1, np.nan)
        self.walls = np.full(n + 1, np.nan)
        self.flags: dict[str, np.ndarray] = {}
        self.rejected: list[tuple[float, str]] = []
        self._rejected_seen = 0
        self.setpoint = scenario.setpoint_function()
        self._msg = Float64()
        self._last_sp = math.nan                     # the setpoint last published on the topic
        self.channel = False                         # the controller is on the lockstep channel
        self._pub_sp = node.create_publisher(Float64, SETPOINT_TOPIC, topic_qos(SETPOINT_TOPIC))
        self.done = False
        self.failure: str | None = None
        self.progress = time.monotonic()
        self._next_proc_check = 0.0
        self.wall0 = 0.0

    # --- the hook ---------------------------------------------------------------------------

    def sampled(self, true: np.ndarray, measured: list[float]) -> None:
        rig = self.node.device
        k = rig.steps // self.per
        self.progress = time.monotonic()
        if k > self.n:
            return
        self.walls[k] = now = time.perf_counter()
        if k == 0:
            self.wall0 = now
        self.true[k] = true
        self.meas[k] = measured
        if self.setpoint is not None:
            self.sp[k] = v = self.setpoint(rig.time)
            # In the lockstep sample: the controller has it with the sample it answers. On the topic
            # for a controller on the per-valve topics (every instant: one that subscribed late gets
            # it) and for other readers (where it changed), before the samples; not at the last
            # instant, which needs no answer: DDS does not order a setpoint after the samples of
            # another topic, and a setpoint that came after the run's last answer would be taken into
            # the next run.
            self.node.sample_extras["setpoint"] = v
            if k < self.n and (v != self._last_sp or not self.channel):
                self._last_sp = self._msg.data = v
                self._pub_sp.publish(self._msg)
        if k == self.n:                              # the last instant: no answer needed (as run_lockstep)
            self.duties[k] = [rig.duties[v] for v in self.valves]
            self.done = True

    def answered(self, k: int) -> None:
        """The controller answered the sample of instant k; the rig is one step past it, so
        `rig.duties` are those in force after the instant (as `run_lockstep` records them)."""
        rig = self.node.device
        if k < self.n:
            self.duties[k] = [rig.duties[v] for v in self.valves]
        counts = self.node.device.counts
        total = sum(counts.rejected.values())
        if total > self._rejected_seen:
            self._rejected_seen = total
            self.rejected.append((rig.time, counts.last_rejection))

    def on_flags(self, msg: Any, _info: Any = None) -> None:
        """controller/flags (a controller on the per-valve topics)."""
        stamp = msg.header.stamp.sec * NS_PER_S + msg.header.stamp.nanosec
        values = {}
        for st in msg.status:
            for kv in st.values:
                try:
                    values[kv.key] = float(kv.value)
                except ValueError:
                    continue
        self.flags_at(stamp, values)

    def flags_at(self, stamp: int, values: dict[str, float]) -> None:
        """The flags of the answer to the sample stamped `stamp` (ns); the rig node calls it with a
        lockstep command's."""
        k, off = divmod(stamp, self.period_ns)
        if off or not 0 <= k < self.n:
            return
        for key, value in values.items():
            arr = self.flags.get(f"controller.{key}")
            if arr is None:
                arr = self.flags[f"controller.{key}"] = np.full(self.n + 1, np.nan)
            arr[k] = value

    # --- the stop flag ----------------------------------------------------------------------

    @property
    def requested(self) -> bool:
        if self.done or self.failure is not None:
            return True
        if self.node.failure is not None:
            return True
        now = time.monotonic()
        if now - self.progress > self.ros.wait:
            self.failure = (f"no answer from the ROS controller for {self.ros.wait:g} s after the sample at "
                            f"t = {self.node.device.time:.4f} s (waiting for duty_cycle from "
                            f"{', '.join(v for v in self.valves if v not in self.node._answered) or 'none'})")
            return True
        if self.proc is not None and now >= self._next_proc_check:
            self._next_proc_check = now + _PROC_CHECK
            if self.proc.poll() is not None:
                self.failure = f"the controller command exited with {self.proc.returncode} during the run"
                return True
        return False

    @requested.setter
    def requested(self, value: bool) -> None:
        self.done = self.done or value

    def run_record(self) -> RigRun:
        rig = self.node.device
        times = np.arange(self.n + 1) * self.per * rig.dt
        wall = time.perf_counter() - self.wall0
        return RigRun(times, rig.signals, self.true, self.meas, self.duties, self.valves, self.sp, self.flags,
                      list(rig.log), list(rig.rejected) + self.rejected, wall, self.walls)


def _log_tail(path: Path | None, lines: int = 15) -> str:
    if path is None:
        return ""
    try:
        text = path.read_text(errors="replace").strip().splitlines()
    except OSError:
        return ""
    return ("; its output:\n" + "\n".join(text[-lines:])) if text else "; it printed nothing"


def _start(scenario: Scenario, domain: int | None, log_path: Path) -> subprocess.Popen[bytes]:
    spec = scenario.ros
    assert spec is not None and spec.command
    env = {k: v for k, v in os.environ.items() if k != "_ROS_WHEELS_BOOTSTRAP_COMPLETE"}
    if domain is not None:
        env.update(ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    cwd = scenario.path.parent if scenario.path else Path.cwd()
    with open(log_path, "wb") as log:
        try:
            return subprocess.Popen(spec.argv(sys.executable), cwd=cwd, env=env, stdout=log,
                                    stderr=subprocess.STDOUT, start_new_session=True)
        except OSError as err:
            raise ScenarioAborted(f"cannot start the controller command {spec.argv(sys.executable)}: {err}") from None


def _stop(proc: subprocess.Popen[bytes] | None) -> None:
    if proc is None or proc.poll() is not None:
        return
    proc.send_signal(signal.SIGINT)
    try:
        proc.wait(_STOP_GRACE)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(5)


def _wait_for_controller(node: Any, host: _Host, spec: RosController, proc: Any, flags_sub: Any) -> bool:
    """Until the controller's endpoints are matched with the rig's: a publisher on lockstep/command
    and a subscriber of lockstep/sample (the lockstep channel: True), or a publisher on every
    duty_cycle and a subscriber of joint_states (False) (required, within `spec.wait` s, else
    ScenarioAborted), then, given _OPTIONAL_MATCH s more, a setpoint subscriber and, off the
    channel, a flags publisher (a controller of the user's may have neither), then _SETTLE s:
    matched on this side, the controller's side matches within milliseconds (a first sample it
    missed would cost the rig's 0.5 s re-publication)."""
    duty = [(sub.topic_name, sub) for sub in node._answer_subs]
    command = node._channel_sub
    joint, sample = node._samples.publisher(cylinder_topic(JOINT_STATES)), node._pub_sample
    optional: list[tuple[str, Callable[[], bool]]] = [(flags_sub.topic_name, lambda: flags_sub.get_publisher_count() > 0)]
    if host.setpoint is not None:
        optional.append((host._pub_sp.topic_name, lambda: host._pub_sp.get_subscription_count() > 0))
    end = time.monotonic() + spec.wait
    matched_at = None
    while True:
        now = time.monotonic()
        if proc is not None and proc.poll() is not None:
            raise ScenarioAborted(f"the controller command exited with {proc.returncode} before answering")
        channel = bool(command.get_publisher_count() > 0 and sample.get_subscription_count() > 0)
        missing = [] if channel else [f"a publisher on {t}" for t, sub in duty if sub.get_publisher_count() == 0]
        if not channel and joint.get_subscription_count() == 0:
            missing.append(f"a subscriber of {joint.topic_name}")
        if not missing:
            matched_at = matched_at or now
            if all(ok() for _t, ok in optional[channel:]) or now - matched_at > _OPTIONAL_MATCH:
                time.sleep(_SETTLE)
                return channel
        if now > end:
            where = f"namespace {spec.namespace or '/'}, ROS_DOMAIN_ID {os.environ.get('ROS_DOMAIN_ID', '0')}" \
                if proc is None else f"namespace {spec.namespace or '/'}"
            raise ScenarioAborted(f"no ROS controller answered within {spec.wait:g} s ({where}): missing "
                                   f"{', '.join(missing)} (or, on the lockstep channel, a publisher on "
                                   f"{command.topic_name} and a subscriber of {sample.topic_name})")
        time.sleep(0.01)


def run_ros_scenario(scenario: Scenario, *, domain: int | None = None) -> ScenarioResult:
    """Run `scenario` (its controller a ROS node) over DDS; see the module docstring."""
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.context import Context
    from rclpy.parameter import Parameter
    from rclpy.signals import SignalHandlerOptions
    from rclpy.utilities import try_shutdown

    from pcv_sim.node.qos_events import topic_qos
    from pcv_sim.node.rig import rig_node

    spec = scenario.ros
    assert spec is not None
    path = str(scenario.path) if scenario.path else ""
    if domain is not None:
        os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"     # the runner's own domain: this machine only
    context = Context()
    rclpy.init(context=context, domain_id=domain, signal_handler_options=SignalHandlerOptions.NO)
    proc = None
    node = None
    log_dir = tempfile.TemporaryDirectory(prefix="pcv_sim_scenario_")
    log_path = Path(log_dir.name) / "controller.log" if spec.command else None
    wall0 = time.perf_counter()
    host = None
    try:
        overrides = [Parameter("seed", value=scenario.seed), Parameter("time_mode", value="simulated"),
                     Parameter("lockstep", value=True), Parameter("faults.enabled", value=True)]
        if scenario.rig_file is not None:
            overrides.append(Parameter("rig_config", value=str(scenario.rig_file)))
        if log_path is not None:
            proc = _start(scenario, domain, log_path)        # first: its start-up overlaps the rig's
        node = rig_node(argv=["rig"], context=context, namespace=spec.namespace or "/", parameter_overrides=overrides)
        if node.device.params != scenario.rig:
            raise ScenarioAborted("the rig node's rig differs from the scenario's (rig_config)")
        host = _Host(node, scenario, spec, proc, log_path)
        flags_sub = node.add_input(DiagnosticArray, FLAGS_TOPIC, host.on_flags, topic_qos(FLAGS_TOPIC))
        schedule_timeline(node.device, scenario)
        host.channel = channel = _wait_for_controller(node, host, spec, proc, flags_sub)
        if channel:                  # the flags come with the answers; unsubscribed, nobody writes them
            node._inputs = [(sub, h) for sub, h in node._inputs if sub is not flags_sub]
            node.destroy_subscription(flags_sub)
        host.progress = time.monotonic()
        node.hook = host
        node.run(host)
        if not channel and host.failure is None and node.failure is None and host.flags:
            _take_last_flags(node, host)
    except ScenarioAborted as err:
        wall = time.perf_counter() - wall0
        return ScenarioResult(scenario.name, path, False, [], math.nan, wall, f"{err}{_log_tail(log_path)}")
    except PcvSimError as err:        # e.g. a second /clock in the domain (ParameterError)
        wall = time.perf_counter() - wall0
        return ScenarioResult(scenario.name, path, False, [], math.nan, wall, f"the rig node: {err}")
    finally:
        _stop(proc)
        if node is not None:
            node.hook = None
            node.destroy_node()
        try_shutdown(context=context)
        if host is not None and host.failure is not None:
            host.failure += _log_tail(log_path)
        log_dir.cleanup()
    if host.failure is not None or node.failure is not None:
        wall = time.perf_counter() - wall0
        reason = host.failure or f"the run stopped at t = {node.device.time:.4f} s: {node.failure}"
        return ScenarioResult(scenario.name, path, False, [], math.nan, wall, reason, host.run_record())
    return scenario_result(scenario, host.run_record())


def _take_last_flags(node: Any, host: _Host, timeout: float = 1.0) -> None:
    """The flags of the last answered instant may still be on their way: take them."""
    end = time.monotonic() + timeout
    last = host.n - 1
    while time.monotonic() < end:
        node._drain()
        if all(not math.isnan(a[last]) for a in host.flags.values()):
            return
        time.sleep(1e-3)
