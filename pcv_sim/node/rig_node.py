"""`RigNode`: the rig (`pcv_sim.rig.Rig`: N valves + the steering cylinder at one 0.1 ms step) on ROS 2.

Started by `pcv_sim.node.rig` (the `rig` executable), which owns the process: signals, exit status.
A thin adapter: ROS parameters in, `Rig` in the middle, messages out; no physics here. Topic
names are relative (`pcv_sim.io.topics`); each valve keeps the emulator's interface under its name:

    in   <valve>/duty_cycle      std_msgs/Float64            duty, fraction 0..1          reliable, depth 10
    out  <valve>/pressure        sensor_msgs/FluidPressure   Pa, stamp = model time       sensor data
    out  <valve>/current         std_msgs/Float64            A                            sensor data
    out  <valve>/spool_position  std_msgs/Float64            m                            sensor data
    out  cylinder/joint_states   sensor_msgs/JointState      prismatic `steering`: m, m/s, N   sensor data
    out  cylinder/pressure_a|b   sensor_msgs/FluidPressure   Pa, the chamber (= its valve's pressure)
    in   faults                  std_msgs/String             {fault: coil_open, valve: left} (YAML)
    in   cylinder/external_force std_msgs/Float64            N on the rod, + extending (toward +x)   reliable, depth 10
    in   <valve>/ambient_temperature, oil_temperature   std_msgs/Float64, K   (the valve options', when on:
    out  <valve>/coil_temperature (K), coil_resistance (ohm), core_position (m)   io.topics.OPTION_INTERFACE)
    srv  reset                   std_srvs/Trigger            the rig back to rest; model time goes on
    out  /diagnostics            one status per valve and one for the rig, every diagnostics_period
    out  /clock                  rosgraph_msgs/Clock (simulated time only: one clock for the whole rig)
    in   /clock                  rosgraph_msgs/Clock (use_sim_time with time_mode real: the model follows it)

Samples leave every control period (model time), measured values (sensor faults applied; a
dropped or non-finite one is not published).

The loops are the emulator's, written once in the node base (`pcv_sim.node.base.DeviceNode`): no
executor, no timer, inputs taken by `take_message` polling, because at 1 kHz an executor costs
more than the work.
- Simulated time, lockstep (default): publish /clock and the samples at T = k x control period,
  wait until every valve has had a duty_cycle message since then, apply them from T + dt, the
  first step not shown (the sample at T shows the inputs in force at T; as
  `pcv_sim.rig.run_lockstep`), compute to T + control period, repeat:
  bit for bit the same run for a controller that answers the same way. A sample left unanswered
  for 0.5 s is published again (a controller not yet connected).
- Simulated, `lockstep: false`: periods back to back at `real_time_factor`; inputs act from the
  period after they were taken.
- Real time: `RealTimeSchedule` on the monotonic clock; an input acts at the first step stamped at
  or after its DDS reception (never before, never before the last sample shown), as the emulator.
- External clock (`use_sim_time: true`, `time_mode: real`): model time follows /clock as in the
  emulator (`pcv_sim.simulation.clock.ExternalClock`, shared): model time 0 is the first /clock,
  the steps up to each new one are computed; inputs act at the present step. use_sim_time with
  time_mode simulated is refused (that publishes /clock itself).
Duty commands are validated with the valve's rules (`check_duty`); refused ones are counted and
logged at most once per `reject_log_period` per valve. Fault commands act at the step the
inputs would and are validated with the rig's fault table; so do external force commands, with
`Rig.set_external_force`'s rules (a refused one is counted and logged, the last valid one stays).

Reset (`reset` service): valves at rest at their initial duty, piston at rest at its initial
position, inputs (duties, supply pressures, external force) back to the start, faults cleared, a
model that ran away running again; model time goes on in every mode (so /clock, stamps and a bag
stay monotonic; in simulated time the run after it is a fresh start's, shifted in time). It acts
at the present step in simulated time and with an external clock (the next sample shows it), in
real time at the step an input received at the request would act at.

Recording (`record.enabled`): a `pcv_sim.rig.bag.RigRecorder` (the emulator's BagRecorder
machinery: writer process, never overwrites, finalised by SIGINT/SIGTERM) from the first sample
(the rig at rest) on: each valve's topics under `<namespace>/<valve>/` as the emulator records
them (inputs duty_cycle, supply_pressure on change, stamped at the step they act; load_flow the
chamber's mean flow over each control period, stamped at its start; outputs pressure, current,
spool_position at every published sample, as published), the
cylinder's joint_states, pressure_a|b and external_force, the fault commands (`faults`, at the
step they acted) and the rig's log (`rig/events`). `pcv-sim replay BAG --namespace left` replays
one valve. The state is in the rig status of the diagnostics (`recording*` keys).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from functools import partial
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

from pcv_sim.device.diagnostics import Status
from pcv_sim.errors import CommandError
from pcv_sim.io.recorder import RecorderStatus
from pcv_sim.io.topics import DIAGNOSTICS, DUTY_CYCLE, RESET, input_topics, output_topics, valve_topic
from pcv_sim.node.base import (
    COMMAND_HINT,
    COMMAND_QOS,
    DIAGNOSTICS_QOS,
    SAMPLE_HINT,
    DeviceNode,
)
from pcv_sim.node.lockstep_channel import COMMAND_TOPIC, SAMPLE_TOPIC, NamedVector, decode, split_command
from pcv_sim.node.samples import SamplePublisher
from pcv_sim.rig import Rig, RigError, load_rig
from pcv_sim.rig.bag import RigRecorder
from pcv_sim.rig.diagnostics import RigDiagnostics
from pcv_sim.rig.params import RigParams
from pcv_sim.rig.settings import SCHEMA, RigNodeSettings

__all__ = ["NODE_NAME", "RigNode"]

NODE_NAME = "rig"


class RigNode(DeviceNode):
    """ROS parameters in, `Rig` out. Construct, then `run(stop)`."""

    device: Rig
    _diag: RigDiagnostics

    unknown_hint = "; the physics is set in the rig YAML (rig_config)"
    schema = SCHEMA

    def __init__(self, *, argv: list[str] | None = None, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, argv=argv, **kwargs)

    # --- set-up --------------------------------------------------------------------------------

    def _setup(self, argv: list[str]) -> None:
        self.settings, rig_params = self.declare_node_parameters()
        s = self.settings
        self.device = rig = Rig(rig_params, seed=s.seed)
        self.simulated = s.time_mode == "simulated"
        self.per: int = rig_params.steps_per_period
        self.dt_ns = rig.dt_ns
        self.resets = 0
        self.samples_published = 0
        self._last_sample: list[float] = []                 # measured, as last published (diagnostics)
        self._last_options: list[float] = []                # the options' outputs, true, as last sampled (the bag)
        #: values sent in the lockstep sample after the rig's signals (a scenario's `setpoint`)
        self.sample_extras: dict[str, float] = {}
        self._channel: NamedVector | None = None            # the lockstep sample's writer, for its names

        sensor = qos_profile_sensor_data

        def publisher(msg_type: Any, topic: str, qos: Any = sensor, hint: str = SAMPLE_HINT) -> Any:
            return self.create_publisher(msg_type, topic, qos, event_callbacks=self.output_events(topic, hint))

        self._samples = SamplePublisher(output_topics(rig.signals, {v.name: v.chamber for v in rig_params.valves
                                                                    if v.chamber in ("a", "b")}),
                                        rig.signals, s.frame_id, publisher)
        channel = self.simulated and s.lockstep
        # The lockstep channel (pcv_sim.node.lockstep_channel): a period in one message each way.
        self._pub_sample = publisher(JointState, SAMPLE_TOPIC, COMMAND_QOS, COMMAND_HINT) if channel else None
        self.subscribe_inputs(input_topics(tuple(rig.inputs), rig.valve_names),
                              self._on_command if channel else None)
        self.subscribe_faults()
        self._pub_diag = publisher(DiagnosticArray, DIAGNOSTICS, DIAGNOSTICS_QOS, COMMAND_HINT)
        self.publish_clock("stop the other simulation, or run this rig with time_mode real")
        self._n_signals = len(rig.signals)
        self._diag = RigDiagnostics(self.get_fully_qualified_name(), time.monotonic())
        mode = (f"simulated time, {'lockstep' if s.lockstep else f'free running (factor {s.real_time_factor:g})'}"
                if self.simulated else "real time")
        self.get_logger().info(
            f"rig: valves {', '.join(f'{v.name} (chamber {v.chamber})' for v in rig_params.valves)} + cylinder, "
            f"step {rig.dt * 1e3:g} ms, {mode}, samples and commands every "
            f"{rig_params.timing.control_period * 1e3:g} ms, watchdog {rig_params.timing.watchdog_timeout:g} s, "
            f"rig config {s.rig_config or 'shipped default'}, fault topic "
            f"{'on (faults.enabled)' if s.faults_enabled else 'off (faults.enabled: false)'}")
        self._setup_more_interface()
        self.collect_event_handlers()

    def _device_parameters(self, settings: RigNodeSettings) -> RigParams:
        """The rig YAML (rig_config) with this node's control_period (when set)."""
        return settings.rig_params(load_rig(settings.rig_config or None))

    # --- inputs --------------------------------------------------------------------------------

    def _on_command(self, raw: bytes, info: Any = None) -> None:
        """A lockstep command: the answer to the sample it is stamped with, for every valve at once (a
        valve it leaves out keeps its duty, as with a callable); its flags go to the hook. An answer to
        an earlier sample (one published again) is not an answer to this one: left."""
        rig = self.rig
        try:
            stamp, names, values = decode(raw)
            duties, flags = split_command(names, values, rig.valve_names)
        except CommandError as err:
            rig.counts.last_rejection = f"{COMMAND_TOPIC}: {err}"
            self.log_rejection(COMMAND_TOPIC, COMMAND_TOPIC, str(err), "the sample stays unanswered")
            return
        if stamp != rig.stamp_ns(self._shown) or len(self._answered) == len(rig.valve_names):
            return
        self._answered.update(rig.valve_names)
        for valve, duty in duties.items():
            self.take_input(f"{valve}.{DUTY_CYCLE}", valve_topic(valve, DUTY_CYCLE), duty, info)
        if flags and self.hook is not None:
            self.hook.flags_at(stamp, flags)

    def add_input(self, msg_type: Any, topic: str, handler: Callable[..., None], qos: Any) -> Any:
        """One more input taken with the node's own (`handler(msg, info)`, after the duties and faults)."""
        sub = self.create_subscription(msg_type, topic, handler, qos)
        self._inputs.append((sub, handler))
        return sub

    # --- outputs -------------------------------------------------------------------------------

    def _publish_samples(self) -> None:
        """The measured samples at the present step (sensor faults applied; non-finite: not published);
        in simulated time /clock first."""
        rig = self.rig
        if self._pub_clock is not None:
            self._publish_clock()
        true = rig.sample()
        self._last_sample = rig.sensors.measure(rig.time, true).tolist()
        self._last_options = rig.option_sample
        self._shown = rig.steps
        if self.hook is not None:
            self.hook.sampled(true, self._last_sample)
        self._send_samples()
        self._record_sample()

    def _send_samples(self) -> None:
        """Publish the last sample (again, for a lockstep re-publication: not computed anew, since
        sampling moves the sensor faults' state and the coil solve's Newton start). The messages
        are made once and refilled (publish serializes them at once). A topic without a matched
        subscriber is not written: no reader would get it (sensor data is volatile), and the lockstep
        controller reads the lockstep channel alone, written first."""
        y = self._last_sample
        stamp = self.rig.stamp_ns(self._shown)
        if self._pub_sample is not None:
            extras = self.sample_extras
            channel = self._channel
            if channel is None or len(channel.names) != self._n_signals + len(extras) \
                    or channel.names[self._n_signals:] != tuple(extras):
                channel = self._channel = NamedVector((*self.rig.signals, *extras))
            self._pub_sample.publish(channel.encode(stamp, (*y, *extras.values()) if extras else y))
        self._samples.publish(stamp, y)
        self.samples_published += 1

    def _statuses(self, now: float, recorder: RecorderStatus | None) -> list[Status]:
        """One status per valve and one for the rig (see pcv_sim.rig.diagnostics)."""
        rig = self.rig
        waiting = tuple(v for v in rig.valve_names if v not in self._answered) \
            if self.simulated and self.settings.lockstep else ()
        time_mode = "external_clock" if self.external_clock else self.settings.time_mode
        return self._diag.build(now, rig=rig, resets=self.resets, samples_published=self.samples_published,
                                time_mode=time_mode, lockstep=self.settings.lockstep,
                                schedule=self._schedule, failure=rig.fault, waiting_for=waiting,
                                last=dict(zip((*rig.signals, *rig.option_outputs), (*self._last_sample,
                                                                                     *self._last_options))),
                                recorder=recorder)

    # --- stepping ------------------------------------------------------------------------------

    def _advance(self, step: int) -> bool:
        """Integrate to `step`, publishing the samples of every control period on the way. False
        (and the rig stops: nothing more is published) if the model ran away."""
        rig, per = self.rig, self.per
        try:
            while rig.steps < step:
                boundary = (rig.steps // per + 1) * per
                if boundary > step:
                    rig.advance_to(step)
                    break
                rig.advance_to(boundary)
                self._publish_samples()
        except RigError as err:
            self.get_logger().error(f"{err}: the rig stopped; restart it")
            return False
        finally:
            self.forward_log()
        return True

    # --- loops ---------------------------------------------------------------------------------

    # --- external force, reset, external clock, recording ------------------------------------

    def _setup_more_interface(self) -> None:
        """The endpoints beside the samples and the duty and fault commands: `cylinder/external_force`,
        the `reset` service, /clock in (use_sim_time), the recorder (record.enabled)."""
        self.follow_clock()
        if self.external_clock:
            self.get_logger().info("time from an external /clock (use_sim_time): model time 0 is the first /clock "
                                   "received, the model computes up to each new one")
        self.create_service(Trigger, RESET, self._on_reset)
        self._rec_logged = 0                                # rig.log entries written to the bag
        self.recorder = self._make_recorder()

    def _on_reset(self, _request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        """The rig back to rest: valves at their initial duty, piston at its initial position and at
        rest, faults cleared, watchdogs counting from now, a stopped (ran away) model running again.
        Model time goes on (in simulated time too: /clock, stamps and a bag stay monotonic; the run
        after it is a fresh start's, shifted in time). In simulated time and with an external clock
        it acts at once, at the present step (the next sample shows it); in real time at the step an
        input received now would act at. Inputs already scheduled for later steps still act."""
        if self._schedule is None:
            self._reset_rig()
            response.message = f"reset: the rig is at rest at t = {self.rig.time:.4f} s"
        else:
            rig = self.rig
            at = self.acting_step(rig.timing, "reset", self.first_open_step(), rig.origin_ns, None)
            rig.timing.took("reset", at)
            rig.schedule_step(at, self._reset_rig)
            response.message = "reset: the rig goes back to rest at the next step"
        response.message += (" (valves at their initial duty, piston at its initial position, faults cleared; "
                             "model time goes on)")
        response.success = True
        return response

    def _reset_rig(self) -> None:
        failure = self.rig.fault
        self.rig.reset(keep_time=True)
        self.resets += 1
        if self.recorder is not None:
            self.recorder.restart_flows()            # the piston jumped: no mean flow across the reset
        if failure is not None:
            self.get_logger().info(f"reset: the model runs again (it had stopped: {failure})")
        self.forward_log()

    # --- the rig under the node base's loops ---------------------------------------------------

    @property
    def rig(self) -> Rig:
        return self.device

    @property
    def failure(self) -> str | None:
        """Why the model stopped (it ran away), until a reset; None while it runs."""
        return self.device.fault

    def _begin(self, origin_ns: int) -> None:
        self.rig.origin_ns = origin_ns
        self._publish_samples()

    def _compute(self, n: int) -> None:
        self._advance(self.rig.steps + n)

    def _sample_period(self) -> int:
        return self.per

    def _lockstep_answers(self) -> tuple[list[Any], Any]:
        """Each valve's duty_cycle and, in lockstep, the lockstep channel's command (one answer for all)."""
        valves = len(self.rig.valve_names)
        channel = self._inputs[valves][0] if self._pub_sample is not None else None
        return [sub for sub, _ in self._inputs[:valves]], channel

    def _halted(self) -> bool:
        return self.rig.fault is not None

    def _make_recorder(self) -> RigRecorder | None:
        """The bag recorder asked for by record.* (None when off); ParameterError if it cannot start."""
        rig = self.rig
        recorder: RigRecorder | None = self.open_recorder(partial(
            RigRecorder, valves=[(v.name, v.chamber) for v in rig.params.valves], signals=rig.signals,
            options=(*rig.option_inputs, *rig.option_outputs)))
        if recorder is not None:
            rig.on_input = self._record_input
            rig.on_fault_command = lambda step, text: recorder.text(recorder.faults_topic, rig.stamp_ns(step), text)
        return recorder

    def _record_input(self, step: int, name: str, value: float) -> None:
        """Rig.on_input: an input in force from `step` (the duty after the watchdog, a supply, the force)."""
        rec = self.recorder
        if rec is not None:
            rec.input(self.rig.stamp_ns(step), name, value)

    def _record_sample(self) -> None:
        """The sample just published (and the load flows, the rig's new log entries) into the bag;
        the first one starts the recording with every input in force."""
        rec = self.recorder
        if rec is None:
            return
        rig = self.rig
        t_ns = rig.stamp_ns(self._shown)
        if not rec.started:
            rec.start(t_ns, rig.input_values())
            self.recording_started(rec, f"to {rec.path}: every valve under its namespace, the cylinder, faults and "
                                        "events (outputs every control period, inputs on change)")
        rec.sample(t_ns, self._last_sample, rig.load_volumes(), self._last_options)
        log = rig.log
        while self._rec_logged < len(log):
            t, text = log[self._rec_logged]
            self._rec_logged += 1
            rec.text(rec.events_topic, rig.stamp_ns(round(t / rig.dt)), text)
