"""The example controller node's parameters over real DDS: declared from their one declaration
(pcv_sim.control.params.PositionControllerParams), refused with its messages at start (exit 2) and
at run time (`ros2 param set`: a bad value, an unknown name, a read-only one), and a change of the
gains in force in the node's control law (a run after it is the callable's with those gains, bit
for bit). The node runs in its own process, in the test's own ROS domain (test/node/conftest.py)."""
import dataclasses
import threading
import time
from pathlib import Path

import numpy as np
import rclpy
from rcl_interfaces.srv import DescribeParameters, GetParameters, SetParameters
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState

from pcv_sim.control.steering import PositionController
from pcv_sim.node.client_services import SERVICE_AGAIN, call_service
from pcv_sim.testing import run_rig_scenario

from .test_scenario_ros import assert_same_run, start_controller

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
START = 60.0                       # s: a node's start under load (a python process, DDS discovery)


def test_an_unknown_parameter_at_start_exits_2_naming_the_one_meant(ros):
    """As the device nodes (a bad value: test_scenario_ros.py's period:=0.0)."""
    ctl = start_controller(ros, args=["-p", "coil_ohms:=5.0"])
    assert ctl.wait(START) == 2, ctl.output()
    assert ("invalid parameters: unknown parameter(s) coil_ohms (did you mean coil_ohm?); accepted are the node's "
            "parameters (--help)") in ctl.output()


class ParameterCalls:
    """`ros2 param set | get | describe` against the controller node, from a node of the test's."""

    def __init__(self, ros, name):
        self.node = rclpy.create_node("param_caller", context=ros.context)
        self.executor = SingleThreadedExecutor(context=ros.context)
        self.executor.add_node(self.node)
        self.target = f"{ros.ns(name)}/steering_controller"

    def call(self, srv_type, service, request):
        client = self.node.create_client(srv_type, f"{self.target}/{service}")
        try:
            return call_service(self.executor, client, request, START, again=SERVICE_AGAIN)
        finally:
            self.node.destroy_client(client)

    def set(self, values):
        return self.call(SetParameters, "set_parameters", SetParameters.Request(
            parameters=[Parameter(k, value=v).to_parameter_msg() for k, v in values.items()])).results

    def get(self, names):
        values = self.call(GetParameters, "get_parameters", GetParameters.Request(names=names)).values
        return [Parameter.from_parameter_msg(type("P", (), {"name": n, "value": v})()).value
                for n, v in zip(names, values)]

    def describe(self, names):
        return self.call(DescribeParameters, "describe_parameters", DescribeParameters.Request(names=names)).descriptors

    def close(self):
        self.executor.shutdown()
        self.node.destroy_node()


def test_a_run_time_change_of_the_gains_is_checked_and_in_force_in_the_next_run(ros):
    """`ros2 param set` on the idle node: the gains change (a numeric text for a float, as `ros2
    param set` sends 6e1, is the number), a bad value, an unknown name and the read-only period
    are refused with their reasons; the descriptors say unit, range and read-only. The run after
    the change is the in-process controller's with the new gains, to the last bit."""
    ctl = start_controller(ros)
    calls = ParameterCalls(ros, "rig")
    try:
        kp, period, channel = calls.describe(["kp", "period", "lockstep_channel"])
        assert kp.description == "proportional gain on the position error; accepted 0 .. 10000 [duty/m]"
        assert not kp.read_only and period.read_only and channel.read_only
        cases = {
            "kp": (30.0, None),
            "ki": ("6e1", None),
            "kv": (-0.5, "kv: got -0.5; accepted is a gain in 0 .. 1000 (duty/(m/s))"),
            "period": (0.002, "read-only"),
            "kpp": (1.0, "unknown parameter(s) kpp (did you mean kp?)"),
        }
        results = calls.set({k: v for k, (v, _) in cases.items()})
        for (name, (_, reason)), result in zip(cases.items(), results):
            assert result.successful == (reason is None), (name, result.reason)
            assert reason is None or reason in result.reason, (name, result.reason)
        assert calls.get(["kp", "ki", "kv", "period"]) == [30.0, 60.0, 0.5, 0.001]
    finally:
        calls.close()
    assert "parameters changed: kp = 30.0" in ctl.output() and "parameters changed: ki = 60.0" in ctl.output()

    ros_ctl = {"ros": {"namespace": ros.ns("rig"), "wait": 60}}
    retuned = run_rig_scenario(EXAMPLES / "step.yaml", ros_ctl, duration=0.4)
    expected = run_rig_scenario(EXAMPLES / "step.yaml", duration=0.4, controller_params={"kp": 30.0, "ki": 60.0})
    assert_same_run(retuned.run, expected.run)
    default = run_rig_scenario(EXAMPLES / "step.yaml", duration=0.4)
    assert not (retuned.run.duties == default.run.duties).all()     # the change made a difference



class RetunedAt:
    """The in-process controller with `gains` put in force from the period at `t` on."""

    def __init__(self, t, **gains):
        self.law, self.t, self.gains = PositionController(), t, gains

    def __call__(self, t, m):
        if self.gains and t >= self.t:
            self.law.retune(dataclasses.replace(self.law.params, **self.gains))
            self.gains = None
        return self.law(t, m)


def test_a_change_while_the_node_runs_acts_between_two_periods_and_keeps_the_state(ros, cpu_load):
    """kp set while a scenario runs (once the piston moves), two busy processes beside: the run is the in-process
    controller's retuned at the first period its duties leave the default run's, bit for bit, so
    the change acted between two periods on the running law's integral and held samples."""
    ctl = start_controller(ros)
    calls = ParameterCalls(ros, "rig")
    answered = []
    calls.node.create_subscription(JointState, f"{ros.ns('rig')}/lockstep/command",
                                   lambda msg: answered.append(msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9),
                                   QoSProfile(depth=1000, reliability=ReliabilityPolicy.BEST_EFFORT))
    ros_ctl = {"ros": {"namespace": ros.ns("rig"), "wait": 60}}
    runs = []
    runner = threading.Thread(target=lambda: runs.append(run_rig_scenario(EXAMPLES / "step.yaml", ros_ctl)))
    runner.start()
    try:
        end = time.monotonic() + START
        while not (answered and answered[-1] > 0.12) and time.monotonic() < end and runner.is_alive():
            calls.executor.spin_once(timeout_sec=0.01)
        assert answered and answered[-1] > 0.12, ctl.output()
        assert calls.set({"kp": 30.0})[0].successful
    finally:
        runner.join()
        calls.close()
    run = runs[0].run
    default = run_rig_scenario(EXAMPLES / "step.yaml").run
    differs = np.flatnonzero(np.any(run.duties != default.duties, axis=1))
    assert differs.size and run.times[differs[0]] > 0.12, "the change acted before it was made"
    assert differs[0] < len(run.times) - 1, "the change did not act within the run (the run was too short)"
    assert_same_run(run, run_rig_scenario(EXAMPLES / "step.yaml", RetunedAt(run.times[differs[0]], kp=30.0)).run)
