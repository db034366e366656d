"""The `emulator` node: the valve model as a real-time hardware-in-the-loop device on ROS 2.

    ros2 run pcv_sim emulator --ros-args --params-file config/emulator.yaml
    python -m pcv_sim.node.emulator --ros-args -r __ns:=/left -p watchdog_timeout:=0.2

A thin adapter: ROS parameters in, `ValveDevice` (pcv_sim.node.device) in the middle, messages
out. Topic names are relative, so a namespace runs one valve per steering chamber.

    in   duty_cycle       std_msgs/Float64            PWM duty, fraction 0..1           reliable
    in   load_flow        std_msgs/Float64            m^3/s drawn from the load port    reliable
    in   supply_pressure  sensor_msgs/FluidPressure   Pa                                reliable
    out  pressure         sensor_msgs/FluidPressure   Pa, stamped with the model time   sensor data
    out  current          std_msgs/Float64            A                                 sensor data
    out  spool_position   std_msgs/Float64            m (x > 0 opens pump -> load)      sensor data
    out  /diagnostics     diagnostic_msgs/DiagnosticArray, every diagnostics_period (wall)
    out  /clock           rosgraph_msgs/Clock (simulated time only)
    srv  reset            std_srvs/Trigger: back to rest at the present operating point, clears a fault

The loop (no rclpy timer, no executor: both cost far more than the work at 1 kHz)
    Real time: one thread sleeps until the next wake on a fixed grid of the monotonic clock
    (`wake_period`, 1 ms), then: takes every pending input message (`take_message` polling),
    asks the `RealTimeSchedule` which 0.1 ms steps are due (model time = steps * dt, never ahead of
    wall time, never drifting), runs them, publishes the samples that fell due, and every 10th
    wake answers pending service requests (parameters, reset). An input takes effect at the
    first model step whose stamp is at or after the input's DDS reception time. Stamps are
    model time anchored to the ROS clock at start, so they are wall-consistent.
    Simulated time: model time starts at 0 and runs in chunks of one publish period; see
    `_run_simulated` for when an input takes effect.

Recorder hook: `EmulatorNode.set_recorder(recorder, every)` makes the device call
`recorder(t_ns, signals)` at every `every`-th model step (see pcv_sim.node.device.SIGNALS); a
`close()` method, if the recorder has one, is called at shutdown.

Recording (`record.enabled`): a `pcv_sim.io.recorder.BagRecorder` on that hook, called at every
model step from the start (the device at rest; stamps are the samples' model time, in simulated
time from 0), finalized by SIGINT/SIGTERM; a writer thread does the disk work, so the loop only
queues samples. Its state is in the diagnostics (`recording*` keys).
"""

from __future__ import annotations

import argparse
import ctypes
import gc
import math
import os
import signal
import sys
import time
from typing import Any, Callable

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.exceptions import InvalidHandle
from rclpy.node import Node
from rclpy.qos import QoSProfile, qos_profile_sensor_data
from rclpy.signals import SignalHandlerOptions
from rclpy.utilities import remove_ros_args
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import FluidPressure
from std_msgs.msg import Float64
from std_srvs.srv import Trigger

from pcv_sim.errors import BagError, ParameterError
from pcv_sim.io.recorder import SWITCH_INTERVAL, BagRecorder, RecorderStatus
from pcv_sim.node.device import INPUTS, Recorder, Sample, ValveDevice, WatchdogState
from pcv_sim.node.settings import (
    MODEL_PREFIX, NODE_PARAMETERS, NodeSettings, check_node_value, model_parameters, params_with,
    settings_with,
)
from pcv_sim.params import ValveParams, load_params
from pcv_sim.simulation.clock import RealTimeSchedule, SimulatedSchedule

__all__ = ["EmulatorNode", "main"]

