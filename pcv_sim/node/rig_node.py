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

import math
import time
from collections.abc import Callable
from functools import partial
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.qos import qos_profile_sensor_data
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import FluidPressure, JointState
from std_msgs.msg import Float64, Header
from std_srvs.srv import Trigger

from pcv_sim.device.diagnostics import Status
from pcv_sim.device.faults import parse_fault_command
from pcv_sim.errors import CommandError
from pcv_sim.io.recorder import RecorderStatus
from pcv_sim.io.topics import (
    CLOCK,
    CURRENT,
    CYLINDER,
    DIAGNOSTICS,
    DUTY_CYCLE,
    FAULTS,
    JOINT_STATES,
    PRESSURE,
    RESET,
    SPOOL_POSITION,
    chamber_topic,
    cylinder_topic,
    valve_topic,
)
from pcv_sim.io.topics import (
    EXTERNAL_FORCE as EXTERNAL_FORCE_ROLE,
)
from pcv_sim.node.base import (
    CLOCK_QOS,
    COMMAND_HINT,
    COMMAND_QOS,
    DIAGNOSTICS_QOS,
    SAMPLE_HINT,
    DeviceNode,
)
from pcv_sim.node.lockstep_channel import COMMAND_TOPIC, SAMPLE_TOPIC, NamedVector, decode, split_command
from pcv_sim.rig import FaultError, Rig, RigError, load_rig
from pcv_sim.rig.bag import JOINT_NAME, RigRecorder
from pcv_sim.rig.diagnostics import RigCounts, RigDiagnostics
from pcv_sim.rig.params import RigParams
from pcv_sim.rig.rig import EXTERNAL_FORCE, check_external_force
from pcv_sim.rig.settings import SCHEMA, RigNodeSettings
from pcv_sim.simulation.clock import (
    ExternalClock,
)
from pcv_sim.simulation.duty import check_duty
from pcv_sim.simulation.stepper import check_temperature

__all__ = ["NODE_NAME", "RigNode"]

