"""`DeviceNode`: any device (`pcv_sim.device.device.Device`) on ROS 2; the `emulator` and the `rig`
executables are this one class over two devices (`pcv_sim.node.kinds`: what differs between
them is data).

Started by `pcv_sim.node.emulator` or `pcv_sim.node.rig`, which own the process: signals, exit
status. A thin adapter: ROS parameters in, the device in the middle, messages out; no physics here.
Topic names are relative (``-r __ns:=/left`` moves a whole device) and follow from the device's
names (`pcv_sim.io.topics.input_topics`, `output_topics`): an input `left.duty_cycle` is the topic
`left/duty_cycle`, the emulator's `duty_cycle` the topic `duty_cycle`; a signal `left.pressure`
the topic `left/pressure`, the cylinder's signals one `cylinder/joint_states`, a valve on a chamber
also `cylinder/pressure_<chamber>`.

    in   the device's inputs      std_msgs/Float64, sensor_msgs/FluidPressure (supply_pressure)   reliable
    in   faults                   std_msgs/String: {fault: coil_open, valve: left} (YAML; faults.enabled only)
    out  the device's signals     std_msgs/Float64, sensor_msgs/FluidPressure (pressure: stamped, Pa),
                                  sensor_msgs/JointState (the cylinder)                         sensor data
    out  lockstep/sample, in lockstep/command   sensor_msgs/JointState, raw CDR (simulated lockstep:
                                  a sample and its answer in one message each way; node.lockstep_channel)
    out  /diagnostics             diagnostic_msgs/DiagnosticArray, every diagnostics_period (wall)
    out  /clock                   rosgraph_msgs/Clock (simulated time only)
    in   /clock                   rosgraph_msgs/Clock (use_sim_time only: the model follows it)
    srv  reset                    std_srvs/Trigger: the device back to rest, a fault cleared; model time goes on

The loops, parameters, inputs, services and QoS events are `pcv_sim.node.base.NodeBase`'s (a
module per idea). Here: the device's samples published as measured (sensor faults applied; a
non-finite value is not), one
sample period at a time so that the hook (a scenario) and the recorder see the device at the
sample's step; its inputs checked by the device on arrival and acting at the step `acting_step`
gives; its log (watchdogs, faults, resets) forwarded once per event; parameter changes and reset
prepared off the loop and installed at a step boundary (in real time at the step an input received
with the request acts at).

Recording (`record.enabled`): the device's bag recorder (`kind.recorder`: the one
`pcv_sim.device.recording.DeviceRecorder` on the device's `BagLayout`), attached to the
device's hooks, started with the first sample, told of every published sample and of resets,
finalized by SIGINT/SIGTERM.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

from pcv_sim.device.device import Sample
from pcv_sim.device.diagnostics import DiagnosticsBuilder, Shown, Status
from pcv_sim.errors import CommandError
from pcv_sim.io.recorder import RecorderStatus
from pcv_sim.io.topics import DIAGNOSTICS, RESET, input_topics, output_topics
from pcv_sim.node.base import NodeBase
from pcv_sim.node.lockstep_channel import COMMAND_TOPIC, SAMPLE_TOPIC, NamedVector, decode, split_command
from pcv_sim.node.loops import StopFlag
from pcv_sim.node.qos_events import COMMAND_HINT, SAMPLE_HINT, topic_qos
from pcv_sim.node.samples import SamplePublisher

__all__ = ["DeviceNode"]


class DeviceNode(NodeBase):
    """ROS parameters in, the device of `kind` (`pcv_sim.node.kinds.NodeKind`) out. Construct, then
    `run(stop)`."""

    def __init__(self, kind: Any, *, argv: list[str] | None = None, **kwargs: Any) -> None:
        self.kind = kind
        self.schema = kind.schema
        self.unknown_hint = kind.unknown_hint
        super().__init__(kind.name, argv=argv, **kwargs)

    # --- set-up ----------------------------------------------------------------------------------

    def _setup(self, argv: list[str]) -> None:
        self.settings, params = self.declare_node_parameters()
        s, kind = self.settings, self.kind
        self.simulated = s.time_mode == "simulated"
        self.device = dev = kind.make_device(s, params)
        self.samples_published = 0
        self.resets = 0
        self._last: tuple[int, list[float]] | None = None      # (step, measured) as last published
        #: values sent in the lockstep sample after the device's signals (a scenario's `setpoint`)
        self.sample_extras: dict[str, float] = {}
        self._channel: NamedVector | None = None               # the lockstep sample's writer, for its names
        self._fault_logged: str | None = None

        def publisher(msg_type: Any, topic: str, hint: str = SAMPLE_HINT) -> Any:
            return self.create_publisher(msg_type, topic, topic_qos(topic), event_callbacks=self.output_events(topic, hint))

        self._samples = SamplePublisher(output_topics(dev.signals, kind.chambers(dev)), dev.signals, s.frame_id,
                                        publisher)
        lockstep = self.simulated and s.lockstep
        # The lockstep channel (pcv_sim.node.lockstep_channel): a period in one message each way.
        self._pub_sample = publisher(JointState, SAMPLE_TOPIC, COMMAND_HINT) if lockstep else None
        self._duty_inputs = {e.answers: e for e in input_topics(dev.input_names, dev.valve_names) if e.answers}
        self.subscribe_inputs(input_topics(dev.input_names, dev.valve_names), self._on_command if lockstep else None)
        self.subscribe_faults()
        self._pub_diag = publisher(DiagnosticArray, DIAGNOSTICS, COMMAND_HINT)
        self.publish_clock(kind.clock_advice)
        self.follow_clock()
        self.create_service(Trigger, RESET, self._on_reset)
        self._deferred_callbacks += (self._on_reset,)       # rest states are computed off the loop
        self._diag = DiagnosticsBuilder(self.get_fully_qualified_name(), time.monotonic(), kind.chambers(dev))
        self.recorder = self.open_recorder(kind.recorder(self))
        if self.recorder is not None:
            self.recorder.attach(dev)
        self.collect_event_handlers()

    def run(self, stop: StopFlag) -> None:
        # The start line is said once a signal is a stop the loop takes (the bag closed, the node
        # torn down: `pcv_sim.node.process.serve`); during the construction it abandons the start-up.
        # Whoever waits for the line and then signals gets the clean stop.
        if not stop.requested:
            self.get_logger().info(self.kind.describe(self))
        super().run(stop)

    def _device_parameters(self, settings: Any) -> Any:
        return self.kind.device_parameters(self, settings)

    # --- parameters at run time ------------------------------------------------------------------

    def _prepare(self, params: Any, changes: dict[str, Any]) -> tuple[Any, Any]:
        """Worker thread: the device's parameters with `changes` (`kind.with_changes`: checked, a
        ParameterError for a refused one) and what the loop installs for them (`kind.prepare`)."""
        if not changes:
            return params, None
        params = self.kind.with_changes(params, changes)
        return params, (self.kind.prepare(self.device, params), ", ".join(changes))

    def _apply_settings(self, settings: Any) -> None:
        self.kind.apply_settings(self.device, settings)
        self._samples.set_frame_id(settings.frame_id)

    def _install(self, prepared: Any) -> None:
        ready, names = prepared
        self.get_logger().info(f"model parameters changed ({names}): {self.kind.install(self.device, ready)}")

    # --- inputs ----------------------------------------------------------------------------------

    def _on_command(self, raw: bytes, info: Any = None) -> None:
        """A lockstep command: the answer to the sample it is stamped with, for every valve at once (a
        valve it leaves out keeps its duty, as with a callable); its flags go to the hook. An answer to
        an earlier sample (one published again) is not an answer to this one: left."""
        dev = self.device
        try:
            stamp, names, values = decode(raw)
            duties, flags = split_command(names, values, dev.valve_names)
        except CommandError as err:
            dev.counts.last_rejection = f"{COMMAND_TOPIC}: {err}"
            self.log_rejection(COMMAND_TOPIC, COMMAND_TOPIC, str(err), "the sample stays unanswered")
            return
        if stamp != dev.stamp_ns(self._shown) or len(self._answered) == len(dev.valve_names):
            return
        self._answered.update(dev.valve_names)
        for valve, duty in duties.items():
            entry = self._duty_inputs[valve]
            self.take_input(entry.input, entry.topic, duty, info)
        if flags and self.hook is not None:
            self.hook.flags_at(stamp, flags)

    def add_input(self, msg_type: Any, topic: str, handler: Callable[..., None], qos: Any) -> Any:
        """One more input taken with the node's own (`handler(msg, info)`, after the device's)."""
        sub = self.create_subscription(msg_type, topic, handler, qos)
        self._inputs.append((sub, handler))
        return sub

    def _on_reset(self, _request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        """Worker thread: the device's rest state prepared (on trial where the device tries one); the
        loop installs it: in simulated time and with an external clock at the present step (the next
        sample shows it), in real time at the step an input received now acts at (after the inputs
        received before, before those after). Model time goes on; the answer comes once it acted."""
        dev = self.device
        try:
            prepared = dev.prepare()
        except Exception as err:
            response.success = False
            response.message = f"reset failed: {type(err).__name__}: {err}"
            self.get_logger().error(response.message)
            return response

        def reset() -> None:
            response.message = f"{dev.install(prepared)}; model time goes on"
            response.success = True
            self.resets += 1
            if self.recorder is not None:
                self.recorder.reset(dev)
            self.get_logger().info(f"reset: {response.message}")
            self.forward_log()

        def install() -> None:
            if self._schedule is None or dev.fault is not None:     # (a faulted model is not stepped)
                reset()
                return
            at = self.acting_step(dev.timing, "reset", self.first_open_step(), dev.origin_ns, None)
            dev.timing.took("reset", at)
            held = self.hold_answer()

            def act() -> None:
                reset()
                held.append(True)

            dev.queue.push(max(at, dev.first_open_step()), act)

        self._ready.append(install)
        return response

    # --- stepping and outputs --------------------------------------------------------------------

    def _begin(self, origin_ns: int) -> None:
        """Model time 0 is stamped origin_ns: the recording starts, the first sample is published."""
        dev = self.device
        dev.origin_ns = origin_ns
        if self.recorder is not None:
            self.recording_started(self.recorder, self.recorder.begin(dev))
        self._publish(dev.present_sample())

    def _compute(self, n: int) -> None:
        """n model steps, one sample period at a time (the hook and the recorder see the device at
        each sample's step), each sample published; the device's log forwarded."""
        dev = self.device
        end = dev.steps + n
        per = dev.sample_every
        while dev.steps < end:
            for sample in dev.run_to(min(end, (dev.steps // per + 1) * per)):
                self._publish(sample)
        self.forward_log()
        if dev.fault is not None and dev.fault != self._fault_logged:
            self._fault_logged = dev.fault
            self.get_logger().error(f"model fault: {dev.fault}; nothing is published until a reset (the reset "
                                    "service) or new model parameters")

    def _publish(self, sample: Sample) -> None:
        """One sample as measured (sensor faults applied); in simulated time /clock first."""
        dev = self.device
        measured = dev.measure(sample).tolist()
        self._shown = sample.step
        if self._pub_clock is not None:
            self._publish_clock()
        if self.hook is not None:
            self.hook.sampled(sample.values, measured)
        self._last = (sample.step, measured)
        self._send_samples()
        if self.recorder is not None:
            self.recorder.shown(dev, sample, measured)

    def _send_samples(self) -> None:
        """Publish the last sample (again, for a lockstep re-publication: not computed anew, since
        sampling moves the sensor faults' state and the coil solve's Newton start); the lockstep
        channel first (the controller reads it alone)."""
        if self._last is None:
            return
        step, y = self._last
        stamp = self.device.stamp_ns(step)
        if self._pub_sample is not None:
            extras = self.sample_extras
            channel = self._channel
            n = len(self.device.signals)
            if channel is None or len(channel.names) != n + len(extras) or channel.names[n:] != tuple(extras):
                channel = self._channel = NamedVector((*self.device.signals, *extras))
            self._pub_sample.publish(channel.encode(stamp, (*y, *extras.values()) if extras else y))
        self._samples.publish(stamp, y)
        self.samples_published += 1

    def _sample_period(self) -> int:
        return self.device.sample_every

    def _halted(self) -> bool:
        return self.device.fault is not None

    @property
    def failure(self) -> str | None:
        """Why the model stopped (it ran away), until a reset; None while it runs."""
        return self.device.fault

    # --- diagnostics -----------------------------------------------------------------------------

    def _statuses(self, now: float, recorder: RecorderStatus | None) -> list[Status]:
        """The device's statuses, one per concern and one per named valve (`DiagnosticsBuilder`)."""
        dev, s = self.device, self.settings
        waiting = tuple(v for v in dev.valve_names if v not in self._answered) \
            if self.simulated and s.lockstep else ()
        shown = Shown("external_clock" if self.external_clock else s.time_mode, self.samples_published, self.resets,
                      waiting)
        statuses: list[Status] = self._diag.build(now, device=dev, settings=s, schedule=self._schedule,
                                                  recorder=recorder, shown=shown)
        return statuses

    def _finish(self) -> None:
        close = getattr(getattr(self.device, "recorder", None), "close", None)
        if self.recorder is None and callable(close):
            close()             # a recorder set on the device by its user
        super()._finish()

