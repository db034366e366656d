"""`EmulatorNode`: the valve model as a real-time hardware-in-the-loop device on ROS 2.

Started by `pcv_sim.node.emulator` (the `emulator` executable), which owns the process: signals,
exit status.

A thin adapter: ROS parameters in, `ValveDevice` (pcv_sim.device.valve) in the middle, messages
out. Topic names are relative, so a namespace runs one valve per steering chamber.

    in   duty_cycle       std_msgs/Float64            PWM duty, fraction 0..1           reliable
    in   load_flow        std_msgs/Float64            m^3/s drawn from the load port    reliable
    in   supply_pressure  sensor_msgs/FluidPressure   Pa                                reliable
    out  pressure         sensor_msgs/FluidPressure   Pa, stamped with the model time   sensor data
    out  current          std_msgs/Float64            A                                 sensor data
    out  spool_position   std_msgs/Float64            m (x > 0 opens pump -> load)      sensor data
    out  /diagnostics     diagnostic_msgs/DiagnosticArray, every diagnostics_period (wall)
    out  /clock           rosgraph_msgs/Clock (simulated time only)
    in   /clock           rosgraph_msgs/Clock (use_sim_time only: the model follows it)
    srv  reset            std_srvs/Trigger: back to rest at the present operating point, clears a fault

The loop (no rclpy timer, no executor: both cost far more than the work at 1 kHz)
    Real time: one thread sleeps until the next wake on a fixed grid of the monotonic clock
    (`wake_period`, 1 ms), then: takes every pending input message (`take_message` polling),
    asks the `RealTimeSchedule` which 0.1 ms steps are due (model time = steps * dt, never ahead of
    wall time, never drifting), runs them, publishes the samples that fell due, and every 10th
    wake takes pending service requests: parameter sets and reset go to a worker thread that
    validates them and computes the new rest state (25-60 ms), the loop swaps the result in at
    its next wake and answers (`_pump`); the rest is answered at once. An input takes effect at
    the first model step whose stamp is at or after the input's DDS reception time (and after
    the previous input on its topic). Stamps are model time anchored to the ROS clock at start,
    so they are wall-consistent. Falling behind: `overrun` (catch_up up to max_catchup, or skip).
    Simulated time: model time starts at 0 and runs in chunks of one publish period; see
    `_run_simulated` for when an input takes effect.
    External clock (use_sim_time): the steps up to each new /clock run when it arrives; see
    `_run_external_clock`.

Parameters are declared from `pcv_sim.device.settings` (one declaration each); what rcl leaves
silent is checked by `pcv_sim.device.parameters`; diagnostics are built by `pcv_sim.device.diagnostics`.
QoS incompatibility events are polled with the services (no executor runs their callbacks).

Recorder hook: `EmulatorNode.set_recorder(recorder, every)` makes the device call
`recorder(t_ns, signals)` at every `every`-th model step (see pcv_sim.device.valve.SIGNALS); a
`close()` method, if the recorder has one, is called at shutdown.

Recording (`record.enabled`): a `pcv_sim.io.recorder.BagRecorder` on that hook, called at every
model step from the start (the device at rest; stamps are the samples' model time, in simulated
time from 0), finalized by SIGINT/SIGTERM; a writer process does the disk work, so the loop only
queues samples (pcv_sim.io.writer_process). Its state is in the diagnostics (`recording*` keys).
"""

from __future__ import annotations

import contextlib
import ctypes
import gc
import math
import os
import sys
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any, Protocol

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.event_handler import PublisherEventCallbacks, SubscriptionEventCallbacks
from rclpy.exceptions import InvalidHandle
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSPolicyKind, QoSProfile, qos_profile_sensor_data
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import FluidPressure
from std_msgs.msg import Float64
from std_srvs.srv import Trigger

from pcv_sim.device.diagnostics import DiagnosticsBuilder
from pcv_sim.device.parameters import (
    Override,
    check_params_files,
    command_line_overrides,
    is_ros_own,
    override_not_taken,
    refuse_unknown,
    unknown_parameters_message,
)
from pcv_sim.device.settings import (
    MODEL_PREFIX,
    NODE_PARAMETERS,
    NodeSettings,
    check_node_value,
    model_parameters,
    params_with,
    settings_with,
)
from pcv_sim.device.valve import INPUTS, Recorder, Sample, ValveDevice, WatchdogState
from pcv_sim.errors import BagError, ParameterError
from pcv_sim.io.recorder import SWITCH_INTERVAL, BagRecorder
from pcv_sim.io.topics import (
    CLOCK,
    CURRENT,
    DIAGNOSTICS,
    DUTY_CYCLE,
    LOAD_FLOW,
    PRESSURE,
    RESET,
    SPOOL_POSITION,
    SUPPLY_PRESSURE,
)
from pcv_sim.node.polling import drain, linger_for_rosout
from pcv_sim.params import ValveParams, load_params
from pcv_sim.simulation.clock import (
    NO_CLOCK_YET,
    SIM_TIME_CONFLICT,
    ExternalClock,
    RealTimeSchedule,
    SimulatedSchedule,
)

