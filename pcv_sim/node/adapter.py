"""`EmulatorNode`: the valve model as a real-time hardware-in-the-loop device on ROS 2.

Started by `pcv_sim.node.emulator` (the `emulator` executable), which owns the process: signals,
exit status.

A thin adapter: ROS parameters in, `ValveDevice` (pcv_sim.device.valve) in the middle, messages
out. Topic names are relative, so a namespace runs one valve per steering chamber.

    in   duty_cycle       std_msgs/Float64            PWM duty, fraction 0..1           reliable
    in   load_flow        std_msgs/Float64            m^3/s drawn from the load port    reliable
    in   supply_pressure  sensor_msgs/FluidPressure   Pa                                reliable
    in   faults           std_msgs/String             {fault: coil_open} (YAML; faults.enabled only)
    in   ambient_temperature, oil_temperature   std_msgs/Float64, K    (the valve's options, when on:
    out  coil_temperature (K), coil_resistance (ohm), core_position (m) std_msgs/Float64   io.topics.OPTION_INTERFACE)
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
    wall time, never drifting), runs them, publishes the samples that fell due, and every 10 ms
    takes pending service requests: parameter sets and reset go to a worker thread that
    validates them and computes the new rest state (25-60 ms), the loop swaps the result in at
    its next wake and answers (`_pump`); the rest is answered at once. An input takes effect at
    the first model step whose stamp is at or after the input's DDS reception time (and after
    the previous input on its topic). Stamps are model time anchored to the ROS clock at start,
    so they are wall-consistent. Falling behind: `overrun` (catch_up up to max_catchup, or skip).
    Simulated time: model time starts at 0 and runs in chunks of one publish period, in lockstep
    with the duty_cycle answers or free running, as the rig's (`DeviceNode._run_simulated`).
    External clock (use_sim_time): the steps up to each new /clock run when it arrives; see
    `_run_external_clock`.

Parameters are declared from `pcv_sim.device.settings` (one declaration each); what rcl leaves
silent is checked by `pcv_sim.device.parameters`; diagnostics are built by `pcv_sim.device.diagnostics`.
Parameter services, service polling, QoS events, the one-/clock rule and the rejection log are the
package's node base (`pcv_sim.node.base.DeviceNode`), shared with the rig node.

Recorder hook: `EmulatorNode.set_recorder(recorder, every)` makes the device call
`recorder(t_ns, signals)` at every `every`-th model step (see pcv_sim.device.valve.SIGNALS); a
`close()` method, if the recorder has one, is called at shutdown.

Recording (`record.enabled`): a `pcv_sim.io.recorder.BagRecorder` on that hook, called at every
model step from the start (the device at rest; stamps are the samples' model time, in simulated
time from 0), finalized by SIGINT/SIGTERM; a writer process does the disk work, so the loop only
queues samples (pcv_sim.io.writer_process). Its state is in the diagnostics (`recording*` keys).
"""

from __future__ import annotations

import time
from functools import partial
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.qos import qos_profile_sensor_data
from std_srvs.srv import Trigger

from pcv_sim.device.diagnostics import DiagnosticsBuilder, Status
from pcv_sim.device.settings import (
    MODEL_PREFIX,
    SCHEMA,
    NodeSettings,
    model_parameters,
    params_with,
)
from pcv_sim.device.valve import MEASURED, Recorder, Sample, ValveDevice
from pcv_sim.io.recorder import BagRecorder, RecorderStatus
from pcv_sim.io.topics import DIAGNOSTICS, RESET, input_topics, output_topics
from pcv_sim.node.base import DIAGNOSTICS_QOS, SAMPLE_HINT, DeviceNode
from pcv_sim.node.samples import SamplePublisher
from pcv_sim.params import ValveParams, load_params

__all__ = ["EmulatorNode"]

NODE_NAME = "emulator"
_UNKNOWN_HINT = (f"; model parameters are {MODEL_PREFIX}<section>.<key> for the scalar and vector keys of the "
                 "valve YAML (matrix fits: use valve_config); allow_unknown_parameters: true ignores unknown names")