NODE_NAME = "rig"
_FAULTS_KEY = "faults"          # the reject-log key of the faults topic
EXTERNAL_FORCE_TOPIC = cylinder_topic(EXTERNAL_FORCE_ROLE)


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
        self.counts = RigCounts(accepted=dict.fromkeys(rig.valve_names, 0), rejected=dict.fromkeys(rig.valve_names, 0))
        self.lockstep_keys = rig.valve_names
        self._logged = 0                                    # rig.log entries forwarded to the logger
        self._last_sample: list[float] = []                 # measured, as last published (diagnostics)
        #: values sent in the lockstep sample after the rig's signals (a scenario's `setpoint`)
        self.sample_extras: dict[str, float] = {}
        self._channel: NamedVector | None = None            # the lockstep sample's writer, for its names

        sensor = qos_profile_sensor_data
        self._valve_pubs = []
        def publisher(msg_type: Any, topic: str, qos: Any = sensor, hint: str = SAMPLE_HINT) -> Any:
            return self.create_publisher(msg_type, topic, qos, event_callbacks=self.output_events(topic, hint))

        def subscription(msg_type: Any, topic: str, handler: Callable[..., None], qos: Any = COMMAND_QOS) -> None:
            sub = self.create_subscription(msg_type, topic, handler, qos, event_callbacks=self.input_events(topic))
            self._inputs.append((sub, handler))

        self._publisher = publisher
        self._subscription = subscription
        for name in rig.valve_names:
            self._valve_pubs.append((publisher(FluidPressure, valve_topic(name, PRESSURE)),
                                     publisher(Float64, valve_topic(name, CURRENT)),
                                     publisher(Float64, valve_topic(name, SPOOL_POSITION))))
            subscription(Float64, valve_topic(name, DUTY_CYCLE), partial(self._on_duty, name))
        self._pub_sample = None
        if self.simulated and s.lockstep:
            # The lockstep channel (pcv_sim.node.lockstep_channel): a period in one message each way.
            self._pub_sample = publisher(JointState, SAMPLE_TOPIC, COMMAND_QOS, COMMAND_HINT)
            sub = self.create_subscription(JointState, COMMAND_TOPIC, self._on_command, COMMAND_QOS, raw=True,
                                           event_callbacks=self.input_events(COMMAND_TOPIC))
            self._inputs.append((sub, self._on_command))
        self.subscribe_faults()
        for name in rig.option_inputs:                      # the valve options' temperatures (K)
            valve, _, role = name.partition(".")
            subscription(Float64, valve_topic(valve, role), partial(self._on_option, valve, role))
            self.counts.accepted[name] = self.counts.rejected[name] = 0
        #: The valve options' outputs (`Rig.option_outputs`), published with each sample as the emulator does.
        self._option_pubs = [publisher(Float64, valve_topic(*name.split(".", 1))) for name in rig.option_outputs]
        self._last_options: list[float] = []
        self._pub_joint = publisher(JointState, cylinder_topic(JOINT_STATES))
        #: (publisher, index of the valve's pressure in the samples, its message) per chamber
        self._chamber_pubs = [(publisher(FluidPressure, chamber_topic(v.chamber)),
                               rig.signals.index(f"{v.name}.pressure"),
                               FluidPressure(header=Header(frame_id=f"chamber_{v.chamber}")))
                              for v in rig_params.valves if v.chamber in ("a", "b")]
        self._msg_pressure = FluidPressure(header=Header(frame_id="load_port"))
        self._msg_float = Float64()
        self._msg_joint = JointState(header=Header(frame_id=CYLINDER), name=[JOINT_NAME])
        self._pub_diag = publisher(DiagnosticArray, DIAGNOSTICS, DIAGNOSTICS_QOS, COMMAND_HINT)
        if self.simulated:
            self.refuse_a_second_clock("stop the other simulation, or run this rig with time_mode real")
        self._pub_clock = publisher(Clock, CLOCK, CLOCK_QOS, COMMAND_HINT) if self.simulated else None
        self._n_signals = len(rig.signals)
        self._cyl_i = [rig.signals.index(f"{CYLINDER}.{q}") for q in ("position", "velocity", "effort")]
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

    def _when(self, key: str, info: Any, action: Callable[[], None]) -> None:
        """Run `action` at the step an input taken now acts from (`InputTiming`), scheduled in the rig:
        never a step whose sample was shown (in lockstep the step after the sample the controller
        answers, as `run_lockstep`); in real time the first step stamped at or after its DDS reception."""
        rig = self.rig
        at = self.acting_step(rig.timing, key, max(rig.steps, self._shown + 1), rig.origin_ns, info)
        rig.timing.took(key, at)
        rig.schedule_step(at, action)

    def _on_duty(self, valve: str, msg: Float64, info: Any = None) -> None:
        self._answered.add(valve)
        self._take_duty(valve, msg.data, info)

    def _on_command(self, raw: bytes, info: Any = None) -> None:
        """A lockstep command: the answer to the sample it is stamped with, for every valve at once (a
        valve it leaves out keeps its duty, as with a callable); its flags go to the hook. An answer to
        an earlier sample (one published again) is not an answer to this one: left."""
        rig = self.rig
        try:
            stamp, names, values = decode(raw)
            duties, flags = split_command(names, values, rig.valve_names)
        except CommandError as err:
            self.counts.last_rejection = f"{COMMAND_TOPIC}: {err}"
            self.log_rejection(COMMAND_TOPIC, COMMAND_TOPIC, str(err), "the sample stays unanswered")
            return
        if stamp != rig.stamp_ns(self._shown) or len(self._answered) == len(rig.valve_names):
            return
        self._answered.update(rig.valve_names)
        for valve, duty in duties.items():
            self._take_duty(valve, duty, info)
        if flags and self.hook is not None:
            self.hook.flags_at(stamp, flags)

    def _take_duty(self, valve: str, value: float, info: Any) -> None:
        rig = self.rig
        try:
            duty = check_duty(value, rig.params.valve(valve).params.command.duty_range)
        except CommandError as err:
            self.counts.rejected[valve] += 1
            self.counts.last_rejection = f"{valve}/{DUTY_CYCLE}: {err}"
            self.log_rejection(valve, f"{valve}/{DUTY_CYCLE}", str(err))
            return
        self.counts.accepted[valve] += 1
        self._when(valve, info, partial(rig.set_duty, valve, duty))

    def _on_option(self, valve: str, name: str, msg: Float64, info: Any = None) -> None:
        """A valve option's temperature (K), checked as the emulator checks it; it acts as the duties do
        (`Rig.set_temperature`, which may still refuse it then: an oil too cold for the step)."""
        key, topic = f"{valve}.{name}", valve_topic(valve, name)
        try:
            value = check_temperature(name.replace("_", " "), msg.data)
        except CommandError as err:
            self._refuse_option(key, topic, str(err))
            return
        self.counts.accepted[key] += 1

        def apply() -> None:
            try:
                self.rig.set_temperature(valve, name, value)
            except CommandError as err:
                self.counts.accepted[key] -= 1
                self._refuse_option(key, topic, str(err))

        self._when(key, info, apply)

    def _refuse_option(self, key: str, topic: str, reason: str) -> None:
        self.counts.rejected[key] += 1
        self.counts.last_rejection = f"{topic}: {reason}"
        self.log_rejection(key, topic, reason)

    def _take_fault(self, text: str, info: Any) -> None:
        """Checked with the rig's fault table now; it acts as the inputs do (and is recorded then)."""
        rig = self.rig
        try:
            cmd = parse_fault_command(text, valves=rig.valve_names, signals=rig.signals)
        except FaultError as err:
            self._refuse_fault(str(err))
            return
        self.counts.faults_accepted += 1

        def apply() -> None:
            try:
                if cmd.clear:
                    rig.clear(cmd.target, cmd.kind)
                else:
                    assert cmd.fault is not None     # a command that is not a clear carries its fault
                    rig.inject(cmd.fault)
            except FaultError as err:            # e.g. clearing a fault that is not active
                self.counts.faults_accepted -= 1
                self._refuse_fault(str(err))
            else:
                self._record_text("faults", text)

        self._when(_FAULTS_KEY, info, apply)

    def _refuse_fault(self, reason: str) -> None:
        self.counts.faults_rejected += 1
        self.counts.last_rejection = f"{FAULTS}: {reason}"
        self.log_rejection(_FAULTS_KEY, FAULTS, reason, "nothing changed")

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
        sec, nsec = divmod(stamp, 1_000_000_000)
        isfinite = math.isfinite
        published = 0
        msg_p, msg_f = self._msg_pressure, self._msg_float
        msg_p.header.stamp.sec, msg_p.header.stamp.nanosec = sec, nsec
        for k, (pub_p, pub_i, pub_x) in enumerate(self._valve_pubs):
            p, i, x = y[3 * k:3 * k + 3]
            if isfinite(p):
                published += 1
                if pub_p.get_subscription_count():
                    msg_p.fluid_pressure = p
                    pub_p.publish(msg_p)
            if isfinite(i):
                published += 1
                if pub_i.get_subscription_count():
                    msg_f.data = i
                    pub_i.publish(msg_f)
            if isfinite(x):
                published += 1
                if pub_x.get_subscription_count():
                    msg_f.data = x
                    pub_x.publish(msg_f)
        for pub, j, msg in self._chamber_pubs:
            if isfinite(y[j]) and pub.get_subscription_count():
                msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nsec
                msg.fluid_pressure = y[j]
                pub.publish(msg)
        if self._pub_joint.get_subscription_count():
            # A dropped signal is left out of the message (JointState allows empty arrays per field).
            joint = self._msg_joint
            pos, vel, eff = (y[j] for j in self._cyl_i)
            joint.position = [pos] if isfinite(pos) else []
            joint.velocity = [vel] if isfinite(vel) else []
            joint.effort = [eff] if isfinite(eff) else []
            joint.header.stamp.sec, joint.header.stamp.nanosec = sec, nsec
            self._pub_joint.publish(joint)
        for pub, value in zip(self._option_pubs, self._last_options):
            if isfinite(value) and pub.get_subscription_count():
                msg_f.data = value
                pub.publish(msg_f)
        self.counts.samples_published += published

    def _statuses(self, now: float, recorder: RecorderStatus | None) -> list[Status]:
        """One status per valve and one for the rig (see pcv_sim.rig.diagnostics)."""
        rig = self.rig
        waiting = tuple(v for v in rig.valve_names if v not in self._answered) \
            if self.simulated and self.settings.lockstep else ()
        time_mode = "external_clock" if self.external_clock else self.settings.time_mode
        return self._diag.build(now, rig=rig, counts=self.counts, time_mode=time_mode, lockstep=self.settings.lockstep,
                                schedule=self._schedule, failure=rig.fault, waiting_for=waiting,
                                last=dict(zip((*rig.signals, *rig.option_outputs), (*self._last_sample,
                                                                                     *self._last_options))),
                                recorder=recorder)

    def _forward_log(self) -> None:
        """What the rig did that a user must hear about (watchdog, faults), once per event."""
        log = self.rig.log
        while self._logged < len(log):
            t, text = log[self._logged]
            self._logged += 1
            if "watchdog fired" in text:
                self.get_logger().warning(f"t = {t:.4f} s: {text}: send each valve's duty at least every "
                                          f"{self.rig.params.timing.watchdog_timeout:g} s; the next valid command "
                                          "resumes")
            else:
                self.get_logger().info(f"t = {t:.4f} s: {text}")

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
            self._forward_log()
        return True

    # --- loops ---------------------------------------------------------------------------------

    # --- external force, reset, external clock, recording ------------------------------------

    def _setup_more_interface(self) -> None:
        """The endpoints beside the samples and the duty and fault commands: `cylinder/external_force`,
        the `reset` service, /clock in (use_sim_time), the recorder (record.enabled)."""
        self._subscription(Float64, EXTERNAL_FORCE_TOPIC, self._on_external_force)
        self._external = ExternalClock(self.dt_ns)
        if self.external_clock:
            self._subscription(Clock, CLOCK, self._on_clock, CLOCK_QOS)
            self.get_logger().info("time from an external /clock (use_sim_time): model time 0 is the first /clock "
                                   "received, the model computes up to each new one")
        self.create_service(Trigger, RESET, self._on_reset)
        self._rec_logged = 0                                # rig.log entries written to the bag
        self.recorder = self._make_recorder()

    def _on_external_force(self, msg: Float64, info: Any = None) -> None:
        """N on the rod, + extending (toward +x); Rig.set_external_force's rules; acts as the inputs do."""
        try:
            force = check_external_force(msg.data)
        except CommandError as err:
            self.counts.force_rejected += 1
            self.counts.last_rejection = f"{EXTERNAL_FORCE_TOPIC}: {err}"
            self.log_rejection(EXTERNAL_FORCE_TOPIC, EXTERNAL_FORCE_TOPIC, str(err))
            return
        self.counts.force_accepted += 1
        self._when(EXTERNAL_FORCE, info, partial(self.rig.set_external_force, force))

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
            self._when("reset", None, self._reset_rig)
            response.message = "reset: the rig goes back to rest at the next step"
        response.message += (" (valves at their initial duty, piston at its initial position, faults cleared; "
                             "model time goes on)")
        response.success = True
        return response

    def _reset_rig(self) -> None:
        failure = self.rig.fault
        self.rig.reset(keep_time=True)
        self.counts.resets += 1
        if self.recorder is not None:
            self.recorder.restart_flows()            # the piston jumped: no mean flow across the reset
        if failure is not None:
            self.get_logger().info(f"reset: the model runs again (it had stopped: {failure})")
        self._forward_log()

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

    def _record_text(self, kind: str, text: str) -> None:
        """A fault command (`kind` faults) at the step it acted."""
        rec = self.recorder
        if rec is not None:
            rec.text(rec.faults_topic if kind == "faults" else rec.events_topic,
                     self.rig.stamp_ns(), text)

