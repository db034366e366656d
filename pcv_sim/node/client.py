"""The ROS client of any device node (`DeviceClient`): the emulator's and the rig's, built from the
interface registry (`pcv_sim.io.topics`: a device's inputs and signals name its topics). Used by the
demo, the tests, the benchmarks and the steering controller; also a starting point for a controller.

What it does for any device:
- send any of its inputs by name (`send("left.duty_cycle", 0.6)`, `send_duty`...), fault commands
  (the node takes them with its `faults` topic enabled), call its `reset` service, set its
  parameters (`set_parameters`, as `ros2 param set`);
- collect its samples (`samples`: the pressure of the emulator's valve with its DDS timestamps;
  `outputs`: its current and spool position) and its diagnostics (`statuses`: per message, each
  status by name; `diagnostics`: the statuses' values merged, as the emulator's unique keys allow);
- wait: `spin_for`, `spin_until`, `wait_for_device`, `wait_for_diagnostics`;
- answer it in lockstep (`run(controller, periods)`): with `lockstep`, a controller is called once
  per sample period with what was measured and its duties are sent back, over the per-valve topics
  or, with `channel`, the lockstep channel (`pcv_sim.node.lockstep_channel`: a period is one
  `lockstep/sample`, every signal of the device and the scenario's `setpoint`, and one
  `lockstep/command` back with the duties and flags, stamped with the sample it answers).

The emulator is the device of one valve whose names are bare (`duty_cycle`, `pressure`; its valve is
`valve` for a controller's duties and the channel's `valve.duty`): `DeviceClient(namespace)`. The
rig names its valves (`left.duty_cycle` on `left/duty_cycle`) and has the cylinder:
`DeviceClient(namespace, ("left", "right"), device_node="rig")`. `EmulatorClient` and `RigClient`
are these two configurations.

Messages are taken without an executor in a lockstep (`take_message`, `poll`: ~125 us per executor
`spin_once` against a 1 ms control period), blocked between periods in an rcl wait set on the
period's last topic (`pcv_sim.node.polling.Waiter`). A period on the topics is complete when the
cylinder's `joint_states` (the rig publishes it last; the emulator: its pressure) stamped with its
model time has arrived and the topics published before it have been taken once more; the controller
then gets `<valve>.pressure` Pa, with `currents` also `<valve>.current` A (std_msgs/Float64 carries
no stamp: the one received since the last answer), `cylinder.position` m, `cylinder.velocity` m/s,
`cylinder.effort` N; a sample the device dropped (a sensor fault) is absent. A sample published
again (unanswered for 0.5 s) is answered again with the same duties; one stamped before the last
one answered is a new run (the device restarted): `rewind` gives a fresh controller. Between runs
the same subscriptions are spun by the client's executor (`spin_for`), their handlers the same.

Samples arrive with sensor-data QoS. `qos_profile_sensor_data` keeps only 5 messages: a Python
subscriber busy for a few ms loses 1 kHz samples. This client subscribes best effort with a deep
queue (`sample_depth`), which is what a subscriber that must see every sample should do.

The client makes its own node, or works on a node it is given (`node=`: the `steering_controller`
node, with its parameters and its own inputs added by `add_input`; its services then go through a
node of their own, made at the first call).

Here: making it (its publishers and subscriptions by the device's names), sending inputs and
waiting. Its parts are modules beside it: `client_messages.py` (the handlers: what it takes of
samples and diagnostics), `client_lockstep.py` (`run`, the lockstep controller runner),
`client_services.py` (`reset`, `set_parameters`).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.srv import SetParameters
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import QoSProfile
from sensor_msgs.msg import FluidPressure, JointState
from std_msgs.msg import Float64, String
from std_srvs.srv import Trigger

from pcv_sim.io import topics
from pcv_sim.io.bag import FLUID_PRESSURE
from pcv_sim.node.client_lockstep import FULL_POLL, Controller, LockstepRunner, PartialPeriod, Period
from pcv_sim.node.client_messages import ClientMessages, PressureSample, diagnostic_level, sample_qos, stamp_ns
from pcv_sim.node.client_services import SERVICE_AGAIN, ServiceCalls, call_service
from pcv_sim.node.lockstep_channel import COMMAND_TOPIC, SAMPLE_TOPIC, NamedVector
from pcv_sim.node.polling import Waiter
from pcv_sim.node.qos_events import topic_qos

__all__ = ["FULL_POLL", "SERVICE_AGAIN", "Controller", "DeviceClient", "EmulatorClient", "Period", "PressureSample",
           "RigClient", "call_service", "diagnostic_level", "sample_qos", "stamp_ns"]

VALVE = "valve"         # the emulator's one valve (pcv_sim.device.valve.VALVE): its duty's key
EMULATOR_INPUTS = (topics.DUTY_CYCLE, topics.LOAD_FLOW, topics.SUPPLY_PRESSURE)


class DeviceClient(ClientMessages, LockstepRunner, ServiceCalls):
    """Talks to the device node `device_node` in `namespace` (see the module docstring). `valves`:
    the device's valve names; `lone_valve`: the device is the emulator's lone valve (the device's
    `lone_valve`: its names are the roles alone, its valve `valve`; None: when no `valves` are
    named). `inputs`: the inputs
    whose publishers are made at once (default: the emulator's three, or each valve's duty and the
    cylinder's force); any other is made at its first `send`. `outputs`: the emulator's signals
    collected in `samples` and `outputs`. `lockstep`: subscribed for `run` (with `channel`, to the
    lockstep channel); `currents`: each valve's current measured too; `history`: keep every answered
    Period, every current and the diagnostics (a long-running controller: False)."""

    def __init__(self, namespace: str | None = "/", valves: tuple[str, ...] = (), *, context: Any = None,
                 node_name: str = "pcv_client", node: Any = None, device_node: str = "emulator",
                 inputs: tuple[str, ...] | None = None, outputs: tuple[str, ...] = (), sample_depth: int = 10000,
                 on_pressure: Callable[[PressureSample], None] | None = None, lockstep: bool = False,
                 channel: bool = False, currents: bool = False, history: bool = True,
                 lone_valve: bool | None = None) -> None:
        self._own_node = node is None
        self.node = rclpy.create_node(node_name, namespace=namespace, context=context) if node is None else node
        node = self.node
        self.context = node.context
        self.device_name = f"{node.get_namespace().rstrip('/')}/{device_node}"
        self.emulator_name = self.device_name
        self.lone_valve = not valves if lone_valve is None else lone_valve
        if self.lone_valve and valves not in ((), (VALVE,)):
            raise ValueError(f"the lone valve is {VALVE!r}; got valves {valves!r}")
        self.valves = (VALVE,) if self.lone_valve else valves
        self.cylinder = not self.lone_valve      # the rig: its valves on the cylinder
        self.history = history
        self.channel = channel
        self.lockstep = lockstep or channel
        self._currents = currents
        self.fault_pub = node.create_publisher(String, topics.FAULTS, topic_qos(topics.FAULTS))
        self._clients: dict[str, Any] = {}
        self._srv: tuple[Any, SingleThreadedExecutor] | None = None     # services of a node given (`_service_node`)

        # --- inputs, by the device's names ---
        self._pubs: dict[str, tuple[Any, Any, Any]] = {}   # input -> (publisher, message, its field's setter)
        if inputs is None:
            inputs = EMULATOR_INPUTS if self.lone_valve else (
                *(self.key(v, topics.DUTY_CYCLE) for v in self.valves),
                f"{topics.CYLINDER}.{topics.EXTERNAL_FORCE}")
        for name in inputs:
            if channel and name.rpartition(".")[2] == topics.DUTY_CYCLE:
                continue                         # the duties go in the channel's command
            self._publisher(name)
        self.duty_pubs = {v: self._pubs[self.key(v, topics.DUTY_CYCLE)][0] for v in self.valves
                          if self.key(v, topics.DUTY_CYCLE) in self._pubs}
        self.command_pub = node.create_publisher(JointState, COMMAND_TOPIC, topic_qos(COMMAND_TOPIC)) if channel else None
        self._commands: dict[tuple[str, ...], NamedVector] = {}
        self._duty_msg = Float64()
        self.duty_sent: list[tuple[float, int]] = []

        # --- what it collects ---
        self.samples: list[PressureSample] = []
        self.outputs: dict[str, list[tuple[int, float]]] = {topics.CURRENT: [], topics.SPOOL_POSITION: []}
        self._outputs = outputs
        self._on_pressure = on_pressure
        self.statuses: list[dict[str, tuple[int, str, dict[str, str]]]] = []   # status name -> (level, message, values)
        self.diagnostics: list[dict[str, str]] = []
        self.diagnostic_levels: list[int] = []
        self.diagnostic_messages: list[str] = []
        self.diagnostic_statuses: list[dict[str, tuple[int, str]]] = []   # concern -> (level, message)
        self.currents: dict[str, list[tuple[int, float]]] = {v: [] for v in self.valves}   # (latest stamp seen, A)
        self.periods: list[Period] = []
        self.answered = 0                    # periods answered (once each), history or not
        self._partial: dict[int, PartialPeriod] = {}
        self._samples: list[tuple[int, dict[str, float]]] = []      # channel: samples taken, not answered
        self._fresh: dict[str, float] = {}   # <valve>.current received since the last answer
        self._answers: dict[int, dict[str, float]] = {}
        self._flags_sent: dict[str, float] = {}
        self._last_answered = -1
        self._latest = -1

        qos = sample_qos(sample_depth)
        self._subs: list[tuple[Any, Callable[..., None]]] = []
        last: tuple[Any, Callable[..., None]] | None = None
        with_info: Any                       # callbacks of (message, MessageInfo): rclpy passes the info
        if channel:
            with_info = self._sample
            last = (node.create_subscription(JointState, SAMPLE_TOPIC, with_info, topic_qos(SAMPLE_TOPIC), raw=True), with_info)
        if not channel and (self.lockstep or topics.PRESSURE in outputs):
            for v in self.valves:
                with_info = self._pressure(v)
                last = (node.create_subscription(FluidPressure, self.topic(v, topics.PRESSURE), with_info, qos),
                        with_info)
                self._subs.append(last)
        if (currents and not channel) or topics.CURRENT in outputs:
            for v in self.valves:
                with_info = self._current(v)
                self._subs.append((node.create_subscription(Float64, self.topic(v, topics.CURRENT), with_info,
                                                            qos), with_info))
        if topics.SPOOL_POSITION in outputs:
            with_info = self._scalar(topics.SPOOL_POSITION)
            self._subs.append((node.create_subscription(Float64, topics.SPOOL_POSITION, with_info, qos), with_info))
        if self.cylinder and self.lockstep and not channel:
            with_info = self._joint
            last = (node.create_subscription(JointState, topics.cylinder_topic(topics.JOINT_STATES), with_info,
                                             qos), with_info)
        if last is not None and last not in self._subs:
            self._subs.append(last)
        #: a lockstep's last topic of a period (the rig publishes joint_states last): it completes one
        self._completing = [last] if last is not None and self.lockstep else []
        self._waiter = Waiter([last[0]], node.context) if self._completing and last is not None else None
        if history:
            with_info = self._diagnostic
            self._subs.append((node.create_subscription(DiagnosticArray, topics.DIAGNOSTICS, with_info,
                                                        QoSProfile(depth=50)), with_info))
        self.executor: SingleThreadedExecutor | None = None
        if self._own_node:
            self.executor = SingleThreadedExecutor(context=self.context)
            self.executor.add_node(node)
            self._service(Trigger, topics.RESET)
            self._service(SetParameters, f"{self.device_name}/set_parameters")

    # --- names -------------------------------------------------------------------------------

    def key(self, valve: str, role: str) -> str:
        """A valve's input or signal as the device names it: `left.pressure`, the emulator's `pressure`."""
        return role if self.lone_valve else f"{valve}.{role}"

    def topic(self, valve: str, role: str) -> str:
        """A valve's signal's relative topic (`pcv_sim.io.topics.output_topics`)."""
        return topics.output_topics((self.key(valve, role),))[0].topic

    # --- inputs ------------------------------------------------------------------------------

    def _publisher(self, name: str) -> tuple[Any, Any, Any]:
        entry = self._pubs.get(name)
        if entry is None:
            [it] = topics.input_topics((name,), self.valves)
            if it.type == FLUID_PRESSURE:
                msg: Any = FluidPressure()
                setter: Any = lambda m, v: setattr(m, "fluid_pressure", v)   # noqa: E731
            else:
                msg = Float64()
                setter = lambda m, v: setattr(m, "data", v)                   # noqa: E731
            entry = self._pubs[name] = (self.node.create_publisher(type(msg), it.topic, topic_qos(it.topic)), msg, setter)
        return entry

    def send(self, name: str, value: float) -> None:
        """One of the device's inputs by its name (`duty_cycle`, `left.duty_cycle`,
        `cylinder.external_force`, `oil_temperature`...), SI, on its topic."""
        pub, msg, setter = self._publisher(name)
        setter(msg, float(value))
        pub.publish(msg)

    def send_duty(self, duty: float, valve: str | None = None) -> None:
        self.send(self.key(valve or self.valves[0], topics.DUTY_CYCLE), duty)
        self.duty_sent.append((duty, time.time_ns()))

    def send_load_flow(self, q: float) -> None:
        self.send(topics.LOAD_FLOW, q)

    def send_supply_pressure(self, p: float, valve: str | None = None) -> None:
        self.send(self.key(valve or self.valves[0], topics.SUPPLY_PRESSURE), p)

    def send_external_force(self, newton: float) -> None:
        self.send(f"{topics.CYLINDER}.{topics.EXTERNAL_FORCE}", newton)

    def send_fault(self, text: str) -> None:
        """A fault command (one line of YAML, `pcv_sim.device.faults.parse_fault_command`)."""
        self.fault_pub.publish(String(data=text))

    @property
    def pub_duty(self) -> Any:
        """The first valve's duty publisher."""
        return self._publisher(self.key(self.valves[0], topics.DUTY_CYCLE))[0]

    def add_input(self, subscription: Any, handler: Callable[..., None]) -> None:
        """Take `subscription`'s messages with `handler(msg, info)` in every poll, after the device's."""
        self._subs.append((subscription, handler))

    # --- waiting -----------------------------------------------------------------------------

    def spin_once(self, timeout: float) -> None:
        """Take what comes within `timeout` s: the client's node spun (its handlers and any the user
        made on it), or on a node given, `poll`."""
        if self.executor is not None:
            self.executor.spin_once(timeout_sec=timeout)
        elif not self.poll():
            time.sleep(timeout)

    def spin_for(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.spin_once(min(0.01, max(0.0, end - time.monotonic())))

    def spin_until(self, predicate: Callable[[], bool], timeout: float) -> bool:
        end = time.monotonic() + timeout
        while not predicate():
            if time.monotonic() > end:
                return False
            self.spin_once(0.01)
        return True

    def wait_for_device(self, timeout: float = 30.0) -> bool:
        """Until every duty publisher (the lockstep command's, with `channel`) is matched with the node."""
        end = time.monotonic() + timeout
        pubs = [self.command_pub] if self.command_pub is not None else list(self.duty_pubs.values())
        while not all(p.get_subscription_count() > 0 for p in pubs):
            if time.monotonic() > end:
                return False
            time.sleep(0.01)
        return True

    wait_for_rig = wait_for_device

    def wait_for_emulator(self, timeout: float = 20.0) -> bool:
        """Until the node's endpoints are matched and a sample has arrived."""
        n = len(self.samples)
        return self.spin_until(lambda: (self.pub_duty.get_subscription_count() > 0 and len(self.samples) > n),
                               timeout)

    def wait_for_diagnostics(self, predicate: Callable[[dict[str, str]], bool] = lambda d: True,
                             timeout: float = 10.0) -> dict[str, str] | None:
        """The first diagnostics message (merged values) from now on that satisfies predicate (None on timeout)."""
        start = len(self.diagnostics)
        found: list[dict[str, str]] = []

        def check() -> bool:
            found[:] = [d for d in self.diagnostics[start:] if predicate(d)]
            return bool(found)

        return found[0] if self.spin_until(check, timeout) else None

    def close(self) -> None:
        # Detach the node before the executor goes and before its handles are destroyed: a wait
        # set still holding them is what rclpy's teardown segfaults have in common.
        if self.executor is not None:
            self.executor.remove_node(self.node)
            self.executor.shutdown(timeout_sec=1.0)
        if self._srv is not None:
            self._srv[1].shutdown()
            self._srv[0].destroy_node()
            self._srv = None
        self._clients.clear()
        if self._own_node:
            self.node.destroy_node()


class EmulatorClient(DeviceClient):
    """The emulator's client: `DeviceClient` of the one bare valve, its pressure collected."""

    def __init__(self, namespace: str = "/", *, context: Any = None, node_name: str = "pcv_client",
                 emulator_node: str = "emulator", sample_depth: int = 10000,
                 outputs: tuple[str, ...] = (topics.PRESSURE,),
                 on_pressure: Callable[[PressureSample], None] | None = None, **kw: Any) -> None:
        super().__init__(namespace, context=context, node_name=node_name, device_node=emulator_node,
                         sample_depth=sample_depth, outputs=outputs, on_pressure=on_pressure, lone_valve=True, **kw)


class RigClient(DeviceClient):
    """The rig's lockstep controller: `DeviceClient` of its named valves, subscribed for `run`."""

    def __init__(self, namespace: str | None, valves: tuple[str, ...], *, context: Any = None,
                 node_name: str = "rig_controller", currents: bool = False, node: Any = None,
                 history: bool = True, channel: bool = False, **kw: Any) -> None:
        super().__init__(namespace, valves, context=context, node_name=node_name, node=node, device_node="rig",
                         lockstep=True, currents=currents, history=history, channel=channel, lone_valve=False,
                         sample_depth=kw.pop("sample_depth", 1000), **kw)