__all__ = ["EmulatorNode", "StopFlag"]

NODE_NAME = "emulator"
COMMAND_QOS = QoSProfile(depth=10)          # reliable, volatile
DIAGNOSTICS_QOS = QoSProfile(depth=10)
CLOCK_QOS = QoSProfile(depth=10)
SERVICE_POLL_EVERY = 10                     # wakes between service polls (10 ms at 1 kHz)
CLOCK_DISCOVERY = 3.0                       # s a simulated-time node looks for another /clock publisher at start
JOB_SWITCH_INTERVAL = 2e-4                  # s, interpreter switch interval while the worker computes
EVENT_POLL_EVERY = 10                       # service polls between QoS event polls (100 ms at 1 kHz)
LOCKSTEP_RESEND = 0.5                       # s without a command: publish the last sample again
_UNKNOWN_HINT = (f"; model parameters are {MODEL_PREFIX}<section>.<key> for the scalar and vector keys of the "
                 "valve YAML (matrix fits: use valve_config); allow_unknown_parameters: true ignores unknown names")


def _ros_value(value: Any) -> Any:
    """A checked value as a ROS parameter value (ints given for a float parameter stay numbers)."""
    return list(value) if isinstance(value, tuple) else value


class StopFlag(Protocol):
    """Set from outside (the signal handlers of `pcv_sim.node.emulator.main`); the loops poll it."""

    requested: bool


