"""The `steering_controller` executable: the example steering position controller as a ROS 2 node.

    ros2 run pcv_sim steering_controller --ros-args -r __ns:=/rig -p use_sim_time:=true
    python -m pcv_sim.node.steering_controller --ros-args -p period:=0.01

The control law is `pcv_sim.control.steering.PositionController`, the class a scenario calls
in-process (examples/steering.py): the node only moves its inputs and outputs over DDS. It talks
to the rig node (`ros2 run pcv_sim rig`) in its namespace, in lockstep: every control period it
takes the sample the rig published (stamped with its model time), calls the controller with it
and answers with both valves' duties and its flags, over the rig's lockstep channel
(`pcv_sim.node.lockstep_channel`; `pcv_sim.node.client.RigClient`, no executor: `take_message`
and a wait set, as the rig). Topics, relative to the namespace:

    in   lockstep/sample         sensor_msgs/JointState      the rig's signals (Pa, A, m, m/s, N) by name,
                                                             stamp = model time; a scenario's `setpoint`
    out  lockstep/command        sensor_msgs/JointState      `left.duty`, `right.duty` (fraction) and
                                                             `controller.fault_detected`, stamped with the
                                                             sample answered, one per period
    in   setpoint                std_msgs/Float64            m: the position to hold; the latest
                                                             received holds (0 before the first); a
                                                             setpoint in the sample comes first
    out  controller/flags        diagnostic_msgs/DiagnosticArray, one per period while it has a
                                 subscriber, published before the command: header.stamp = the
                                 answered sample's model time; one status `steering_controller`
                                 (level ERROR while fault_detected, else OK) with a KeyValue per
                                 flag, the value as repr(float) (`fault_detected`: "0.0" or "1.0")

Parameters, each declared once (unit, range, default, doc) and refused with its declaration's
message, at start (exit 2) and at run time: the controller's gains and settings (kp, ki, kv,
base, period, fault_time, coil_volts, coil_ohm, current_loop:
`pcv_sim.control.params.PositionControllerParams`, docs/files.md has their table), changed with
`ros2 param set` between two control periods (the integral and the held samples carry over;
`period` is fixed while the node runs); `lockstep_channel` (true;
false: the rig's per-valve topics, `<valve>/pressure`, `<valve>/current`, `cylinder/joint_states`
in, one `<valve>/duty_cycle` per valve and `controller/flags` out, a period complete when
joint_states, published last, has come); `period` must be the rig's
control period (1 ms in config/rig.yaml; a warning says so when the samples come at another
rate). With `use_sim_time: true` the node's clock follows the rig's model time: each sample's
stamp, the /clock the rig publishes with it (taken from the sample, not from /clock: one message
less per period);
the controller's time is always the sample's stamp. A sample stamped before the last one answered
(the rig started again, the next scenario) starts a fresh controller (and forgets the setpoint
unless one came with that sample). Exit status as the rig:
0 after SIGINT/SIGTERM, 2 for invalid parameters.
"""

from __future__ import annotations

import dataclasses
import statistics
import sys
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from pcv_sim.control.params import PositionControllerParams
from pcv_sim.device.settings import NodeParameter, parameters_of
from pcv_sim.node.process import Stop, main_process, parameter_help, run_node
from pcv_sim.params import any_value, setting
from pcv_sim.units import NS_PER_S

__all__ = ["DECLARING", "NODE_NAME", "STATUS_NAME", "VALVES", "ControllerNodeSettings", "PeriodCheck", "main",
           "node_parameters"]

NODE_NAME = "steering_controller"
STATUS_NAME = "steering_controller"
CHANNEL_PARAMETER = "lockstep_channel"
VALVES = ("left", "right")        # the valves PositionController drives (chambers a and b)