NODE_NAME = "emulator"
COMMAND_QOS = QoSProfile(depth=10)          # reliable, volatile
DIAGNOSTICS_QOS = QoSProfile(depth=10)
CLOCK_QOS = QoSProfile(depth=10)
SERVICE_POLL_EVERY = 10                     # wakes between service polls (10 ms at 1 kHz)
LOCKSTEP_RESEND = 0.5                       # s without a command: publish the last sample again
_ROS_OWN_PARAMETERS = ("use_sim_time", "start_type_description_service", "qos_overrides.")


class Stop:
    """Set by SIGINT/SIGTERM; the loop checks it at every wake."""

    def __init__(self) -> None:
        self.requested = False
        self.signal: int | None = None

    def __call__(self, signum: int, _frame: Any) -> None:
        self.requested = True
        self.signal = signum


class EmulatorNode(Node):
    """ROS parameters in, `ValveDevice` out. Construct, then `run(stop)`."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        self.settings, params = self._declare_parameters()
        dt = params.simulation.time_step
        s = self.settings
        self.simulated = s.time_mode == "simulated"
        self.device = ValveDevice(params, safe_duty=s.safe_duty, watchdog_timeout=s.watchdog_timeout,
                                  sample_every=s.sample_every(dt))
        self._staged: tuple[NodeSettings, Any] | None = None
        self._schedule: RealTimeSchedule | None = None
        self._sim: SimulatedSchedule | None = None
        self._duty_messages = 0                      # valid or not: the lockstep handshake counts them
        self._last_reject_log = dict.fromkeys(INPUTS, -math.inf)
        self._suppressed = dict.fromkeys(INPUTS, 0)
        self.samples_published = 0

        self._pub_pressure = self.create_publisher(FluidPressure, "pressure", qos_profile_sensor_data)
        self._pub_current = self.create_publisher(Float64, "current", qos_profile_sensor_data)
        self._pub_spool = self.create_publisher(Float64, "spool_position", qos_profile_sensor_data)
        self._pub_diag = self.create_publisher(DiagnosticArray, "/diagnostics", DIAGNOSTICS_QOS)
        self._pub_clock = self.create_publisher(Clock, "/clock", CLOCK_QOS) if self.simulated else None
        self._inputs = [
            (self.create_subscription(Float64, "duty_cycle", self._on_duty, COMMAND_QOS), self._on_duty),
            (self.create_subscription(Float64, "load_flow", self._on_load_flow, COMMAND_QOS), self._on_load_flow),
            (self.create_subscription(FluidPressure, "supply_pressure", self._on_supply, COMMAND_QOS),
             self._on_supply),
        ]
        self.create_service(Trigger, "reset", self._on_reset)
        self._msg_pressure = FluidPressure()
        self._msg_pressure.header.frame_id = s.frame_id
        self._msg_current = Float64()
        self._msg_spool = Float64()
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        self._diag_wall = time.monotonic()
        self._diag_steps = 0
        self._diag_counts: dict[str, int] = {}
        self._diag_dropped = 0
        self.recorder = self._make_recorder()
        self.get_logger().info(
            f"{'simulated' if self.simulated else 'real'} time, samples at {s.publish_rate:g} Hz, "
            f"model step {dt * 1e3:g} ms ({self.device.stepper.integrator}), watchdog "
            f"{s.watchdog_timeout:g} s -> duty {s.safe_duty:g}, valve config {s.valve_config or 'shipped default'}")

    # --- parameters --------------------------------------------------------------------------

    def _declare_parameters(self) -> tuple[NodeSettings, ValveParams]:
        """Declare node and model parameters; refuse invalid ones with a ParameterError."""
        values = {}
        for spec in NODE_PARAMETERS:
            desc = ParameterDescriptor(description=f"{spec.description} [{spec.unit}]", dynamic_typing=True,
                                       read_only=spec.read_only)
            value = self.declare_parameter(spec.name, spec.default, desc).value
            values[spec.name] = check_node_value(spec.name, value)
        settings = NodeSettings.from_parameters(values)
        if self.get_parameter("use_sim_time").value:
            raise ParameterError("use_sim_time: the emulator keeps its own time (time_mode real or simulated, "
                                 "where it publishes /clock itself); leave use_sim_time false")
        params = load_params(settings.valve_config or None)
        changes = {}
        for mp in model_parameters(params):
            desc = ParameterDescriptor(description=f"[{mp.unit}] {mp.source}", dynamic_typing=True)
            value = self.declare_parameter(mp.name, mp.value, desc).value
            if value != mp.value:
                changes[mp.name] = value
        overrides = getattr(self, "_parameter_overrides", {}) or {}
        declared = {spec.name for spec in NODE_PARAMETERS} | {mp.name for mp in model_parameters(params)}
        unknown = sorted(n for n in overrides if n not in declared and not n.startswith(_ROS_OWN_PARAMETERS))
        bad_model = [n for n in unknown if n.startswith(MODEL_PREFIX)]
        if bad_model:
            raise ParameterError(
                f"unknown model parameter(s) {', '.join(bad_model)}; accepted are {MODEL_PREFIX}<section>.<key> "
                "for the scalar and vector keys of the valve YAML (matrix fits: use valve_config)")
        if unknown:
            self.get_logger().warning(f"ignoring unknown parameter(s): {', '.join(unknown)}")
        if changes:
            params = params_with(params, changes, origin="ROS parameters")
        return settings.check(params), params

    def _validate_parameters(self, parameters: list[Any]) -> SetParametersResult:
        """on-set callback: validate the whole change with the model's rules; stage it."""
        node_changes: dict[str, Any] = {}
        model_changes: dict[str, Any] = {}
        names = {spec.name for spec in NODE_PARAMETERS}
        for p in parameters:
            if p.name.startswith(MODEL_PREFIX):
                model_changes[p.name] = p.value
            elif p.name in names:
                node_changes[p.name] = p.value
            elif p.name == "use_sim_time" and p.value:
                return SetParametersResult(successful=False, reason="use_sim_time: the emulator keeps its own time")
        try:
            settings = settings_with(self.settings, node_changes)
            params = (params_with(self.device.params, model_changes, runtime=True)
                      if model_changes else self.device.params)
            settings.check(params)
            stepper = self.device.prepare(params) if model_changes else None
        except (ParameterError, ValueError) as err:
            return SetParametersResult(successful=False, reason=str(err))
        except Exception as err:  # noqa: BLE001 - e.g. no equilibrium for these parameters: refuse, keep running
            return SetParametersResult(successful=False,
                                       reason=f"the model cannot run with these parameters: {type(err).__name__}: {err}")
        self._staged = (settings, stepper)
        return SetParametersResult(successful=True)

    def _apply_parameters(self, parameters: list[Any]) -> None:
        """post-set callback: apply what `_validate_parameters` staged."""
        if self._staged is None:
            return
        settings, stepper = self._staged
        self._staged = None
        dev = self.device
        self.settings = settings
        dev.set_watchdog_timeout(settings.watchdog_timeout)
        dev.set_safe_duty(settings.safe_duty)
        dev.sample_every = settings.sample_every(dev.dt)
        self._msg_pressure.header.frame_id = settings.frame_id
        if self._schedule is not None:
            self._schedule.late_threshold = settings.late_threshold
            self._schedule.max_catchup_steps = int(settings.max_catchup / dev.dt)
        if self._sim is not None and self._sim.factor != settings.real_time_factor:
            self._sim.set_factor(settings.real_time_factor)
        if stepper is not None:
            dev.install(stepper)
            names = ", ".join(p.name for p in parameters if p.name.startswith(MODEL_PREFIX))
            self.get_logger().info(f"model parameters changed ({names}): model restarted at rest at the present "
                                   f"operating point, {dev.stepper.pressure / 1e5:.2f} bar")

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

    def _recording_values(self, values: dict[str, Any], problems: list[str]) -> None:
        rec = self.recorder
        if rec is None:
            values["recording"] = "off"
            return
        st: RecorderStatus = rec.status()
        new_dropped = st.dropped - self._diag_dropped
        self._diag_dropped = st.dropped
        if st.error:
            problems.append(f"recording failed: {st.error}")
        if new_dropped:
            problems.append(f"recording dropped {new_dropped} messages in the last period")
        values.update({
            "recording": st.state,
            "recording_path": str(st.path),
            "recording_messages": st.messages,
            "recording_bytes": st.bytes,
            "recording_files": st.files,
            "recording_queued": st.queued,
            "recording_dropped": st.dropped,
            "recording_error": st.error,
        })

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
        reason = self.device.submit(name, value, self._at_step(info))
        if reason is not None:
            self._log_rejection(name, reason)

    def _on_duty(self, msg: Float64, info: Any = None) -> None:
        self._duty_messages += 1
        self._input("duty_cycle", msg.data, info)

    def _on_load_flow(self, msg: Float64, info: Any = None) -> None:
        self._input("load_flow", msg.data, info)

    def _on_supply(self, msg: FluidPressure, info: Any = None) -> None:
        self._input("supply_pressure", msg.fluid_pressure, info)

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
        """Take every pending input message (no executor: `take_message` polling, ~2 us per empty topic)."""
        taken = 0
        for sub, handler in self._inputs:
            while True:
                try:
                    with sub.handle:
                        got = sub.handle.take_message(sub.msg_type, sub.raw)
                except InvalidHandle:
                    break
                if got is None:
                    break
                handler(*got)
                taken += 1
        return taken

    def _poll_services(self) -> None:
        """Answer pending service requests (parameters, reset) the way an executor would."""
        for srv in list(self.services):
            while True:
                try:
                    with srv.handle:
                        request, header = srv.handle.service_take_request(srv.srv_type.Request)
                except InvalidHandle:
                    break
                if header is None:
                    break
                response = srv.callback(request, srv.srv_type.Response())
                srv.send_response(response, header)

    def _on_reset(self, _request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        try:
            response.message = self.device.reset()
            response.success = True
            self.get_logger().info(f"reset: {response.message}")
        except Exception as err:  # noqa: BLE001 - the device stays as it was; the caller learns why
            response.success = False
            response.message = f"reset failed: {type(err).__name__}: {err}"
            self.get_logger().error(response.message)
        return response

    # --- outputs -----------------------------------------------------------------------------

    def _stamp(self, ns: int) -> Any:
        stamp = self._msg_pressure.header.stamp
        stamp.sec, stamp.nanosec = divmod(ns, 1_000_000_000)
        return stamp

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
        self._pub_clock.publish(msg)

    def diagnostics(self, now: float) -> DiagnosticStatus:
        """The device's health as one DiagnosticStatus (values as strings, SI units in the key names)."""
        dev, s = self.device, self.settings
        wall = max(now - self._diag_wall, 1e-9)
        rtf = (dev.steps - self._diag_steps) * dev.dt / wall
        counts = {f"rejected.{k}": v for k, v in dev.counts.rejected.items()}
        sched = self._schedule
        if sched is not None:
            counts["late_steps"] = sched.late_steps
            counts["skipped_steps"] = sched.skipped_steps
        new = {k: v - self._diag_counts.get(k, 0) for k, v in counts.items()}
        self._diag_wall, self._diag_steps, self._diag_counts = now, dev.steps, counts
        last = dev.last_good
        st = DiagnosticStatus()
        st.name = f"{self.get_fully_qualified_name()}: pcv_sim valve emulator"
        st.hardware_id = self.get_fully_qualified_name()
        problems = []
        if dev.fault is not None:
            st.level = DiagnosticStatus.ERROR
            problems.append(f"model fault: {dev.fault}; call the reset service")
        if dev.watchdog_state == WatchdogState.FIRED:
            problems.append(f"watchdog: no duty command for {s.watchdog_timeout:g} s, safe duty {dev.safe_duty:g}")
        if new.get("late_steps") or new.get("skipped_steps"):
            problems.append(f"{new['late_steps']} late and {new['skipped_steps']} skipped steps in the last "
                            f"{wall:.1f} s")
        rejected = {k[len('rejected.'):]: v for k, v in new.items() if k.startswith("rejected.") and v}
        if rejected:
            problems.append("rejected inputs: " + ", ".join(f"{k} {v}" for k, v in rejected.items()))
        recording: dict[str, Any] = {}
        self._recording_values(recording, problems)
        if dev.fault is None:
            st.level = DiagnosticStatus.WARN if problems else DiagnosticStatus.OK
        waiting = dev.watchdog_state == WatchdogState.WAITING
        st.message = "; ".join(problems) if problems else ("running, waiting for the first duty command"
                                                           if waiting else "running")
        values: dict[str, Any] = {
            "time_mode": s.time_mode,
            "model_time_s": f"{dev.time:.4f}",
            "real_time_factor": f"{rtf:.4f}",
            "model": "fault" if dev.fault else "ok",
            "fault_reason": dev.fault or "",
            "watchdog": dev.watchdog_state,
            "watchdog_timeout_s": f"{s.watchdog_timeout:g}",
            "watchdog_fired_count": dev.watchdog_fired,
            "safe_duty": f"{dev.safe_duty:g}",
            "duty_command": f"{dev.duty_command_in_force:g}",
            "duty_effective": f"{last.duty:g}" if last else "",
            "duty_applied_stamp_ns": dev.stamp_ns(dev.duty_applied_step) if dev.duty_applied_step is not None else "",
            "watchdog_fired_stamp_ns": (dev.stamp_ns(dev.watchdog_fired_step)
                                        if dev.watchdog_fired_step is not None else ""),
            "model_time_origin_ns": dev.origin_ns,
            "pressure_pa": f"{last.pressure:.1f}" if last else "",
            "pressure_bar": f"{last.pressure / 1e5:.3f}" if last else "",
            "current_a": f"{last.current:.5f}" if last else "",
            "spool_position_m": f"{last.spool_position:.4e}" if last else "",
            "load_flow_m3s": f"{dev.load_flow:g}",
            "supply_pressure_pa": f"{dev.stepper.supply_pressure:g}",
            "integrator": dev.stepper.integrator,
            "samples_published": self.samples_published,
            "last_rejection": dev.counts.last_rejection,
        }
        for k in INPUTS:
            values[f"accepted.{k}"] = dev.counts.accepted[k]
            values[f"rejected.{k}"] = dev.counts.rejected[k]
        if sched is not None:
            period_lag, period_lag_after = sched.take_period_max()
            values.update({
                "late_steps": sched.late_steps,
                "skipped_steps": sched.skipped_steps,
                "late_threshold_ms": f"{s.late_threshold * 1e3:g}",
                "lag_ms": f"{sched.lag_after * 1e3:.3f}",
                "max_lag_ms": f"{sched.max_lag * 1e3:.3f}",
                "max_lag_after_step_ms": f"{sched.max_lag_after * 1e3:.3f}",
                "period_max_lag_ms": f"{period_lag * 1e3:.3f}",
                "period_max_lag_after_step_ms": f"{period_lag_after * 1e3:.3f}",
                "wakes": sched.wakes,
            })
        else:
            values["lockstep"] = str(s.lockstep).lower()
            values["real_time_factor_set"] = f"{s.real_time_factor:g}"
        values.update(recording)
        st.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
        return st

    def _publish_diagnostics(self, now: float) -> None:
        msg = DiagnosticArray()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.status = [self.diagnostics(now)]
        self._pub_diag.publish(msg)

    # --- loops -------------------------------------------------------------------------------

    def run(self, stop: Stop) -> None:
        """Run until stop.requested (SIGINT/SIGTERM)."""
        try:
            if self.simulated:
                self._run_simulated(stop)
            else:
                self._run_real_time(stop)
        finally:
            self._stop_recording()

    def _run_real_time(self, stop: Stop) -> None:
        """Wake on the grid, take inputs, run the due steps, publish; see RealTimeSchedule."""
        s, dev = self.settings, self.device
        sched = RealTimeSchedule(dev.dt, wake_period=s.wake_period, late_threshold=s.late_threshold,
                                 max_catchup=s.max_catchup)
        self._schedule = sched
        _tighten_timer_slack()
        if s.realtime_priority:
            self._set_realtime_priority(s.realtime_priority)
        _freeze_heap()
        mono = time.monotonic
        sched.start()
        dev.origin_ns = self.get_clock().now().nanoseconds
        self._start_recording()
        self._diag_wall = mono()
        next_diag = self._diag_wall + s.diagnostics_period
        self._publish([dev.sample()])
        wake = 0
        while not stop.requested:
            now = mono()
            self._drain()
            plan = sched.plan(now)
            if plan.skipped:
                dev.skip(plan.skipped)
                self.get_logger().warning(
                    f"{plan.lag * 1e3:.1f} ms behind wall time (more than max_catchup {s.max_catchup * 1e3:g} ms): "
                    f"skipped {plan.skipped} steps, the model state was held over them",
                    throttle_duration_sec=1.0)
            if plan.steps:
                self._publish(dev.run(plan.steps))
            sched.finish()
            wake += 1
            if wake % SERVICE_POLL_EVERY == 0:
                self._poll_services()
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

    def _run_simulated(self, stop: Stop) -> None:
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
        self._diag_wall = mono()
        next_diag = self._diag_wall + s.diagnostics_period
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
            samples = dev.run(chunk)
            sim.advance(chunk)
            self._publish_clock()
            self._publish(samples)
            published = mono()


def _tighten_timer_slack() -> None:
    """Ask Linux for 1 ns timer slack (default 50 us): wakes land ~50 us closer to the grid."""
    try:
        ctypes.CDLL(None, use_errno=True).prctl(29, 1, 0, 0, 0)   # PR_SET_TIMERSLACK
    except (OSError, AttributeError):
        pass


def _freeze_heap() -> None:
    """Move everything allocated so far (rclpy, numpy, scipy, the model: ~50 000 objects) out of
    the garbage collector's reach. A full collection over them takes ~17 ms here, which would
    make a wake-up that many ms late; the loop itself only makes short-lived objects."""
    gc.collect()
    gc.freeze()


def _parameter_help() -> str:
    lines = ["parameters (--ros-args -p NAME:=VALUE, or --params-file config/emulator.yaml):"]
    for spec in NODE_PARAMETERS:
        lines.append(f"  {spec.name} = {spec.default!r} [{spec.unit}]{' (read-only)' if spec.read_only else ''}")
        lines.append(f"      {spec.description}")
    lines.append(f"  {MODEL_PREFIX}<section>.<key>: the valve model's scalar and vector parameters "
                 "(config/valve.yaml), e.g. model.spool.mass")
    return "\n".join(lines)


def main(args: list[str] | None = None) -> int:
    """Console entry point `emulator`. Returns 0 after SIGINT/SIGTERM, 2 for invalid parameters."""
    argv = list(sys.argv if args is None else args)
    parser = argparse.ArgumentParser(
        prog="emulator", formatter_class=argparse.RawDescriptionHelpFormatter, epilog=_parameter_help(),
        description="Hydraulic proportional pressure control valve emulator (ROS 2 node). Topics: in duty_cycle, "
                    "load_flow, supply_pressure; out pressure, current, spool_position, /diagnostics.")
    parser.parse_args(remove_ros_args(argv)[1:])
    stop = Stop()
    rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    previous: dict[int, Callable[..., Any] | int | None] = {}
    for sig in (signal.SIGINT, signal.SIGTERM):
        previous[sig] = signal.signal(sig, stop)
    node = None
    try:
        try:
            node = EmulatorNode()
        except ParameterError as err:
            print(f"emulator: invalid parameters: {err}", file=sys.stderr)
            return 2
        node.run(stop)
        node.get_logger().info(f"stopping on {signal.Signals(stop.signal).name}" if stop.signal else "stopping")
        return 0
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
        for sig, handler in previous.items():
            signal.signal(sig, handler)


if __name__ == "__main__":
    sys.exit(main())