class EmulatorNode(Node):
    """ROS parameters in, `ValveDevice` out. Construct, then `run(stop)`."""

    def __init__(self, *, argv: list[str] | None = None, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        try:
            self._setup(argv)
        except ParameterError as err:
            # Start-up errors also go to /rosout (a launch file's user may only see that), then the
            # half-built node is destroyed here: nobody else holds it.
            self.get_logger().error(f"invalid parameters: {err}")
            linger_for_rosout(self)
            self.destroy_node()
            raise

    def _setup(self, argv: list[str] | None) -> None:
        self._argv = list(sys.argv if argv is None else argv)
        self._retaken: dict[str, Override] = {}      # -p overrides rcl dropped, applied by us
        self._declared: set[str] = set()
        self.settings, params = self._declare_parameters()
        if self._retaken:
            self.set_parameters([Parameter(n, value=_ros_value(o.value)) for n, o in self._retaken.items()])
        dt = params.simulation.time_step
        s = self.settings
        self.simulated = s.time_mode == "simulated"
        self.external_clock = bool(self.get_parameter("use_sim_time").value)
        self.device = ValveDevice(params, safe_duty=s.safe_duty, watchdog_timeout=s.watchdog_timeout,
                                  sample_every=s.sample_every(dt))
        self._external = ExternalClock(self.device.dt_ns)   # use_sim_time: the latest /clock, model time anchored
        # Rest states (25-60 ms of model solves) are computed off the loop: the loop takes parameter
        # and reset requests, a worker thread validates and prepares them, the loop swaps the result
        # in at the next wake and only then answers. One request at a time, in arrival order.
        self._worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="pcv_sim_prepare")
        self._deferred: deque[tuple[Any, Any, Any]] = deque()       # (service, request, header)
        self._job: tuple[Any, Any, Future[Any]] | None = None       # (service, header, answer)
        self._ready: list[Callable[[], None]] = []                  # worker-built, applied by the loop
        self._pending: tuple[NodeSettings, ValveParams] | None = None   # staged within the running job
        self._staged: tuple[NodeSettings, ValveParams, Any] | None = None
        self._schedule: RealTimeSchedule | None = None
        self._sim: SimulatedSchedule | None = None
        self._duty_messages = 0                      # valid or not: the lockstep handshake counts them
        self._last_reject_log = dict.fromkeys(INPUTS, -math.inf)
        self._suppressed = dict.fromkeys(INPUTS, 0)
        self.samples_published = 0
        self._polls = 0
        self._switch_interval = sys.getswitchinterval()
        self._last_input_step: dict[str, int] = {}   # per input topic: the step its last valid value acts at
        self._watchdog_logged = 0                    # firings logged (one line per firing, not per step)

        out, sensor = self._output_events, qos_profile_sensor_data
        self._pub_pressure = self.create_publisher(FluidPressure, PRESSURE, sensor, event_callbacks=out(PRESSURE))
        self._pub_current = self.create_publisher(Float64, CURRENT, sensor, event_callbacks=out(CURRENT))
        self._pub_spool = self.create_publisher(Float64, SPOOL_POSITION, sensor, event_callbacks=out(SPOOL_POSITION))
        self._pub_diag = self.create_publisher(DiagnosticArray, DIAGNOSTICS, DIAGNOSTICS_QOS,
                                               event_callbacks=out(DIAGNOSTICS))
        if self.simulated:
            self._refuse_a_second_clock()
        self._pub_clock = (self.create_publisher(Clock, CLOCK, CLOCK_QOS, event_callbacks=out(CLOCK))
                           if self.simulated else None)
        inp = self._input_events
        self._inputs: list[tuple[Any, Callable[..., None]]] = [
            (self.create_subscription(Float64, DUTY_CYCLE, self._on_duty, COMMAND_QOS,
                                      event_callbacks=inp(DUTY_CYCLE)), self._on_duty),
            (self.create_subscription(Float64, LOAD_FLOW, self._on_load_flow, COMMAND_QOS,
                                      event_callbacks=inp(LOAD_FLOW)), self._on_load_flow),
            (self.create_subscription(FluidPressure, SUPPLY_PRESSURE, self._on_supply, COMMAND_QOS,
                                      event_callbacks=inp(SUPPLY_PRESSURE)), self._on_supply),
        ]
        if self.external_clock:
            self._inputs.append((self.create_subscription(Clock, CLOCK, self._on_clock, CLOCK_QOS,
                                                          event_callbacks=inp(CLOCK)), self._on_clock))
        self._event_handlers = [h for e in (*self.publishers, *self.subscriptions)
                                for h in getattr(e, "event_handlers", ())]
        self.create_service(Trigger, RESET, self._on_reset)
        for srv in self.services:        # rclpy's handlers say "undeclared parameter(s): []": name them
            if srv.srv_name.endswith("/set_parameters"):
                srv.callback = self._on_set_parameters
            elif srv.srv_name.endswith("/set_parameters_atomically"):
                srv.callback = self._on_set_parameters_atomically
        self._msg_pressure = FluidPressure()
        self._msg_pressure.header.frame_id = s.frame_id
        self._msg_current = Float64()
        self._msg_spool = Float64()
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        self._diag = DiagnosticsBuilder(self.get_fully_qualified_name(), time.monotonic())
        self.recorder = self._make_recorder()
        mode = ("simulated time" if self.simulated else "time from an external /clock (use_sim_time)"
                if self.external_clock else "real time")
        self.get_logger().info(
            f"{mode}, samples at {s.publish_rate:g} Hz, "
            f"model step {dt * 1e3:g} ms ({self.device.stepper.integrator}), watchdog "
            f"{s.watchdog_timeout:g} s -> duty {s.safe_duty:g}, valve config {s.valve_config or 'shipped default'}")

    # --- parameters --------------------------------------------------------------------------

    def _declare_parameters(self) -> tuple[NodeSettings, ValveParams]:
        """Declare node and model parameters; refuse invalid ones with a ParameterError.

        Beyond what rcl checks: a params file with a key given twice, a `-p` override that did not
        take (rcl drops one whose type differs from the params file's), and names nobody declares
        (unless allow_unknown_parameters) are refused too (see pcv_sim.device.parameters)."""
        check_params_files(self._argv)
        cli = command_line_overrides(self._argv, self.get_name())
        values = {}
        for spec in NODE_PARAMETERS:
            desc = ParameterDescriptor(description=f"{spec.description} [{spec.unit}]", dynamic_typing=True,
                                       read_only=spec.read_only)
            value = self._taken(spec.name, self.declare_parameter(spec.name, spec.default, desc).value, cli)
            values[spec.name] = check_node_value(spec.name, value)
        settings = NodeSettings.from_parameters(values)
        if self.get_parameter("use_sim_time").value and settings.time_mode == "simulated":
            raise ParameterError(SIM_TIME_CONFLICT)
        params = load_params(settings.valve_config or None)
        changes = {}
        for mp in model_parameters(params):
            desc = ParameterDescriptor(description=f"[{mp.unit}] {mp.source}", dynamic_typing=True)
            value = self._taken(mp.name, self.declare_parameter(mp.name, mp.value, desc).value, cli)
            if value != mp.value:
                changes[mp.name] = value
        overrides = set(getattr(self, "_parameter_overrides", {}) or {}) | set(cli)
        self._declared = {spec.name for spec in NODE_PARAMETERS} | {mp.name for mp in model_parameters(params)}
        unknown = sorted(n for n in overrides if n not in self._declared and not is_ros_own(n))
        if unknown and not settings.allow_unknown_parameters:
            refuse_unknown(unknown, self._declared, hint=_UNKNOWN_HINT)
        if unknown:
            self.get_logger().warning(f"ignoring unknown parameter(s) (allow_unknown_parameters): {', '.join(unknown)}")
        if changes:
            params = params_with(params, changes)
        return settings.check(params), params

    def _taken(self, name: str, declared: Any, cli: dict[str, Override]) -> Any:
        """The value the command line asked for if rcl dropped it (it is then checked like any value)."""
        override = cli.get(name)
        if override is None or not override_not_taken(override, declared):
            return declared
        self._retaken[name] = override
        return override.value

    def _set_checked(self, parameters: list[Parameter]) -> SetParametersResult:
        unknown = [p.name for p in parameters if not self.has_parameter(p.name)]
        if unknown:
            return SetParametersResult(successful=False, reason=unknown_parameters_message(
                unknown, self._declared, hint=_UNKNOWN_HINT.split("; allow_unknown", maxsplit=1)[0]))
        return self.set_parameters_atomically(parameters)

    def _on_set_parameters(self, request: Any, response: Any) -> Any:
        """SetParameters service: one result per parameter, each set on its own (as rclpy does)."""
        for msg in request.parameters:
            response.results.append(self._set_checked([Parameter.from_parameter_msg(msg)]))
        return response

    def _on_set_parameters_atomically(self, request: Any, response: Any) -> Any:
        response.result = self._set_checked([Parameter.from_parameter_msg(m) for m in request.parameters])
        return response

    def _validate_parameters(self, parameters: list[Any]) -> SetParametersResult:
        """on-set callback (worker thread): validate the whole change with the model's rules, prepare
        the new model's rest state; stage it (the loop applies it, `_pump`)."""
        node_changes: dict[str, Any] = {}
        model_changes: dict[str, Any] = {}
        names = {spec.name for spec in NODE_PARAMETERS}
        for p in parameters:
            if p.name.startswith(MODEL_PREFIX):
                model_changes[p.name] = p.value
            elif p.name in names:
                node_changes[p.name] = p.value
            elif p.name == "use_sim_time" and bool(p.value) != self.external_clock:
                return SetParametersResult(successful=False, reason=(
                    "use_sim_time is fixed while the node runs (the model's clock is chosen at start): restart "
                    f"with -p use_sim_time:={'true' if p.value else 'false'}"))
        base_settings, base_params = self._pending or (self.settings, self.device.params)
        try:
            settings = settings_with(base_settings, node_changes)
            params = params_with(base_params, model_changes, runtime=True) if model_changes else base_params
            settings.check(params)
            stepper = self.device.prepare(params) if model_changes else None
        except (ParameterError, ValueError) as err:
            return SetParametersResult(successful=False, reason=str(err))
        except Exception as err:
            return SetParametersResult(successful=False,
                                       reason=f"the model cannot run with these parameters: {type(err).__name__}: {err}")
        self._staged = (settings, params, stepper)
        return SetParametersResult(successful=True)

    def _apply_parameters(self, parameters: list[Any]) -> None:
        """post-set callback (worker thread): queue what `_validate_parameters` staged for the loop."""
        if self._staged is None:
            return
        settings, params, stepper = self._staged
        self._staged = None
        self._pending = (settings, params)
        names = ", ".join(p.name for p in parameters if p.name.startswith(MODEL_PREFIX))
        self._ready.append(lambda: self._apply(settings, stepper, names))

    def _apply(self, settings: NodeSettings, stepper: Any, names: str) -> None:
        """On the loop, between wakes: the new settings and model in force from the next step."""
        dev = self.device
        self.settings = settings
        dev.set_watchdog_timeout(settings.watchdog_timeout)
        dev.set_safe_duty(settings.safe_duty)
        dev.sample_every = settings.sample_every(dev.dt)
        self._msg_pressure.header.frame_id = settings.frame_id
        if self._schedule is not None:
            self._schedule.late_threshold = settings.late_threshold
            self._schedule.max_catchup_steps = int(settings.catchup_bound / dev.dt)
        if self._sim is not None and self._sim.factor != settings.real_time_factor:
            self._sim.set_factor(settings.real_time_factor)
        if stepper is not None:
            what = dev.install(stepper)
            self.get_logger().info(f"model parameters changed ({names}): model restarted at rest at the present "
                                   f"operating point: {what}")

    # --- QoS events ----------------------------------------------------------------------------

    def _output_events(self, topic: str) -> PublisherEventCallbacks:
        hint = ("subscribe best effort (QoSProfile(depth=1000, reliability=BEST_EFFORT); "
                "ros2 topic echo --qos-reliability best_effort)") if topic in (PRESSURE, CURRENT, SPOOL_POSITION) \
            else "subscribe with a compatible QoS (reliable, volatile)"
        return PublisherEventCallbacks(incompatible_qos=lambda info: self._incompatible(
            topic, "a subscriber", info, hint))

    def _input_events(self, topic: str) -> SubscriptionEventCallbacks:
        return SubscriptionEventCallbacks(incompatible_qos=lambda info: self._incompatible(
            topic, "a publisher", info, "publish reliable (the default of ros2 topic pub and of QoSProfile(depth=10))"))

    def _incompatible(self, topic: str, them: str, info: Any, hint: str) -> None:
        try:
            policy = QoSPolicyKind(info.last_policy_kind).name
        except ValueError:
            policy = str(info.last_policy_kind)
        self.get_logger().warning(
            f"QoS incompatible on {topic!r}: {them} has a {policy} policy the node's endpoint cannot match; no "
            f"messages flow between them ({info.total_count} such endpoint(s) so far). To connect: {hint}")

    def _poll_events(self) -> None:
        """Run the QoS event callbacks (no executor runs them here): take each event's status, call back
        when its count changed. ~2 us per endpoint; polled with the services."""
        for handler in self._event_handlers:
            try:
                handler._ready_to_take_data = True     # what a wait set would mark; then rclpy's own take
                info = handler.take_data()
            except (InvalidHandle, AttributeError, RuntimeError):
                continue
            if info is not None and getattr(info, "total_count_change", 0) > 0:
                handler.callback(info)

    # --- recording ---------------------------------------------------------------------------

    def _make_recorder(self) -> BagRecorder | None:
        """The bag recorder asked for by record.* (None when off); ParameterError if it cannot start."""
        s, dev = self.settings, self.device
        if not s.record_enabled:
            return None
        try:
            recorder = BagRecorder(
                os.path.expanduser(s.record_directory), name=s.record_name or None, signals=s.record_signals,
                every=s.record_every(dev.dt), dt_ns=dev.dt_ns, namespace=self.get_namespace(),
                frame_id=s.frame_id,
                split_size_bytes=round(s.record_split_size_mb * 1e6) if s.record_split_size_mb else None,
                writer="process",     # the disk work off the loop's interpreter lock (pcv_sim.io.writer_process)
                when_full="wait" if self.simulated else "drop")    # simulated time may outrun the writer
        except BagError as err:
            raise ParameterError(f"record.directory / record.name: cannot record: {err}") from None
        self.set_recorder(recorder, 1)      # every step: inputs stamped exactly, outputs decimated inside
        return recorder

    def _start_recording(self) -> None:
        """Anchor the recording at the present model time, the device at rest."""
        rec = self.recorder
        if rec is None:
            return
        dev = self.device
        rec.start(dev.stamp_ns(), dev.signals())
        if rec.threaded:
            sys.setswitchinterval(SWITCH_INTERVAL)
        self.get_logger().info(
            f"recording {', '.join(rec.signals)} to {rec.path} (outputs every {rec.every * dev.dt * 1e3:g} ms of "
            f"model time, inputs on change)")

    def _stop_recording(self) -> None:
        rec = self.recorder
        close = getattr(self.device.recorder, "close", None)
        if rec is None:
            if callable(close):
                close()
            return
        st = rec.close()
        text = (f"bag {st.path}: {st.messages} messages, {st.bytes} bytes in {st.files} file(s)"
                f"{f', {st.dropped} messages dropped' if st.dropped else ''}")
        if st.error:
            self.get_logger().error(f"recording failed ({st.error}); {text}")
        else:
            self.get_logger().info(f"recording finished: {text}")

    # --- recorder hook -----------------------------------------------------------------------

    def set_recorder(self, recorder: Recorder | None, every: int = 1) -> None:
        """Call `recorder(t_ns, signals)` at every `every`-th model step (None: stop recording)."""
        self.device.record_every = max(1, int(every))
        self.device.recorder = recorder

    # --- inputs ------------------------------------------------------------------------------

    def _at_step(self, info: Any) -> int | None:
        """The step at which an input received at `info['received_timestamp']` takes effect."""
        if self._schedule is None:
            return None          # simulated time: at the present model time (the next chunk's start)
        dev = self.device
        # The message was received by now at the latest: the first step at or after this instant
        # of the monotonic clock (the schedule's), immune to steps of the system clock.
        taken = -(-round((time.monotonic() - self._schedule.t0) * 1e9) // dev.dt_ns)
        r_ns = info.get("received_timestamp", 0) if isinstance(info, dict) else 0
        if not r_ns:
            return taken
        # ceil: the first step stamped at or after the DDS reception time (system clock, as the stamps).
        # Never later than `taken` (a system clock stepped forward); never earlier than the reception,
        # whatever the wake-up lag (the schedule's slot may be far behind `now` under load).
        return min(-(-(r_ns - dev.origin_ns) // dev.dt_ns), taken)

    def _input(self, name: str, value: float, info: Any) -> None:
        # Two inputs on one topic never act at the same step (a starved DDS thread can receive
        # several at once): the later acts one step after the earlier, so none is lost unseen.
        at = max(self._at_step(info) or 0, self._last_input_step.get(name, -1) + 1, self.device.steps + 1)
        reason = self.device.submit(name, value, at)
        if reason is not None:
            self._log_rejection(name, reason)
        else:
            self._last_input_step[name] = at

    def _on_duty(self, msg: Float64, info: Any = None) -> None:
        self._duty_messages += 1
        self._input(DUTY_CYCLE, msg.data, info)

    def _on_clock(self, msg: Clock, _info: Any = None) -> None:
        self._external.take(msg.clock.sec * 1_000_000_000 + msg.clock.nanosec)

    def _on_load_flow(self, msg: Float64, info: Any = None) -> None:
        self._input(LOAD_FLOW, msg.data, info)

    def _on_supply(self, msg: FluidPressure, info: Any = None) -> None:
        self._input(SUPPLY_PRESSURE, msg.fluid_pressure, info)

    def _log_rejection(self, name: str, reason: str) -> None:
        now = time.monotonic()
        if now - self._last_reject_log[name] < self.settings.reject_log_period:
            self._suppressed[name] += 1
            return
        more = self._suppressed[name]
        self._suppressed[name] = 0
        self._last_reject_log[name] = now
        tail = f" ({more} more rejected since the last message)" if more else ""
        self.get_logger().warning(f"rejected {name}: {reason}; the last valid value stays in force{tail}")

    def _drain(self) -> int:
        """Take every pending input message (no executor: `take_message` polling)."""
        return drain(self._inputs)

    def _poll_services(self) -> None:
        """Answer pending service requests the way an executor would; parameter sets and reset go
        to the worker thread (`_pump`), the rest is answered here."""
        deferred = (self._on_set_parameters, self._on_set_parameters_atomically, self._on_reset)
        for srv in list(self.services):
            while True:
                try:
                    with srv.handle:
                        request, header = srv.handle.service_take_request(srv.srv_type.Request)
                except InvalidHandle:
                    break
                if header is None:
                    break
                if srv.callback in deferred:
                    self._deferred.append((srv, request, header))
                else:
                    srv.send_response(srv.callback(request, srv.srv_type.Response()), header)
        self._pump()
        self._polls += 1
        if self._polls % EVENT_POLL_EVERY == 0:
            self._poll_events()

    def _pump(self) -> None:
        """At a step boundary: apply a finished worker job (new model, settings) and answer its request;
        start the next one. Cheap when idle: called at every wake."""
        job = self._job
        if job is not None:
            srv, header, answer = job
            if not answer.done():
                return
            self._job = None
            sys.setswitchinterval(self._switch_interval)
            for apply in self._ready:
                apply()
            self._ready.clear()
            self._pending = None
            srv.send_response(answer.result(), header)
        if self._deferred:
            srv, request, header = self._deferred.popleft()
            # While the worker computes (~40 ms of Python) the loop waits for the interpreter lock at
            # each wake: a short switch interval hands it over sooner (bench/node_restart.py).
            self._switch_interval = sys.getswitchinterval()
            sys.setswitchinterval(JOB_SWITCH_INTERVAL)
            self._job = (srv, header, self._worker.submit(self._serve, srv, request))

    def _serve(self, srv: Any, request: Any) -> Any:
        """Worker thread: one deferred request; an unexpected error is logged and answered, not raised."""
        response = srv.srv_type.Response()
        try:
            return srv.callback(request, response)
        except Exception as err:
            self._staged = None
            self._ready.clear()
            self.get_logger().error(f"{srv.srv_name}: {type(err).__name__}: {err}")
            if hasattr(response, "message"):
                response.success, response.message = False, f"{type(err).__name__}: {err}"
            return response

    def _on_reset(self, _request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        """Worker thread: the rest state at the present operating point, on trial; the loop installs it."""
        try:
            stepper = self.device.prepare()
        except Exception as err:
            response.success = False
            response.message = f"reset failed: {type(err).__name__}: {err}"
            self.get_logger().error(response.message)
            return response

        def install() -> None:
            response.message = self.device.install(stepper)
            response.success = True
            self.get_logger().info(f"reset: {response.message}")

        self._ready.append(install)
        return response

    # --- outputs -----------------------------------------------------------------------------

    def _stamp(self, ns: int) -> Any:
        stamp = self._msg_pressure.header.stamp
        stamp.sec, stamp.nanosec = divmod(ns, 1_000_000_000)
        return stamp

    def _run_steps(self, n: int) -> list[Sample]:
        """Run n model steps; log what the device did that a user must hear about (once per event)."""
        dev = self.device
        was_fired = dev.watchdog_state == WatchdogState.FIRED
        samples = dev.run(n)
        if dev.watchdog_fired != self._watchdog_logged:
            self._watchdog_logged = dev.watchdog_fired
            t = self.settings.watchdog_timeout
            self.get_logger().warning(
                f"watchdog: no valid duty_cycle command for {t:g} s (model time): the duty fell to safe_duty "
                f"{dev.safe_duty:g}. Send the duty at least every {t:g} s (a controller does; by hand: ros2 topic pub "
                f"-r 10 duty_cycle std_msgs/msg/Float64 '{{data: 0.7}}'), or raise watchdog_timeout (0 = off). "
                "The next valid command resumes.")
        elif was_fired and dev.watchdog_state != WatchdogState.FIRED:
            self.get_logger().info(f"watchdog: duty commands resumed, duty {dev.duty_command_in_force:g}")
        return samples

    def _publish(self, samples: list[Sample]) -> None:
        dev = self.device
        for s in samples:
            self._stamp(dev.stamp_ns(s.step))
            self._msg_pressure.fluid_pressure = s.pressure
            self._msg_current.data = s.current
            self._msg_spool.data = s.spool_position
            self._pub_pressure.publish(self._msg_pressure)
            self._pub_current.publish(self._msg_current)
            self._pub_spool.publish(self._msg_spool)
        self.samples_published += len(samples)

    def _publish_clock(self) -> None:
        msg = Clock()
        msg.clock.sec, msg.clock.nanosec = divmod(self.device.stamp_ns(), 1_000_000_000)
        assert self._pub_clock is not None          # created in simulated time, the only caller
        self._pub_clock.publish(msg)

    def diagnostics(self, now: float) -> list[DiagnosticStatus]:
        """The device's health, one status per concern (see pcv_sim.device.diagnostics)."""
        rec = self.recorder.status() if self.recorder is not None else None
        out = []
        for st in self._diag.build(now, device=self.device, settings=self.settings, schedule=self._schedule,
                                   recorder=rec, samples_published=self.samples_published,
                                   time_mode="external_clock" if self.external_clock else None):
            msg = DiagnosticStatus(level=bytes([st.level]), name=st.name, message=st.message,
                                   hardware_id=st.hardware_id)
            msg.values = [KeyValue(key=k, value=v) for k, v in st.values.items()]
            out.append(msg)
        return out

    def _publish_diagnostics(self, now: float) -> None:
        msg = DiagnosticArray()
        # The node's ROS clock is not updated without an executor; the model time is the device's clock.
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(
            self.device.stamp_ns() if self.simulated or self.external_clock else time.time_ns(), 1_000_000_000)
        msg.status = self.diagnostics(now)
        self._pub_diag.publish(msg)

    # --- loops -------------------------------------------------------------------------------

    def run(self, stop: StopFlag) -> None:
        """Run until stop.requested (SIGINT/SIGTERM)."""
        try:
            if self.simulated:
                self._run_simulated(stop)
            elif self.external_clock:
                self._run_external_clock(stop)
            else:
                self._run_real_time(stop)
        finally:
            self._worker.shutdown(wait=True, cancel_futures=True)
            self._stop_recording()

    def _run_real_time(self, stop: StopFlag) -> None:
        """Wake on the grid, take inputs, run the due steps, publish; see RealTimeSchedule."""
        s, dev = self.settings, self.device
        sched = RealTimeSchedule(dev.dt, wake_period=s.wake_period, late_threshold=s.late_threshold,
                                 max_catchup=s.catchup_bound)
        self._schedule = sched
        _tighten_timer_slack()
        # The worker thread (rest states) competes for the interpreter lock: hand it back within one
        # wake period rather than the default 5 ms.
        sys.setswitchinterval(SWITCH_INTERVAL)
        if s.realtime_priority:
            self._set_realtime_priority(s.realtime_priority)
        _freeze_heap()
        mono = time.monotonic
        sched.start()
        dev.origin_ns = self.get_clock().now().nanoseconds
        self._start_recording()
        self._diag.restart(mono(), dev.steps)
        next_diag = mono() + s.diagnostics_period
        self._publish([dev.sample()])
        wake = 0
        cpu = time.thread_time
        while not stop.requested:
            now = mono()
            c0 = cpu()
            self._drain()
            plan = sched.plan(now)
            if plan.skipped:
                dev.skip(plan.skipped)
                st = self.settings
                bound = (f"max_catchup {st.max_catchup * 1e3:g} ms" if st.overrun == "catch_up"
                         else "one wake period, overrun: skip")
                self.get_logger().warning(
                    f"{plan.lag * 1e3:.1f} ms behind wall time (more than {bound}): "
                    f"skipped {plan.skipped} steps, the model state was held over them",
                    throttle_duration_sec=1.0)
            if plan.steps:
                self._publish(self._run_steps(plan.steps))
            sched.finish()
            wake += 1
            if wake % SERVICE_POLL_EVERY == 0:
                self._poll_services()
            elif self._job is not None:
                self._pump()
            sched.note_wake_cpu(cpu() - c0)
            if now >= next_diag:
                self._publish_diagnostics(now)
                next_diag = max(next_diag + self.settings.diagnostics_period, now)
            delay = sched.next_wake() - mono()
            if delay > 0.0:
                time.sleep(delay)

    def _set_realtime_priority(self, priority: int) -> None:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        except (OSError, AttributeError) as err:
            self.get_logger().warning(f"realtime_priority {priority}: SCHED_FIFO refused ({err}); running with "
                                      "normal scheduling (grant an rtprio limit or run as root)")
        else:
            self.get_logger().info(f"loop thread under SCHED_FIFO, priority {priority}")

    def _run_simulated(self, stop: StopFlag) -> None:
        """Simulated time: model time from 0, chunks of one publish period, /clock published.

        Each chunk: publish /clock and the sample at model time T, take the pending inputs, which
        take effect at T + dt (the sample at T has shown the inputs in force at T), then compute
        [T, T + 1/publish_rate].
        With `lockstep` (default) the node waits, before computing a chunk, for one duty_cycle
        message received after the last sample was published: a controller that answers every
        sample with one command sees exactly the same run each time (its command for the sample
        at T acts from T + dt on). Without lockstep the chunks run back to back (paced by
        real_time_factor) and an input acts from the chunk after its arrival, which depends on
        wall-clock timing. If a sample goes unanswered for 0.5 s (e.g. the controller was not yet
        connected) it is published again.
        """
        s, dev = self.settings, self.device
        sim = SimulatedSchedule(dev.dt, factor=s.real_time_factor)
        self._sim = sim
        _freeze_heap()
        mono = time.monotonic
        dev.origin_ns = 0
        self._start_recording()
        sim.start()
        self._diag.restart(mono(), dev.steps)
        next_diag = mono() + s.diagnostics_period
        answered = self._duty_messages

        def publish_now() -> float:
            self._publish_clock()
            if dev.fault is None:
                self._publish([dev.sample()])
            return mono()

        published = publish_now()
        loops = 0
        while not stop.requested:
            loops += 1
            self._drain()
            now = mono()
            waiting = self.settings.lockstep and self._duty_messages == answered
            if waiting or dev.fault is not None or loops % SERVICE_POLL_EVERY == 0:
                self._poll_services()
            if now >= next_diag:
                self._publish_diagnostics(now)
                next_diag = max(next_diag + self.settings.diagnostics_period, now)
            if dev.fault is not None:
                time.sleep(1e-3)          # model time stands still until reset
                continue
            if waiting:
                if now - published > LOCKSTEP_RESEND:
                    published = publish_now()
                time.sleep(1e-4)
                continue
            chunk = dev.sample_every - dev.steps % dev.sample_every
            ready = sim.ready_at(chunk)
            if ready > now:
                time.sleep(min(ready - now, 1e-3))
                continue
            answered = self._duty_messages
            samples = self._run_steps(chunk)
            sim.advance(chunk)
            self._publish_clock()
            self._publish(samples)
            published = mono()


    def _refuse_a_second_clock(self) -> None:
        """Two simulated-time emulators would both publish /clock, and every node with use_sim_time would
        see time jump between them. Before creating its own /clock publisher the node looks for another
        one for up to CLOCK_DISCOVERY s (discovery is usually done within the node's creation; under
        load it can take longer) and refuses to start if it finds one. Only the newcomer looks, so a
        running simulation is never stopped by a second one."""
        end = time.monotonic() + CLOCK_DISCOVERY
        while True:
            others = self.count_publishers(CLOCK)
            if others > 0 or time.monotonic() >= end:
                break
            time.sleep(0.05)
        if others > 0:
            raise ParameterError(
                    f"time_mode: simulated: {others} other publisher(s) of {CLOCK} found; two clocks make time jump "
                    "for every node that follows /clock. Accepted is one clock: run this emulator with "
                    "use_sim_time:=true (time_mode real) to follow the other clock, or simulate several valves "
                    "in one process (the multi-valve rig)")

    def _run_external_clock(self, stop: StopFlag) -> None:
        """use_sim_time: model time follows an external /clock (e.g. a Gazebo simulation).

        Model time 0 is the first /clock received (stamps = that clock); whenever /clock advances,
        the steps up to it run and the samples that fell due are published. An input acts from the
        step after the last one run when it was taken. The clock going back (a simulation reset)
        re-anchors model time at the new clock, keeping the model's state."""
        s, dev = self.settings, self.device
        _freeze_heap()
        mono = time.monotonic
        ext = self._external
        self._diag.restart(mono(), dev.steps)
        next_diag = mono() + s.diagnostics_period
        loops = 0
        while not stop.requested:
            loops += 1
            self._drain()
            now = mono()
            if loops % SERVICE_POLL_EVERY == 0:
                self._poll_services()
            elif self._job is not None:
                self._pump()
            if now >= next_diag:
                self._publish_diagnostics(now)
                next_diag = max(next_diag + self.settings.diagnostics_period, now)
            if ext.latest_ns is None:
                if loops == 2000:           # ~2 s: say why nothing is published
                    self.get_logger().warning(NO_CLOCK_YET)
                time.sleep(1e-3)
                continue
            if not ext.started:
                dev.origin_ns = ext.start(dev.steps)
                self._start_recording()
                self._publish([dev.sample()])
                continue
            plan = ext.plan(dev.steps)
            if plan.reanchored:
                dev.origin_ns = ext.origin_ns
                self.get_logger().warning(ext.went_back(), throttle_duration_sec=1.0)
            elif plan.skip:
                dev.skip(plan.skip)
                self.get_logger().warning(ext.jumped(plan.skip), throttle_duration_sec=1.0)
            elif plan.run:
                self._publish(self._run_steps(plan.run))
            else:
                time.sleep(2e-4)           # wait for the clock to advance


def _tighten_timer_slack() -> None:
    """Ask Linux for 1 ns timer slack (default 50 us): wakes land ~50 us closer to the grid."""
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL(None, use_errno=True).prctl(29, 1, 0, 0, 0)   # PR_SET_TIMERSLACK


def _freeze_heap() -> None:
    """Move everything allocated so far (rclpy, numpy, scipy, the model: ~50 000 objects) out of
    the garbage collector's reach. A full collection over them takes ~17 ms here, which would
    make a wake-up that many ms late; the loop itself only makes short-lived objects."""
    gc.collect()
    gc.freeze()