class PeriodCheck:
    """Do the samples come at the controller's period? Judged once, from the median of the first
    `intervals` intervals between sample stamps, against `tolerance` (relative) of the period.

    One interval says little: stamps in real time are epoch seconds, which a float64 resolves to
    ~0.24 µs (an exact 1 ms reads as 0.9998-1.0004 ms), and a sample the rig skipped doubles an
    interval. A wrong period (the rig's control period 2 ms, the controller's 1 ms) moves the
    median by 100 %."""

    def __init__(self, period: float, *, intervals: int = 50, tolerance: float = 0.01) -> None:
        self.period = period
        self.intervals = intervals
        self.tolerance = tolerance
        self._last: float | None = None
        self._seen: list[float] = []
        self.done = False

    def restart(self) -> None:
        """A new run of samples (the rig started again): the next interval is not across the restart."""
        self._last = None

    def __call__(self, t: float) -> str | None:
        """The sample stamped `t` (s); the warning text once the median shows another period."""
        last, self._last = self._last, t
        if self.done or last is None:
            return None
        self._seen.append(t - last)
        if len(self._seen) < self.intervals:
            return None
        self.done = True
        median = statistics.median(self._seen)
        if abs(median - self.period) <= self.tolerance * self.period:
            return None
        return (f"samples {median * 1e3:.4g} ms apart (median of {len(self._seen)}), the controller's period is "
                f"{self.period * 1e3:g} ms: set -p period:={median:.4g} (the rig's control_period)")


@dataclass(frozen=True)
class ControllerNodeSettings:
    """The node's own setting, beside the controller's gains and settings
    (`pcv_sim.control.params.PositionControllerParams`)."""

    lockstep_channel: bool = setting(
        True, "-", "answer over the rig's lockstep channel (lockstep/sample, lockstep/command); false: the "
        "per-valve topics", any_value, "bool", read_only=True)


#: What the node declares, each from its one declaration: the controller's, then the node's own.
DECLARING = (PositionControllerParams, ControllerNodeSettings)


def node_parameters() -> tuple[NodeParameter, ...]:
    """The node's parameters as it declares them (`pcv_sim.device.settings.NodeParameter`, as the
    device nodes' settings): the controller's, then the node's own."""
    return tuple(p for cls in DECLARING for p in parameters_of(cls))


