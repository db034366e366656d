"""`NodeBase`: what a node of the package does whatever its device, written once (the one node class
over a device, `pcv_sim.node.device_node.DeviceNode`, is made of it).

- Construction: a ParameterError while setting up is logged (stderr and /rosout), the half-built
  node destroyed, the error raised for the process to exit 2 (`pcv_sim.node.process`).
- Parameters: each declared from its one declaration (dynamic typing, so that a wrong type gets our
  message, not rcl's); a `-p` override rcl dropped for its type is applied and checked like any
  value; names nobody declares are refused (or, with allow_unknown_parameters, warned about), at
  start and at run time ("unknown parameter(s) x (did you mean y?)", not rclpy's "undeclared
  parameter(s): []"); a numeric text for a float parameter (`ros2 param set` sends 2e-5 as text)
  is the number; use_sim_time cannot change while the node runs, nor go with simulated time.
- Services without an executor (`_poll_services`): requests are taken and answered in the loop;
  those in `_deferred_callbacks` are queued for `_pump` (the emulator computes rest states in a
  worker thread). QoS incompatibility events are polled with them and logged with the way out.
- One /clock: a simulated-time node refuses to start beside another /clock publisher.
- Refused inputs are counted by the device and logged at most once per reject_log_period per input.
- Recording: the recorder closed at the end, with what it wrote.
- Inputs act at the step `acting_step` gives (the device's `InputTiming`: from the DDS reception
  time in real time, from the first step not shown otherwise).
- The real-time loop and the external-clock loop (use_sim_time), written once over the node's
  `device` (`pcv_sim.device.device.Device`: steps, origin, skip, fault) and the hooks `_begin`,
  `_compute`, `_halted`, `_send_samples`, `_sample_period`; the simulated loop (lockstep or free
  running) too, waiting in lockstep for the `lockstep_keys` commands.
- Inputs taken by `_drain` (`take_message` polling of `_inputs`), services polled with them every
  SERVICE_POLL_PERIOD of wall time.
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
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from functools import partial
from operator import attrgetter
from typing import Any, Protocol

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.event_handler import PublisherEventCallbacks, SubscriptionEventCallbacks
from rclpy.exceptions import InvalidHandle
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSPolicyKind, QoSProfile
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import FluidPressure, JointState
from std_msgs.msg import Float64, String

from pcv_sim.device.device import Device
from pcv_sim.device.diagnostics import PeriodDiagnostics, Status
from pcv_sim.device.inputs import InputTiming
from pcv_sim.device.parameters import (
    Override,
    check_params_files,
    command_line_overrides,
    is_ros_own,
    numeric_text,
    override_not_taken,
    refuse_unknown,
    unknown_parameters_message,
)
from pcv_sim.device.settings import SettingsSchema
from pcv_sim.errors import BagError, ParameterError
from pcv_sim.io.bag import FLOAT64, FLUID_PRESSURE
from pcv_sim.io.recorder import SWITCH_INTERVAL, RecorderStatus, WriterSettings
from pcv_sim.io.topics import CLOCK, DUTY_CYCLE, FAULTS, InputTopic
from pcv_sim.node.lockstep_channel import COMMAND_TOPIC
from pcv_sim.node.polling import Waiter, drain, linger_for_rosout
from pcv_sim.simulation.clock import (
    NO_CLOCK_YET,
    SIM_TIME_CONFLICT,
    ExternalClock,
    RealTimeSchedule,
    SimulatedSchedule,
)

__all__ = [
    "CLOCK_DISCOVERY", "CLOCK_QOS", "COMMAND_QOS", "DIAGNOSTICS_QOS", "EVENT_POLL_EVERY", "JOB_SWITCH_INTERVAL",
    "LOCKSTEP_FULL_POLL",
    "LOCKSTEP_RESEND", "SERVICE_POLL_PERIOD",
    "NodeBase", "StopFlag", "freeze_heap", "publisher_name", "ros_value", "tighten_timer_slack",
]

COMMAND_QOS = QoSProfile(depth=10)          # reliable, volatile
DIAGNOSTICS_QOS = QoSProfile(depth=10)
CLOCK_QOS = QoSProfile(depth=10)
CLOCK_DISCOVERY = 3.0                       # s a simulated-time node looks for another /clock publisher at start
EVENT_POLL_EVERY = 10                       # service polls between QoS event polls
LOCKSTEP_RESEND = 0.5                       # s without a command: publish the last sample again
LOCKSTEP_FULL_POLL = 1e-3                   # s (wall) between polls of every input while the lockstep waits for its answers
SERVICE_POLL_PERIOD = 0.01                  # s (wall) between polls for service requests (reset, parameters)
JOB_SWITCH_INTERVAL = 2e-4                  # s, interpreter switch interval while the worker computes
SAMPLE_HINT = ("subscribe best effort (QoSProfile(depth=1000, reliability=BEST_EFFORT); "
               "ros2 topic echo --qos-reliability best_effort)")
COMMAND_HINT = "subscribe with a compatible QoS (reliable, volatile)"
KEPT = "the last valid value stays in force"            # what a refused input leaves
#: An input topic's message type -> (message class, what it carries).
_INPUT_MESSAGES: dict[str, tuple[Any, Callable[[Any], Any]]] = {
    FLOAT64: (Float64, attrgetter("data")), FLUID_PRESSURE: (FluidPressure, attrgetter("fluid_pressure"))}


class StopFlag(Protocol):
    """Set from outside (the signal handlers of `pcv_sim.node.process`); the loops poll it."""

    requested: bool


def ros_value(value: Any) -> Any:
    """A checked value as a ROS parameter value (ints given for a float parameter stay numbers)."""
    return list(value) if isinstance(value, tuple) else value


class NodeBase(Node):
    """The device-independent part of the package's node (see the module docstring). A subclass sets
    up in `_setup(argv)` and runs in `run(stop)`."""

    #: What the unknown-name message adds (where the other parameters are set).
    unknown_hint = ""
    #: The node's settings (`pcv_sim.device.settings.SettingsSchema`): what it declares and how it checks.
    schema: SettingsSchema[Any]
    settings: Any
    device: Device
    simulated: bool                 # time_mode simulated (else real: the wall clock, or an external /clock)
    recorder: Any                   # the bag recorder (record.enabled), or None
    _diag: PeriodDiagnostics
    _pub_diag: Any
    _external: ExternalClock
    _schedule: RealTimeSchedule | None
    _sim: SimulatedSchedule | None
    _pub_clock: Any                 # the /clock publisher (simulated time), or None
    #: The keys a lockstep waits for, one per answering command: its subscription is `_inputs[k]`
    #: (made first), its handler adds the key to `_answered`.
    lockstep_keys: tuple[str, ...] = ()

    def __init__(self, node_name: str, *, argv: list[str] | None = None, **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self._argv = list(sys.argv if argv is None else argv)
        self._retaken: dict[str, Override] = {}      # -p overrides rcl dropped, applied by us
        self._declared: set[str] = set()
        self._float_names: set[str] = set()
        # Parameter sets (and what else a node lists in `_deferred_callbacks`) go to a worker thread:
        # it validates them and prepares what they need (an emulator's rest state: 25-60 ms of model
        # solves), the loop swaps the result in at its next wake and only then answers. One request
        # at a time, in arrival order (`_pump`).
        self._worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="pcv_sim_prepare")
        self._deferred: deque[tuple[Any, Any, Any]] = deque()       # (service, request, header)
        self._job: tuple[Any, Any, Future[Any]] | None = None       # (service, header, answer)
        self._ready: list[Callable[[], None]] = []                  # worker-built, applied by the loop
        self._pending: tuple[Any, Any] | None = None                # (settings, device parameters) of the running job
        self._staged: tuple[Any, Any, Any] | None = None            # checked, about to be queued for the loop
        self._hold: list[bool] | None = None                        # `hold_answer` of the job being applied
        self._held: tuple[Any, Any, Any, list[bool]] | None = None  # (service, header, answer, acted) held back
        self._switch_interval = sys.getswitchinterval()
        self._deferred_callbacks: tuple[Any, ...] = (self._on_set_parameters, self._on_set_parameters_atomically)
        self._event_handlers: list[Any] = []
        self._polls = 0
        self._last_reject_log: dict[str, float] = {}
        self._suppressed: dict[str, int] = {}
        self._inputs: list[tuple[Any, Any]] = []    # (subscription, handler(msg, info)), taken by `_drain`
        self._answer_subs: list[Any] = []           # the lockstep_keys' commands, in their order
        self._channel_sub: Any = None               # the lockstep channel's command, when subscribed
        self._duty_topics: dict[str, str] = {}      # valve -> its duty's topic (the watchdog's message)
        self._logged = 0                            # device.log entries forwarded to the logger
        self._next_service_poll = 0.0               # monotonic s of the next service poll
        self._answered: set[str] = set()            # lockstep: keys heard since the last sample
        self._shown = 0                             # the last step whose sample was published
        self._schedule = None
        self._sim = None
        self._pub_clock = None
        self._msg_clock = Clock()
        #: a scenario's hook (pcv_sim.node.scenario_host): `sampled(true, measured)` before each period's
        #: samples are published, `answered(k)` when every key answered, before the next period
        self.hook: Any = None
        try:
            check_params_files(self._argv)
            self._cli = command_line_overrides(self._argv, self.get_name())
            self._setup(self._argv)
        except ParameterError as err:
            # Start-up errors also go to /rosout (a launch file's user may only see that), then the
            # half-built node is destroyed here: nobody else holds it.
            self.get_logger().error(f"invalid parameters: {err}")
            linger_for_rosout(self)
            self.destroy_node()
            raise

    def _setup(self, argv: list[str]) -> None:
        raise NotImplementedError

    # --- parameters ------------------------------------------------------------------------------

    def declare(self, name: str, default: Any, description: str, *, read_only: bool = False,
                is_float: bool = False) -> Any:
        """Declare one parameter; its value as given (the command line's if rcl dropped it)."""
        desc = ParameterDescriptor(description=description, dynamic_typing=True, read_only=read_only)
        value = self.declare_parameter(name, default, desc).value
        self._declared.add(name)
        if is_float:
            self._float_names.add(name)
        override = self._cli.get(name)
        if override is None or not override_not_taken(override, value):
            return value
        self._retaken[name] = override
        return override.value

    def declare_node_parameters(self) -> tuple[Any, Any]:
        """Declare the node's settings (`schema`) and the device's parameters (`_device_parameters`);
        the settings and the device's parameters, cross-checked. Refused (ParameterError naming it):
        an invalid value, and beyond what rcl checks, a params file with a key given twice, a `-p`
        override that did not take (rcl drops one whose type differs from the params file's), names
        nobody declares (unless allow_unknown_parameters; see pcv_sim.device.parameters)."""
        settings = self.schema.settings_from(self.declare_settings(self.schema.parameters, self.schema.check))
        self.take_parameter_services(bool(self.get_parameter("use_sim_time").value), settings.time_mode == "simulated")
        params = self._device_parameters(settings)
        self.refuse_unknown_names(settings.allow_unknown_parameters)
        self.set_retaken()
        settings.check(params)
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        return settings, params

    def _device_parameters(self, settings: Any) -> Any:
        """The device's parameters (its YAML), with those the node declares for it applied."""
        raise NotImplementedError

    def _validate_parameters(self, parameters: list[Any]) -> SetParametersResult:
        """on-set callback (worker thread): the whole change checked with the rules at start (settings
        by the schema, the device's parameters by `_prepare`), what it needs prepared and staged; the
        loop applies it (`_pump`). use_sim_time cannot change; rclpy refuses the read-only ones."""
        refused = self.sim_time_change_refused(parameters)
        if refused is not None:
            return refused
        settings_changes = {p.name: p.value for p in parameters if p.name in self.schema.by_name}
        device_changes = {p.name: p.value for p in parameters
                          if p.name not in self.schema.by_name and p.name in self._declared}
        base_settings, base_params = self._pending or (self.settings, self.device_params)
        try:
            settings = self.schema.with_changes(base_settings, settings_changes)
            params, prepared = self._prepare(base_params, device_changes)
            settings.check(params)
        except (ParameterError, ValueError) as err:
            return SetParametersResult(successful=False, reason=str(err))
        except Exception as err:
            return SetParametersResult(successful=False,
                                       reason=f"the model cannot run with these parameters: {type(err).__name__}: {err}")
        self._staged = (settings, params, prepared)
        return SetParametersResult(successful=True)

    @property
    def device_params(self) -> Any:
        """The device's parameters in force."""
        return self.device.params

    def _prepare(self, params: Any, changes: dict[str, Any]) -> tuple[Any, Any]:
        """Worker thread: `params` with the device's parameter `changes`, and what the loop installs for
        them (None: nothing); ParameterError for a refused change."""
        return params, None

    def _apply_parameters(self, parameters: list[Any]) -> None:
        """post-set callback (worker thread): queue what `_validate_parameters` staged for the loop."""
        if self._staged is None:
            return
        settings, params, prepared = self._staged
        self._staged = None
        self._pending = (settings, params)
        changed = ", ".join(f"{p.name} = {p.value!r}" for p in parameters)
        self._ready.append(lambda: self._apply(settings, prepared, changed))

    def _apply(self, settings: Any, prepared: Any, changed: str) -> None:
        """On the loop, between wakes: the new settings (and what the device prepared) in force from the
        next step."""
        self.settings = settings
        self._apply_settings(settings)
        self._retime(settings)
        self.get_logger().info(f"parameters changed: {changed}")
        if prepared is not None:
            self._install(prepared)

    def _apply_settings(self, settings: Any) -> None:
        """The settings the device holds (watchdog, safe duty...) into it (none here)."""

    def _install(self, prepared: Any) -> None:
        """What `_prepare` made, into the device (on the loop)."""
        raise NotImplementedError

    def declare_settings(self, specs: Iterable[Any], check: Callable[[str, Any], Any]) -> dict[str, Any]:
        """Declare each setting from its one declaration (`pcv_sim.params.setting`); its value checked
        by `check(name, value)` as soon as it is declared (ParameterError naming it)."""
        return {spec.name: check(spec.name, self.declare(spec.name, spec.default, f"{spec.description} [{spec.unit}]",
                                                          read_only=spec.read_only, is_float=spec.is_float))
                for spec in specs}

    def refuse_unknown_names(self, allowed: bool) -> None:
        """Names given (params file, -p) that nobody declared: ParameterError, or a warning if allowed."""
        overrides = set(getattr(self, "_parameter_overrides", {}) or {}) | set(self._cli)
        unknown = sorted(n for n in overrides if n not in self._declared and not is_ros_own(n))
        if unknown and not allowed:
            refuse_unknown(unknown, self._declared, hint=self.unknown_hint)
        if unknown:
            self.get_logger().warning(f"ignoring unknown parameter(s) (allow_unknown_parameters): {', '.join(unknown)}")

    def set_retaken(self) -> None:
        """After declaring: the values rcl dropped (and we took) set on the node, so that they read back."""
        if self._retaken:
            self.set_parameters([Parameter(n, value=ros_value(o.value)) for n, o in self._retaken.items()])

    def take_parameter_services(self, external_clock: bool, simulated: bool) -> None:
        """The parameter services answered by ours (unknown names named, numeric text for floats);
        use_sim_time with simulated time refused (ParameterError)."""
        if external_clock and simulated:
            raise ParameterError(SIM_TIME_CONFLICT)
        self.external_clock = external_clock
        for srv in self.services:
            if srv.srv_name.endswith("/set_parameters"):
                srv.callback = self._on_set_parameters
            elif srv.srv_name.endswith("/set_parameters_atomically"):
                srv.callback = self._on_set_parameters_atomically

    def _set_checked(self, parameters: list[Any]) -> SetParametersResult:   # rclpy Parameters (generic from kilted on)
        parameters = [Parameter(p.name, value=numeric_text(p.value)) if p.name in self._float_names else p
                      for p in parameters]
        unknown = [p.name for p in parameters if not self.has_parameter(p.name)]
        if unknown:
            return SetParametersResult(successful=False, reason=unknown_parameters_message(
                unknown, self._declared, hint=self.unknown_hint.split("; allow_unknown", maxsplit=1)[0]))
        return self.set_parameters_atomically(parameters)

    def _on_set_parameters(self, request: Any, response: Any) -> Any:
        """SetParameters service: one result per parameter, each set on its own (as rclpy does)."""
        for msg in request.parameters:
            response.results.append(self._set_checked([Parameter.from_parameter_msg(msg)]))
        return response

    def _on_set_parameters_atomically(self, request: Any, response: Any) -> Any:
        response.result = self._set_checked([Parameter.from_parameter_msg(m) for m in request.parameters])
        return response

    def sim_time_change_refused(self, parameters: Iterable[Any]) -> SetParametersResult | None:
        """use_sim_time (ROS's own, not read-only) cannot change while the node runs: the reason, or None."""
        for p in parameters:
            if p.name == "use_sim_time" and bool(p.value) != self.external_clock:
                return SetParametersResult(successful=False, reason=(
                    "use_sim_time is fixed while the node runs (the model's clock is chosen at start): restart "
                    f"with -p use_sim_time:={'true' if p.value else 'false'}"))
        return None

    # --- clock -----------------------------------------------------------------------------------

    def publish_clock(self, accepted: str) -> None:
        """In simulated time the /clock publisher, the domain's one clock: refused beside another
        (`accepted` says what to do instead); otherwise none."""
        if self.simulated:
            self.refuse_a_second_clock(accepted)
        self._pub_clock = (self.create_publisher(Clock, CLOCK, CLOCK_QOS, event_callbacks=self.output_events(CLOCK))
                           if self.simulated else None)

    def follow_clock(self) -> None:
        """With use_sim_time, /clock in: the model follows it (`ExternalClock`, `_run_external_clock`)."""
        self._external = ExternalClock(self.device.dt_ns)
        if self.external_clock:
            sub = self.create_subscription(Clock, CLOCK, self._on_clock, CLOCK_QOS,
                                           event_callbacks=self.input_events(CLOCK))
            self._inputs.append((sub, self._on_clock))

    def refuse_a_second_clock(self, accepted: str) -> None:
        """Two simulated-time nodes would both publish /clock, and every node with use_sim_time would see
        time jump between them. Before creating its own /clock publisher the node looks for another one
        for up to CLOCK_DISCOVERY s (discovery is usually done within the node's creation; under load it
        can take longer) and refuses to start if it finds one. Only the newcomer looks, so a running
        simulation is never stopped by a second one."""
        end = time.monotonic() + CLOCK_DISCOVERY
        while True:
            others = self.count_publishers(CLOCK)
            if others > 0 or time.monotonic() >= end:
                break
            time.sleep(0.05)
        if others > 0:
            raise ParameterError(f"time_mode: simulated: {others} other publisher(s) of {CLOCK} found; two clocks "
                                 f"make time jump for every node that follows /clock. Accepted is one clock: {accepted}")

    # --- inputs ----------------------------------------------------------------------------------

    def log_rejection(self, key: str, topic: str, reason: str, outcome: str = KEPT) -> None:
        """One log line per `key` per reject_log_period for refused inputs (the device counts them all)."""
        now = time.monotonic()
        if now - self._last_reject_log.get(key, -math.inf) < self.settings.reject_log_period:
            self._suppressed[key] = self._suppressed.get(key, 0) + 1
            return
        more = self._suppressed.pop(key, 0)
        self._last_reject_log[key] = now
        tail = f" ({more} more rejected since the last message)" if more else ""
        self.get_logger().warning(f"rejected {topic}: {reason}; {outcome}{tail}")

    def subscribe_inputs(self, table: Sequence[InputTopic], on_command: Callable[..., None] | None = None) -> None:
        """The device's input topics (`pcv_sim.io.topics.input_topics`), each taken into the device's
        `submit`. The valves' duties first, then, given `on_command`, the lockstep channel's command
        (raw CDR): the lockstep waits on these (`lockstep_keys`, `_lockstep_answers`)."""
        duties = [e for e in table if e.answers]
        self.lockstep_keys = tuple(e.answers for e in duties)
        for entry in (*duties, None, *(e for e in table if not e.answers)):
            if entry is None:
                if on_command is not None:
                    sub = self.create_subscription(JointState, COMMAND_TOPIC, on_command, COMMAND_QOS, raw=True,
                                                   event_callbacks=self.input_events(COMMAND_TOPIC))
                    self._inputs.append((sub, on_command))
                    self._channel_sub = sub
                continue
            msg_type, value_of = _INPUT_MESSAGES[entry.type]
            handler = partial(self._on_input, entry, value_of)
            sub = self.create_subscription(msg_type, entry.topic, handler, COMMAND_QOS,
                                           event_callbacks=self.input_events(entry.topic))
            self._inputs.append((sub, handler))
            if entry.answers:
                self._answer_subs.append(sub)
                self._duty_topics[entry.answers] = entry.topic

    def _on_input(self, entry: InputTopic, value_of: Callable[[Any], Any], msg: Any, info: Any = None) -> None:
        if entry.answers:
            self._answered.add(entry.answers)        # valid or not: the lockstep's answer
        self.take_input(entry.input, entry.topic, value_of(msg), info)

    def take_input(self, name: str, topic: str, value: Any, info: Any) -> None:
        """An input of the device (its name; `topic` for the log), checked now by the device and
        acting from the step an input taken now acts from (`acting_step`); a refused one logged."""
        dev = self.device
        at = self.acting_step(dev.timing, name, self.first_open_step(), dev.origin_ns, info)
        reason = dev.submit(name, value, at)
        if reason is not None:
            self.log_rejection(name, topic, reason)
        else:
            dev.timing.took(name, at)

    def first_open_step(self) -> int:
        """The first step whose sample nobody has seen: an input taken now acts from there at the earliest."""
        return max(self.device.first_open_step(), self._shown + 1)

    def acting_step(self, timing: InputTiming, name: str, first: int, origin_ns: int, info: Any) -> int:
        """The step an input of `name` taken now acts from (`InputTiming`, the devices' one rule; `first`:
        the first step not shown): in real time from its DDS reception time, otherwise from `first`."""
        sched = self._schedule
        if sched is None:
            return timing.step(name, first)
        r_ns = info.get("received_timestamp", 0) if isinstance(info, dict) else 0
        return timing.step(name, first, received_ns=r_ns, origin_ns=origin_ns, elapsed=time.monotonic() - sched.t0)

    def subscribe_faults(self) -> None:
        """The `faults` topic, with faults.enabled only: any node on the domain could break the bench."""
        if self.settings.faults_enabled:
            sub = self.create_subscription(String, FAULTS, self._on_fault, COMMAND_QOS,
                                           event_callbacks=self.input_events(FAULTS))
            self._inputs.append((sub, self._on_fault))

    def _on_fault(self, msg: String, info: Any = None) -> None:
        """A fault command, logged with its publisher; the device's part (`_take_fault`) checks it and
        lets it act as an input taken now would."""
        self.get_logger().info(f"fault command {msg.data!r} from {self.publisher_of(FAULTS, info)}")
        self._take_fault(msg.data, info)

    def _take_fault(self, text: str, info: Any) -> None:
        """Checked by the device now, acting as an input taken now."""
        dev = self.device
        at = self.acting_step(dev.timing, FAULTS, self.first_open_step(), dev.origin_ns, info)
        reason = dev.submit_fault(text, at)
        if reason is not None:
            self.log_rejection(FAULTS, FAULTS, reason, "nothing changed")
        else:
            dev.timing.took(FAULTS, at)

    def forward_log(self) -> None:
        """What the device did that a user must hear about (its log: watchdogs, faults, resets), once
        per event: a watchdog firing as a warning saying what to send, the rest as information."""
        dev = self.device
        log = dev.log
        if self._logged > len(log):
            self._logged = 0                # the device started its log anew
        while self._logged < len(log):
            t, text = log[self._logged]
            self._logged += 1
            valve, _, what = text.partition(": ")
            watchdog = dev.watchdogs.get(valve)
            if watchdog is not None and what.startswith("watchdog fired"):
                topic = self._duty_topics.get(valve, DUTY_CYCLE)
                timeout = watchdog.timeout_steps * dev.dt
                self.get_logger().warning(
                    f"t = {t:.4f} s: {text}; watchdog: no valid {topic} command for {timeout:g} s (model time): the "
                    f"duty fell to safe_duty {dev.safe_duty:g}. Send the duty at least every {timeout:g} s (a "
                    f"controller does; by hand: ros2 topic pub -r 10 {topic} std_msgs/msg/Float64 '{{data: 0.7}}'), "
                    "or raise watchdog_timeout (0 = off). The next valid command resumes.")
            elif watchdog is not None and what.startswith("watchdog cleared"):
                self.get_logger().info(f"t = {t:.4f} s: {text}; watchdog: duty commands resumed, duty "
                                       f"{dev.duties[valve]:g}")
            else:
                self.get_logger().info(f"t = {t:.4f} s: {text}")

    def publisher_of(self, topic: str, info: Any) -> str:
        """The node that published a message on `topic` (`publisher_name`)."""
        return publisher_name(self.get_publishers_info_by_topic(topic), info)

    # --- services and QoS events ---------------------------------------------------------------

    def _poll_services(self) -> None:
        """Answer pending service requests the way an executor would; those in `_deferred_callbacks`
        go to `_defer` (a worker thread), the rest is answered here. Every EVENT_POLL_EVERY polls the
        QoS events too."""
        for srv in list(self.services):
            srv_type: Any = srv.srv_type         # jazzy's annotation (SrvType) names no Request/Response
            while True:
                try:
                    with srv.handle:
                        request, header = srv.handle.service_take_request(srv_type.Request)
                except InvalidHandle:
                    break
                if header is None:
                    break
                if srv.callback in self._deferred_callbacks:
                    self._defer(srv, request, header)
                else:
                    srv.send_response(srv.callback(request, srv_type.Response()), header)
        self._pump()
        self._polls += 1
        if self._polls % EVENT_POLL_EVERY == 0:
            self._poll_events()

    def _defer(self, srv: Any, request: Any, header: Any) -> None:
        """Parameter sets (and the node's other `_deferred_callbacks`): to the worker thread, in arrival
        order (`_pump`)."""
        self._deferred.append((srv, request, header))

    def _pump(self) -> None:
        """At a step boundary: apply a finished worker job (new settings, model) and answer its request;
        start the next one. Cheap when idle: called at every wake."""
        held = self._held
        if held is not None:
            if not held[3]:
                return                      # its answer waits until what it asked for acted
            self._held = None
            held[0].send_response(held[2], held[1])
        job = self._job
        if job is not None:
            srv, header, answer = job
            if not answer.done():
                return
            self._job = None
            sys.setswitchinterval(self._switch_interval)
            self._hold = None
            for apply in self._ready:
                apply()
            self._ready.clear()
            self._pending = None
            if self._hold is not None:
                self._held = (srv, header, answer.result(), self._hold)
                return
            srv.send_response(answer.result(), header)
        if self._deferred:
            srv, request, header = self._deferred.popleft()
            # While the worker computes (~40 ms of Python) the loop waits for the interpreter lock at
            # each wake: a short switch interval hands it over sooner (bench/node_restart.py).
            self._switch_interval = sys.getswitchinterval()
            sys.setswitchinterval(JOB_SWITCH_INTERVAL)
            self._job = (srv, header, self._worker.submit(self._serve, srv, request))

    def hold_answer(self) -> list[bool]:
        """From a worker-built callback the loop applies: the request's answer waits (and the next
        request with it) until the returned list is not empty (what the request asked for acted)."""
        self._hold = []
        return self._hold

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

    def output_events(self, topic: str, hint: str = COMMAND_HINT) -> PublisherEventCallbacks:
        return PublisherEventCallbacks(incompatible_qos=lambda info: self._incompatible(
            topic, "a subscriber", info, hint))

    def input_events(self, topic: str) -> SubscriptionEventCallbacks:
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

    def collect_event_handlers(self) -> None:
        """After the endpoints are made: the QoS event handlers `_poll_events` takes."""
        self._event_handlers = [h for e in (*self.publishers, *self.subscriptions)
                                for h in getattr(e, "event_handlers", ())]

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

    # --- the loops -------------------------------------------------------------------------------

    def run(self, stop: StopFlag) -> None:
        """Run the loop of the node's time mode until stop.requested (SIGINT/SIGTERM); then `_finish`
        (the bag of record.enabled finalised)."""
        try:
            if self.simulated:
                self._run_simulated(stop)
            elif self.external_clock:
                self._run_external_clock(stop)
            else:
                self._run_real_time(stop)
        finally:
            self._finish()

    def _lockstep_answers(self) -> tuple[list[Any], Any]:
        """The subscriptions of the `lockstep_keys` commands (made first, in that order), and one that
        answers for all of them at once (a lockstep channel, made right after them), or None."""
        return list(self._answer_subs), self._channel_sub

    def _wait_for_controllers(self, stop: StopFlag, subs: list[Any], channel: Any) -> None:
        """Lockstep: before the first sample, until every answering command (or the channel that
        answers for all) has a matched publisher (a command sent before that is lost); the 0.5 s
        re-publication covers what is left. Service requests (parameters, reset) are answered meanwhile."""
        start = time.monotonic()
        told = False
        while not stop.requested and not all(sub.get_publisher_count() > 0 for sub in subs) \
                and not (channel is not None and channel.get_publisher_count() > 0):
            if not told and time.monotonic() - start > 2.0:
                missing = [sub.topic_name for sub in subs if sub.get_publisher_count() == 0]
                alternative = f" (or {channel.topic_name})" if channel is not None else ""
                self.get_logger().info(f"lockstep: waiting for a controller publishing {', '.join(missing)}"
                                       f"{alternative}")
                told = True
            self._poll_services()
            time.sleep(0.01)

    def _run_simulated(self, stop: StopFlag) -> None:
        """Simulated time: model time from 0, in periods of one sample (`_sample_period` steps), /clock
        published with each sample.

        Lockstep (default): publish /clock and the samples at T, wait until every `lockstep_keys`
        command has had a message since then, apply them from T + dt, the first step not shown (the
        sample at T shows the inputs in force at T), compute to the next sample, repeat: a controller
        that answers every sample the same way sees bit for bit the same run. A sample left
        unanswered for 0.5 s is published again (a controller not yet connected, a lost command).
        Without lockstep the periods run back to back, paced by real_time_factor, and an input acts
        from the period after it was taken, which depends on wall-clock timing."""
        s, dev = self.settings, self.device
        lock = s.lockstep
        sim = self._sim = SimulatedSchedule(dev.dt, factor=s.real_time_factor)
        tighten_timer_slack()         # the free-running wait sleeps to its period's wall time
        freeze_heap()
        mono = time.monotonic
        keys = self.lockstep_keys
        subs, channel = self._lockstep_answers()
        answers = self._inputs[:len(subs) + (channel is not None)]      # made first, in this order
        if lock:
            self._wait_for_controllers(stop, subs, channel)
        sim.start()
        self._diag.restart(mono(), dev.steps)
        next_diag = mono() + s.diagnostics_period
        self._begin(0)
        published = mono()
        self._answered.clear()
        waiter = Waiter([sub for sub, _ in answers], self.context)
        next_full = 0.0
        while not stop.requested:
            answers_only = lock and len(self._answered) < len(keys) and mono() < next_full
            if answers_only:
                drain(answers)               # waiting: the answers alone, blocked in `waiter` between
                                             # (BENCHMARKS.md, "Where a 1 kHz lockstep period goes")
            else:
                self._drain()
                next_full = mono() + LOCKSTEP_FULL_POLL
            now = mono()
            if now >= next_diag:
                self._publish_diagnostics(now)
                next_diag = max(next_diag + self.settings.diagnostics_period, now)
            if dev.fault is not None:
                time.sleep(1e-3)             # model time stands still until reset
                continue
            period = self._sample_period()
            if lock:
                if len(self._answered) < len(keys):
                    if now - published > LOCKSTEP_RESEND:
                        missing = [k for k in keys if k not in self._answered]
                        # A command was lost (sent before its publisher matched) or the controller is
                        # slow: an answer to both copies may count for the next period, so such a run
                        # is not promised to repeat bit for bit; say so.
                        self.get_logger().warning(
                            f"lockstep: no duty_cycle from {', '.join(missing)} for {LOCKSTEP_RESEND:g} s after the "
                            f"sample at t = {dev.time:.4f} s: published again", throttle_duration_sec=5.0)
                        self._publish_clock()
                        self._send_samples()
                        published = now
                    waiter.wait(max(0.0, next_full - now))       # woken by an answer
                    continue
            else:
                ready = sim.ready_at(period)
                if ready > now:
                    time.sleep(min(ready - now, 1e-3))
                    continue
            if answers_only:
                self._drain()                # what came with the answers acts from the same step as before
            chunk = period - dev.steps % period
            target = dev.steps + chunk
            if self.hook is not None:
                # The answers act from the step after the sample (scheduled there): take that one
                # step first, so the hook sees the inputs in force after the instant.
                k = self._shown // period
                self._compute(1)
                if dev.fault is not None:
                    continue
                self.hook.answered(k)
            self._answered.clear()
            self._compute(target - dev.steps)
            if dev.fault is None:
                sim.advance(chunk)
            published = mono()

    def _sample_period(self) -> int:
        """Model steps between two samples."""
        raise NotImplementedError

    def _send_samples(self) -> None:
        """Publish the last sample again (a lockstep re-publication: not computed anew)."""
        raise NotImplementedError

    def _publish_clock(self) -> None:
        """/clock at the present model step (simulated time: the one clock of the domain)."""
        msg = self._msg_clock
        msg.clock.sec, msg.clock.nanosec = divmod(self.device.stamp_ns(), 1_000_000_000)
        assert self._pub_clock is not None              # created in simulated time, the only caller
        self._pub_clock.publish(msg)

    def _on_clock(self, msg: Clock, _info: Any = None) -> None:
        """use_sim_time: the latest external /clock."""
        self._external.take(msg.clock.sec * 1_000_000_000 + msg.clock.nanosec)

    def _finish(self) -> None:
        """After the loop: the worker stopped, the recorder closed."""
        self._worker.shutdown(wait=True, cancel_futures=True)
        self.close_recorder(self.recorder)

    def _run_real_time(self, stop: StopFlag) -> None:
        """Real time: wake on a fixed grid of the monotonic clock (`wake_period`), take the inputs, run the
        steps due by wall time (`RealTimeSchedule`: model time never ahead of wall time, never drifting),
        publish the samples that fell due. Falling behind: the backlog is computed up to the catch-up
        bound (`overrun`, `max_catchup`), beyond it skipped (the model state held over it)."""
        s, dev = self.settings, self.device
        sched = RealTimeSchedule(dev.dt, wake_period=s.wake_period, late_threshold=s.late_threshold,
                                 max_catchup=s.catchup_bound)
        self._schedule = sched
        tighten_timer_slack()
        # Another Python thread (a worker computing rest states, a recorder) competes for the
        # interpreter lock: hand it back within one wake period rather than the default 5 ms.
        sys.setswitchinterval(SWITCH_INTERVAL)
        if s.realtime_priority:
            self.set_realtime_priority(s.realtime_priority)
        freeze_heap()
        mono = time.monotonic
        sched.start()
        self._begin(self.get_clock().now().nanoseconds)
        self._diag.restart(mono(), dev.steps)
        next_diag = mono() + s.diagnostics_period
        cpu = time.thread_time
        while not stop.requested:
            now = mono()
            c0 = cpu()
            self._drain()
            if not self._halted():
                plan = sched.plan(now)
                if plan.skipped:
                    self._skip(plan.skipped)
                    st = self.settings
                    bound = (f"max_catchup {st.max_catchup * 1e3:g} ms" if st.overrun == "catch_up"
                             else "one wake period, overrun: skip")
                    self.get_logger().warning(
                        f"{plan.lag * 1e3:.1f} ms behind wall time (more than {bound}): "
                        f"skipped {plan.skipped} steps, the model state was held over them",
                        throttle_duration_sec=1.0)
                if plan.steps:
                    self._compute(plan.steps)
                sched.finish()
            sched.note_wake_cpu(cpu() - c0)
            if now >= next_diag:
                self._publish_diagnostics(now)
                next_diag = max(next_diag + self.settings.diagnostics_period, now)
            delay = sched.next_wake() - mono()
            if delay > 0.0:
                time.sleep(delay)

    def _retime(self, settings: Any) -> None:
        """Changed settings into the running loop's schedule (late threshold, catch-up bound, pace)."""
        if self._schedule is not None:
            self._schedule.late_threshold = settings.late_threshold
            self._schedule.max_catchup_steps = int(settings.catchup_bound / self.device.dt)
        if self._sim is not None and self._sim.factor != settings.real_time_factor:
            self._sim.set_factor(settings.real_time_factor)

    # --- the external-clock loop -----------------------------------------------------------------

    def _run_external_clock(self, stop: StopFlag) -> None:
        """use_sim_time: model time follows an external /clock (e.g. a Gazebo simulation).

        Model time 0 is the first /clock received (stamps = that clock); whenever /clock advances,
        the steps up to it run and the samples that fell due are published. An input acts from the
        step after the last one run when it was taken. The clock going back (a simulation reset)
        re-anchors model time at the new clock, keeping the model's state; a jump far ahead is held
        (`ExternalClock`)."""
        freeze_heap()
        mono = time.monotonic
        ext = self._external
        self._diag.restart(mono(), self.model_steps)
        next_diag = mono() + self.settings.diagnostics_period
        loops = 0
        while not stop.requested:
            loops += 1
            self._drain()
            now = mono()
            if now >= next_diag:
                self._publish_diagnostics(now)
                next_diag = max(next_diag + self.settings.diagnostics_period, now)
            if ext.latest_ns is None:
                if loops == 2000:           # ~2 s: say why nothing is published
                    self.get_logger().warning(NO_CLOCK_YET)
                time.sleep(1e-3)
                continue
            if not ext.started:
                self._begin(ext.start(self.model_steps))
                continue
            if self._halted():
                time.sleep(1e-2)
                continue
            plan = ext.plan(self.model_steps)
            if plan.reanchored:
                self._set_origin(ext.origin_ns)
                self.get_logger().warning(ext.went_back(), throttle_duration_sec=1.0)
            elif plan.skip:
                self._skip(plan.skip)
                self.get_logger().warning(ext.jumped(plan.skip), throttle_duration_sec=1.0)
            elif plan.run:
                self._compute(plan.run)
            else:
                time.sleep(2e-4)           # wait for the clock to advance

    @property
    def model_steps(self) -> int:
        """The device's model steps computed (or skipped) so far."""
        return self.device.steps

    def _drain(self) -> int:
        """Take every pending input message (no executor: `take_message` polling); every
        SERVICE_POLL_PERIOD also the service requests, and in between a deferred request's answer
        if one is ready (`_pump`)."""
        n = drain(self._inputs)
        now = time.monotonic()
        if now >= self._next_service_poll:
            self._next_service_poll = now + SERVICE_POLL_PERIOD
            self._poll_services()
        else:
            self._pump()
        return n

    def _publish_diagnostics(self, now: float) -> None:
        """/diagnostics: the device's statuses (`_statuses`), stamped with the model time in simulated
        time and with an external clock (the node's ROS clock is not updated without an executor),
        with wall time in real time."""
        msg = DiagnosticArray()
        model_clock = self.simulated or self.external_clock
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(
            self.device.stamp_ns() if model_clock else time.time_ns(), 1_000_000_000)
        for st in self._statuses(now, self.recorder.status() if self.recorder is not None else None):
            d = DiagnosticStatus(level=bytes([st.level]), name=st.name, message=st.message, hardware_id=st.hardware_id)
            d.values = [KeyValue(key=k, value=v) for k, v in st.values.items()]
            msg.status.append(d)
        self._pub_diag.publish(msg)

    def _statuses(self, now: float, recorder: RecorderStatus | None) -> list[Status]:
        """The device's statuses (`recorder`: the recording's status, record.enabled)."""
        raise NotImplementedError

    def _begin(self, origin_ns: int) -> None:
        """Model time 0 is stamped origin_ns: the first sample (and the recording) start."""
        raise NotImplementedError

    def _set_origin(self, origin_ns: int) -> None:
        self.device.origin_ns = origin_ns

    def _skip(self, n: int) -> None:
        """n steps of model time pass uncomputed (the state held)."""
        self.device.skip(n)

    def _compute(self, n: int) -> None:
        """n model steps computed, their samples published."""
        raise NotImplementedError

    def _halted(self) -> bool:
        """True while the model stands still (it ran away) until a reset."""
        return False

    # --- recording and scheduling ----------------------------------------------------------------

    def open_recorder(self, make: Callable[..., Any]) -> Any:
        """The bag recorder record.* asks for (None when off): `make(directory, **what every node's
        recorder takes)` with the device's own arguments bound; ParameterError if it cannot start."""
        s = self.settings
        if not s.record_enabled:
            return None
        try:
            return make(os.path.expanduser(s.record_directory), name=s.record_name or None,
                        namespace=self.get_namespace(), writing=WriterSettings(
                            split_size_bytes=round(s.record_split_size_mb * 1e6) if s.record_split_size_mb else None,
                            writer="process",  # the disk work off the loop's interpreter lock (pcv_sim.io.writer_process)
                            when_full="wait" if self.simulated else "drop"))   # simulated time may outrun the writer
        except BagError as err:
            raise ParameterError(f"record.directory / record.name: cannot record: {err}") from None

    def recording_started(self, recorder: Any, what: str) -> None:
        """After `recorder.start`: the interpreter handed to a writer thread within a wake; say what goes where."""
        if recorder.threaded:
            sys.setswitchinterval(SWITCH_INTERVAL)
        self.get_logger().info(f"recording {what}")

    def close_recorder(self, recorder: Any) -> None:
        """Close a bag recorder (None: nothing) and say what it wrote."""
        if recorder is None:
            return
        st = recorder.close()
        text = (f"bag {st.path}: {st.messages} messages, {st.bytes} bytes in {st.files} file(s)"
                f"{f', {st.dropped} messages dropped' if st.dropped else ''}")
        if st.error:
            self.get_logger().error(f"recording failed ({st.error}); {text}")
        else:
            self.get_logger().info(f"recording finished: {text}")

    def set_realtime_priority(self, priority: int) -> None:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        except (OSError, AttributeError) as err:
            self.get_logger().warning(f"realtime_priority {priority}: SCHED_FIFO refused ({err}); running with "
                                      "normal scheduling (grant an rtprio limit or run as root)")
        else:
            self.get_logger().info(f"loop thread under SCHED_FIFO, priority {priority}")


def tighten_timer_slack() -> None:
    """Ask Linux for 1 ns timer slack (default 50 us): wakes land ~50 us closer to the grid."""
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL(None, use_errno=True).prctl(29, 1, 0, 0, 0)   # PR_SET_TIMERSLACK


def freeze_heap() -> None:
    """Move everything allocated so far (rclpy, numpy, scipy, the model: ~50 000 objects) out of
    the garbage collector's reach. A full collection over them takes ~17 ms here, which would
    make a wake-up that many ms late; the loop itself only makes short-lived objects."""
    gc.collect()
    gc.freeze()


def publisher_name(endpoints: Any, info: Any) -> str:
    """Who published a message, for the log: the node whose endpoint GID is the publisher GID in the
    message's MessageInfo (Kilted's rclpy gives it). Where the MessageInfo carries no GID (Jazzy's
    rclpy), the topic's publishers tell it when there is only one of them, and narrow it otherwise."""
    def name(e: Any) -> str:
        return f"{e.node_namespace.rstrip('/')}/{e.node_name}"

    endpoints = list(endpoints)
    gid = info.get("publisher_gid") if isinstance(info, dict) else None
    data = list(gid.get("data", ())) if isinstance(gid, dict) else []
    if any(data):
        for e in endpoints:
            known = list(e.endpoint_gid)
            n = min(len(known), len(data))
            if n and known[:n] == data[:n]:
                return f"node {name(e)}"
        return "a publisher DDS did not name"
    if len(endpoints) == 1:
        return f"node {name(endpoints[0])} (the topic's only publisher; DDS gave no publisher GID)"
    if endpoints:
        return f"one of the nodes {', '.join(sorted(name(e) for e in endpoints))} (DDS gave no publisher GID)"
    return "a publisher DDS did not name"