class EmulatorNode(DeviceNode):
    """ROS parameters in, `ValveDevice` out. Construct, then `run(stop)`."""

    device: ValveDevice
    _diag: DiagnosticsBuilder

    unknown_hint = _UNKNOWN_HINT
    schema = SCHEMA

    def __init__(self, *, argv: list[str] | None = None, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, argv=argv, **kwargs)

    def _setup(self, argv: list[str]) -> None:
        self.settings, params = self.declare_node_parameters()
        dt = params.simulation.time_step
        s = self.settings
        self.simulated = s.time_mode == "simulated"
        self.device = ValveDevice(params, safe_duty=s.safe_duty, watchdog_timeout=s.watchdog_timeout,
                                  sample_every=s.sample_every(dt), seed=s.seed)
        self.samples_published = 0
        self._last_published: tuple[Any, ...] | None = None   # `_send`'s arguments: step, measured values

        sensor = qos_profile_sensor_data
        #: The measured signals and the valve options' outputs (ValveDevice.option_outputs), published with each sample.
        self.signal_names = (*MEASURED, *self.device.option_outputs)
        self._samples = SamplePublisher(output_topics(self.signal_names), self.signal_names, s.frame_id,
                                        lambda t, topic: self.create_publisher(
                                            t, topic, sensor, event_callbacks=self.output_events(topic, SAMPLE_HINT)))
        self._pub_diag = self.create_publisher(DiagnosticArray, DIAGNOSTICS, DIAGNOSTICS_QOS,
                                               event_callbacks=self.output_events(DIAGNOSTICS))
        self.publish_clock("run this emulator with use_sim_time:=true (time_mode real) to follow the other "
                           "clock, or simulate several valves in one process (the multi-valve rig)")
        self.subscribe_inputs(input_topics(tuple(self.device.inputs), self.device.valve_names))
        self.subscribe_faults()
        self.follow_clock()
        self.collect_event_handlers()
        self.create_service(Trigger, RESET, self._on_reset)
        self._deferred_callbacks += (self._on_reset,)      # rest states are computed off the loop
        self._diag = DiagnosticsBuilder(self.get_fully_qualified_name(), time.monotonic())
        self.recorder = self._make_recorder()
        mode = ("simulated time" if self.simulated else "time from an external /clock (use_sim_time)"
                if self.external_clock else "real time")
        self.get_logger().info(
            f"{mode}, samples at {s.publish_rate:g} Hz, "
            f"model step {dt * 1e3:g} ms ({self.device.stepper.integrator}), watchdog "
            f"{s.watchdog_timeout:g} s -> duty {s.safe_duty:g}, valve config {s.valve_config or 'shipped default'}, "
            f"fault topic {'on (faults.enabled)' if s.faults_enabled else 'off (faults.enabled: false)'}")

    # --- parameters --------------------------------------------------------------------------

    def _device_parameters(self, settings: NodeSettings) -> ValveParams:
        """The valve YAML (valve_config), with the model parameters declared from it (model.<section>.<key>)
        applied."""
        params = load_params(settings.valve_config or None)
        changes = {}
        for mp in model_parameters(params):
            value = self.declare(mp.name, mp.value, f"[{mp.unit}] {mp.source}", is_float=mp.kind.startswith("float"))
            if value != mp.value:
                changes[mp.name] = value
        return params_with(params, changes) if changes else params

    def _prepare(self, params: ValveParams, changes: dict[str, Any]) -> tuple[ValveParams, Any]:
        """Worker thread: the model's parameters changed and the new model's rest state prepared."""
        if not changes:
            return params, None
        params = params_with(params, changes, runtime=True)
        return params, (self.device.prepare(params), ", ".join(changes))

    def _apply_settings(self, settings: NodeSettings) -> None:
        dev = self.device
        dev.set_watchdog_timeout(settings.watchdog_timeout)
        dev.set_safe_duty(settings.safe_duty)
        dev.sample_every = settings.sample_every(dev.dt)
        dev.sensors.period = dev.sample_every * dev.dt      # a delay fault counts samples
        self._samples.set_frame_id(settings.frame_id)

    def _install(self, prepared: Any) -> None:
        stepper, names = prepared
        what = self.device.install(stepper)
        self.get_logger().info(f"model parameters changed ({names}): model restarted at rest at the present "
                               f"operating point: {what}")

    # --- recording ---------------------------------------------------------------------------

    def _make_recorder(self) -> BagRecorder | None:
        """The bag recorder asked for by record.* (None when off); ParameterError if it cannot start."""
        s, dev = self.settings, self.device
        recorder: BagRecorder | None = self.open_recorder(partial(
            BagRecorder, signals=s.record_signals, options=(*dev.option_inputs, *dev.option_outputs),
            every=s.record_every(dev.dt), dt_ns=dev.dt_ns, frame_id=s.frame_id, faults=s.faults_enabled))
        if recorder is not None:
            self.set_recorder(recorder, 1)      # every step: inputs stamped exactly, outputs decimated inside
            dev.on_fault_command = lambda step, text: recorder.fault_command(dev.stamp_ns(step), text)
        return recorder

    def _start_recording(self) -> None:
        """Anchor the recording at the present model time, the device at rest."""
        rec = self.recorder
        if rec is None:
            return
        dev = self.device
        rec.start(dev.stamp_ns(), dev.record_values())
        self.recording_started(rec, f"{', '.join((*rec.signals, *rec.options))} to {rec.path} (outputs every "
                                    f"{rec.every * dev.dt * 1e3:g} ms of model time, inputs on change)")

    # --- recorder hook -----------------------------------------------------------------------

    def set_recorder(self, recorder: Recorder | None, every: int = 1) -> None:
        """Call `recorder(t_ns, signals)` at every `every`-th model step (None: stop recording)."""
        self.device.record_every = max(1, int(every))
        self.device.recorder = recorder

    # --- inputs ------------------------------------------------------------------------------

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

    def _run_steps(self, n: int) -> list[Sample]:
        """Run n model steps; log what the device did that a user must hear about (once per event)."""
        samples = self.device.run(n)
        self.forward_log()
        return samples

    def _publish(self, samples: list[Sample]) -> None:
        """The samples as measured (simulated time: /clock first, at the present step, the last
        sample's). Sensor faults (faults.enabled) apply once per sample, in order."""
        if not samples:
            return
        if self._pub_clock is not None:
            self._publish_clock()
        measure = self.device.measure_valve if self.settings.faults_enabled else None
        for s in samples:
            measured = (s.step, (*(measure(s) if measure is not None else (s.pressure, s.current, s.spool_position)),
                                 *s.options))
            self._send(*measured)
            self._last_published = measured
        self._shown = samples[-1].step

    def _send(self, step: int, values: tuple[float, ...]) -> None:
        """One sample's messages; a value a sensor fault dropped (NaN) is not published."""
        self._samples.publish(self.device.stamp_ns(step), values)
        self.samples_published += 1

    def _send_samples(self) -> None:
        if self._last_published is not None:
            self._send(*self._last_published)

    def _sample_period(self) -> int:
        return self.device.sample_every

    def _statuses(self, now: float, recorder: RecorderStatus | None) -> list[Status]:
        """The device's health, one status per concern (see pcv_sim.device.diagnostics)."""
        return self._diag.build(now, device=self.device, settings=self.settings, schedule=self._schedule,
                                recorder=recorder, samples_published=self.samples_published,
                                time_mode="external_clock" if self.external_clock else None)

    # --- loops -------------------------------------------------------------------------------

    def _finish(self) -> None:
        close = getattr(self.device.recorder, "close", None)
        if self.recorder is None and callable(close):
            close()             # a recorder set through `set_recorder`
        super()._finish()

    # --- the device under the node base's loops ----------------------------------------------

    def _begin(self, origin_ns: int) -> None:
        self.device.origin_ns = origin_ns
        self._start_recording()
        self._publish([self.device.sample()])

    def _compute(self, n: int) -> None:
        self._publish(self._run_steps(n))