def make_node(argv: list[str], **kwargs: Any) -> Any:
    """The node (rclpy initialized); ParameterError for an invalid parameter."""
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    from rcl_interfaces.msg import SetParametersResult
    from rosgraph_msgs.msg import Clock
    from std_msgs.msg import Float64

    from pcv_sim.control.params import controller_params
    from pcv_sim.control.steering import PositionController
    from pcv_sim.device.parameters import check_params_files, command_line_overrides
    from pcv_sim.errors import ParameterError
    from pcv_sim.io.topics import CONTROLLER_FLAGS as FLAGS_TOPIC
    from pcv_sim.io.topics import SETPOINT as SETPOINT_TOPIC
    from pcv_sim.node.client import RigClient
    from pcv_sim.node.parameters import NodeParameters
    from pcv_sim.node.polling import linger_for_rosout
    from pcv_sim.node.qos_events import QosEvents, topic_qos
    from pcv_sim.node.services import ServicePolling
    from pcv_sim.node.tuning import freeze_heap, tighten_timer_slack

    gain_names = frozenset(f.name for f in dataclasses.fields(PositionControllerParams))

    class SteeringControllerNode(NodeParameters, ServicePolling, QosEvents):
        """PositionController between the rig's samples and its duty commands; `run(stop)`. Its
        parameters as the device nodes': declared from their declarations, refused with their
        messages at start and at run time (`pcv_sim.node.parameters`), a change of the gains checked
        on the service worker and put in force by the loop between two periods as theirs
        (`NodeParameters.check_change`, `queue_change`; `pcv_sim.node.services`, polled by the
        client's run)."""

        def __init__(self) -> None:
            super().__init__(NODE_NAME, **kwargs)
            self._init_services()
            self._init_parameters()
            self._init_qos_events()
            try:
                check_params_files(argv)
                self._cli = command_line_overrides(argv, NODE_NAME)
                self.gains, self.channel = self._declare()
            except ParameterError as err:
                self.get_logger().error(f"invalid parameters: {err}")
                linger_for_rosout(self)
                self.destroy_node()
                raise
            self.law = PositionController(self.gains)
            self.setpoint: float | None = None
            self._setpoint_fresh = False
            self.client = RigClient(None, VALVES, node=self, currents=True, history=False, channel=self.channel)
            # Taken by the client's poll with its MessageInfo (jazzy's rclpy types callbacks as (msg) only).
            on_setpoint: Callable[..., None] = self._on_setpoint
            sub = self.create_subscription(Float64, SETPOINT_TOPIC, on_setpoint, topic_qos(SETPOINT_TOPIC))
            self.client.add_input(sub, on_setpoint)
            self._pub_flags = self.create_publisher(DiagnosticArray, FLAGS_TOPIC, topic_qos(FLAGS_TOPIC))
            self._msg_flags = DiagnosticArray(status=[DiagnosticStatus(name=STATUS_NAME)])
            self._clock_msg = Clock()
            self._drop_clock_subscription()
            self._period_check = PeriodCheck(self.gains.period)
            self._start_line = (
                f"steering controller: valves {', '.join(VALVES)}, period {self.gains.period * 1e3:g} ms, "
                + ", ".join(f"{k} {v:g}" for k, v in dataclasses.asdict(self.gains).items() if k != "period")
                + f"; setpoint on {self.resolve_topic_name(SETPOINT_TOPIC)}, flags on "
                f"{self.resolve_topic_name(FLAGS_TOPIC)}; waiting for the rig's samples")

        def _declare(self) -> tuple[PositionControllerParams, bool]:
            """Every parameter declared and checked by its declaration; names nobody declares refused."""
            specs = {p.name: p for p in node_parameters()}
            values = self.declare_settings(specs.values(), lambda name, value: specs[name].check(name, value))
            self.refuse_unknown_names(False)
            self.set_retaken()
            self.take_parameter_services(bool(self.get_parameter("use_sim_time").value), False)
            self.add_on_set_parameters_callback(self._check_change)
            self.add_post_set_parameters_callback(self._queue_change)
            return (PositionControllerParams(**{k: v for k, v in values.items() if k in gain_names}),
                    bool(values[CHANNEL_PARAMETER]))

        def _check_change(self, parameters: list[Any]) -> SetParametersResult:
            """on-set callback (the service worker): the gains with the change, checked as at start
            (rclpy refuses the read-only ones), put in force by the loop between two periods
            (`_pump`, `_retune`), the request answered only then."""
            return self.check_change(parameters, self._gains_with)

        def _gains_with(self, parameters: list[Any]) -> PositionControllerParams | None:
            """The gains with the change (None: it changes none). The base is the node's parameters,
            which hold the changes of the request so far (one request sets each of its parameters
            on its own, all put in force after it)."""
            changes = {p.name: p.value for p in parameters if p.name in gain_names}
            if not changes:
                return None
            now = {name: self.get_parameter(name).value for name in gain_names}
            return controller_params({**now, **changes}, where=NODE_NAME)

        def _queue_change(self, parameters: list[Any]) -> None:
            """post-set callback: the staged gains queued for the loop."""
            self.queue_change(parameters, self._retune)

        def _retune(self, gains: PositionControllerParams) -> None:
            self.gains = gains
            self.law.retune(gains)

        def _drop_clock_subscription(self) -> None:
            """use_sim_time: the TimeSource's /clock subscription goes (no executor would take it); the
            clock is set from each sample's stamp instead, the same instants."""
            ts = getattr(self, "_time_source", None)
            sub = getattr(ts, "_clock_sub", None)
            if ts is not None and sub is not None:
                self.destroy_subscription(sub)
                ts._clock_sub = None

        def _follow(self, t: float) -> None:
            ts = getattr(self, "_time_source", None)
            if ts is None or not ts.ros_time_is_active:
                return
            if ts._clock_sub is not None:      # use_sim_time switched on at run time
                self._drop_clock_subscription()
            clock = self._clock_msg.clock
            clock.sec, clock.nanosec = divmod(round(t * 1e9), NS_PER_S)
            ts.clock_callback(self._clock_msg)

        def _on_setpoint(self, msg: Any, _info: Any) -> None:
            self.setpoint = msg.data
            self._setpoint_fresh = True        # received since the last answer

        def _control(self, t: float, measured: Mapping[str, float]) -> Any:
            m = dict(measured)
            self._setpoint_fresh = False
            if "setpoint" in m:                # the scenario's, with the sample: the topic's may be late
                self.setpoint = m["setpoint"]
            elif self.setpoint is not None:
                m["setpoint"] = self.setpoint
            self._follow(t)
            wrong = self._period_check(t)
            if wrong is not None:
                self.get_logger().warning(wrong)
            return self.law(t, m)

        def _rewind(self) -> Any:
            self.get_logger().info("a sample before the last one answered: the rig started again; a fresh "
                                   "controller")
            self.law = PositionController(self.gains)
            self._period_check.restart()
            if not self._setpoint_fresh:       # the new run sent none before its first sample: it has none
                self.setpoint = None
            return self._control

        def _publish_flags(self, stamp_ns: int, flags: Mapping[str, float]) -> None:
            # One message refilled every period (publish serializes it at once): building the
            # array, its status and key-values anew cost more than the control law.
            if not self._pub_flags.get_subscription_count():
                return                         # nobody reads them (a scenario runner has them in the command)
            msg, st = self._msg_flags, self._msg_flags.status[0]
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, NS_PER_S)
            fault = flags.get("fault_detected", 0.0) != 0.0
            st.level = DiagnosticStatus.ERROR if fault else DiagnosticStatus.OK
            st.message = "coil fault detected" if fault else "ok"
            if [kv.key for kv in st.values] != list(flags):
                st.values = [KeyValue(key=k) for k in flags]
            for kv, v in zip(st.values, flags.values()):
                kv.value = repr(v)
            self._pub_flags.publish(msg)

        def run(self, stop: Stop) -> None:
            if not stop.requested:          # said once a signal is a clean stop (as the device nodes')
                self.get_logger().info(self._start_line)
            tighten_timer_slack()        # wait-set timeouts land on time
            freeze_heap()                # no 17 ms collection over rclpy's objects in a period
            try:
                self.client.run(self._control, None, timeout=None, stop=stop, on_flags=self._publish_flags,
                                rewind=self._rewind, on_poll=self._poll_services)
            finally:
                self._stop_worker()

    return SteeringControllerNode()


def main(args: list[str] | None = None) -> int:
    """Console entry point `steering_controller`: 0 after SIGINT/SIGTERM, 2 for invalid parameters."""
    return main_process(_run, args)


def _run(argv: list[str], stop: Stop) -> int:
    return run_node(
        NODE_NAME, argv, stop, make_node=make_node,
        description="The example steering position controller (pcv_sim.control.steering) as a ROS 2 node, in "
                    "lockstep with the rig node in its namespace: in <valve>/pressure, <valve>/current, "
                    "cylinder/joint_states, setpoint (std_msgs/Float64, m); out <valve>/duty_cycle, "
                    "controller/flags (diagnostic_msgs/DiagnosticArray stamped with the sample's model time).",
        epilog=lambda: parameter_help(
            [dataclasses.replace(p, description=p.described) for p in node_parameters()], "FILE",
            "period must be the rig's control period; the others but "
            f"{CHANNEL_PARAMETER} change between two periods (ros2 param set)",
            "use_sim_time follows the rig's model time"))


if __name__ == "__main__":
    sys.exit(main())
