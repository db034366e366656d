"""ROS clients of the device nodes: what every client does (`DeviceClient`: its node, the
device's fault topic and reset service, the diagnostics' levels and the samples' stamps), and the
client of one emulator (`EmulatorClient`: send inputs, collect samples and diagnostics, set its
parameters). The rig's client is `pcv_sim.node.rig_client.RigClient`.

Used by the demo, the tests and the benchmarks; also a starting point for a controller.

Samples arrive with sensor-data QoS from the emulator. `qos_profile_sensor_data` keeps only 5
messages: a Python subscriber busy for a few ms loses 1 kHz samples. This client subscribes
best-effort with a deep queue (`sample_depth`), which is what a subscriber that must see every
sample should do.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import SetParametersResult
from rcl_interfaces.srv import SetParameters
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import FluidPressure
from std_msgs.msg import Float64, String
from std_srvs.srv import Trigger

from pcv_sim.io import topics

__all__ = ["DeviceClient", "EmulatorClient", "PressureSample", "diagnostic_level", "sample_qos", "stamp_ns"]

SERVICE_AGAIN = 5.0     # s without an answer before a repeatable request (set_parameters) is sent again


def sample_qos(depth: int = 10000) -> QoSProfile:
    """Best effort (matches the emulator's sensor-data publisher) with a deep queue."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth, reliability=ReliabilityPolicy.BEST_EFFORT)


def stamp_ns(msg: Any) -> int:
    """A stamped message's header.stamp in ns (the sample's model time)."""
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


def diagnostic_level(status: Any) -> int:
    """A DiagnosticStatus's level as a number (rclpy gives it as bytes of one)."""
    level = status.level
    return level[0] if isinstance(level, (bytes, bytearray)) else int(level)


def call_service(executor: Any, client: Any, request: Any, timeout: float, *, again: float | None = None) -> Any:
    """The service's answer, spinning `executor` (the client's node's) while it waits; TimeoutError
    without one within `timeout` s. `again`: for a request that may be repeated (the same effect
    twice), sent again after that many seconds without an answer. Under load an answer can be lost
    though the request came through: the server's response writer may not have matched this
    client's reader yet when it answers (the middleware waits a short while for the match, then
    drops the answer), and asking again is answered."""
    end = time.monotonic() + timeout
    if not client.wait_for_service(timeout_sec=timeout):
        raise TimeoutError(f"service {client.srv_name} not available")
    while True:
        future = client.call_async(request)
        wait_end = min(end, time.monotonic() + again) if again is not None else end
        while not future.done() and time.monotonic() < wait_end:
            executor.spin_once(timeout_sec=min(0.01, max(0.0, wait_end - time.monotonic())))
        if future.done():
            return future.result()
        client.remove_pending_request(future)
        if again is None or time.monotonic() >= end:
            raise TimeoutError(f"no answer from {client.srv_name} within {timeout} s")


class DeviceClient:
    """What a client of any device node does, from its own node or from `node` (then `namespace`
    and `context` are the node's): send fault commands (the node takes them with its `faults`
    topic enabled), call the device's `reset` service, close."""

    def __init__(self, namespace: str | None, *, context: Any = None, node_name: str, node: Any = None) -> None:
        self._own_node = node is None
        self.node = rclpy.create_node(node_name, namespace=namespace, context=context) if node is None else node
        self.context = self.node.context
        self.fault_pub = self.node.create_publisher(String, topics.FAULTS, QoSProfile(depth=10))
        self._clients: dict[str, Any] = {}

    def send_fault(self, text: str) -> None:
        """A fault command (one line of YAML, `pcv_sim.device.faults.parse_fault_command`)."""
        self.fault_pub.publish(String(data=text))

    def _service_node(self) -> tuple[Any, Any]:
        """The node service clients live on and the executor that spins it while a call waits."""
        raise NotImplementedError

    def _service(self, srv_type: Any, name: str) -> Any:
        client = self._clients.get(name)
        if client is None:
            client = self._clients[name] = self._service_node()[0].create_client(srv_type, name)
        return client

    def call(self, srv_type: Any, name: str, request: Any, timeout: float, *, again: float | None = None) -> Any:
        """Call the service `name` (of type `srv_type`; see `call_service`)."""
        return call_service(self._service_node()[1], self._service(srv_type, name), request, timeout, again=again)

    def reset(self, timeout: float = 10.0) -> Any:
        """Call the device's `reset` service; its response (TimeoutError if none within `timeout` s)."""
        return self.call(Trigger, topics.RESET, Trigger.Request(), timeout)

    def close(self) -> None:
        if self._own_node:
            self.node.destroy_node()


@dataclass(frozen=True)
class PressureSample:
    stamp_ns: int          # header.stamp: the sample's model time (anchored to the ROS clock in real time)
    pressure: float        # Pa
    source_ns: int         # DDS source timestamp (when the emulator published it)
    received_ns: int       # DDS reception timestamp at this client


class EmulatorClient(DeviceClient):
    """Talks to the emulator in `namespace` (node name `emulator_node`) from its own node."""

    def __init__(
        self, namespace: str = "/", *, context: Any = None, node_name: str = "pcv_client",
        emulator_node: str = "emulator", sample_depth: int = 10000, outputs: tuple[str, ...] = (topics.PRESSURE,),
        on_pressure: Callable[[PressureSample], None] | None = None,
    ) -> None:
        super().__init__(namespace, context=context, node_name=node_name)
        ns = self.node.get_namespace().rstrip("/")
        self.emulator_name = f"{ns}/{emulator_node}"
        self.samples: list[PressureSample] = []
        self.outputs: dict[str, list[tuple[int, float]]] = {topics.CURRENT: [], topics.SPOOL_POSITION: []}
        self.diagnostics: list[dict[str, str]] = []
        self.diagnostic_levels: list[int] = []
        self.diagnostic_messages: list[str] = []
        self.diagnostic_statuses: list[dict[str, tuple[int, str]]] = []   # concern -> (level, message)
        self.duty_sent: list[tuple[float, int]] = []
        self._on_pressure = on_pressure
        qos = sample_qos(sample_depth)
        cmd = QoSProfile(depth=10)
        self.pub_duty = self.node.create_publisher(Float64, topics.DUTY_CYCLE, cmd)
        self.pub_load_flow = self.node.create_publisher(Float64, topics.LOAD_FLOW, cmd)
        self.pub_supply = self.node.create_publisher(FluidPressure, topics.SUPPLY_PRESSURE, cmd)
        # Callbacks of (message, MessageInfo): rclpy passes the info to a two-argument callback
        # (jazzy's annotation names only the one-argument form).
        with_info: Any
        if topics.PRESSURE in outputs:
            with_info = self._pressure
            self.node.create_subscription(FluidPressure, topics.PRESSURE, with_info, qos)
        for name in (topics.CURRENT, topics.SPOOL_POSITION):
            if name in outputs:
                with_info = self._scalar(name)
                self.node.create_subscription(Float64, name, with_info, qos)
        self.node.create_subscription(DiagnosticArray, topics.DIAGNOSTICS, self._diagnostics, QoSProfile(depth=50))
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)
        self._service(Trigger, topics.RESET)
        self._service(SetParameters, f"{self.emulator_name}/set_parameters")

    # --- callbacks ---------------------------------------------------------------------------

    def _pressure(self, msg: FluidPressure, info: Any) -> None:
        s = PressureSample(stamp_ns(msg), msg.fluid_pressure, info["source_timestamp"], info["received_timestamp"])
        self.samples.append(s)
        if self._on_pressure is not None:
            self._on_pressure(s)

    def _scalar(self, name: str) -> Callable[[Float64, Any], None]:
        def callback(msg: Float64, info: Any) -> None:
            self.outputs[name].append((info["source_timestamp"], msg.data))
        return callback

    def _diagnostics(self, msg: DiagnosticArray) -> None:
        """One entry per message of this emulator: the statuses' values merged (the keys are unique
        across concerns), the highest level, the messages joined; per concern in `diagnostic_statuses`."""
        ours = [st for st in msg.status if st.name.startswith(self.emulator_name + ":")]
        if not ours:
            return
        merged: dict[str, str] = {}
        statuses: dict[str, tuple[int, str]] = {}
        for st in ours:
            merged.update({kv.key: kv.value for kv in st.values})
            level = diagnostic_level(st)
            statuses[st.name[len(self.emulator_name) + 1:].strip()] = (level, st.message)
        self.diagnostics.append(merged)
        self.diagnostic_statuses.append(statuses)
        self.diagnostic_levels.append(max(level for level, _ in statuses.values()))
        self.diagnostic_messages.append("; ".join(m for _, m in statuses.values()))

    # --- spinning ----------------------------------------------------------------------------

    def spin_for(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=min(0.01, max(0.0, end - time.monotonic())))

    def spin_until(self, predicate: Callable[[], bool], timeout: float) -> bool:
        end = time.monotonic() + timeout
        while not predicate():
            if time.monotonic() > end:
                return False
            self.executor.spin_once(timeout_sec=0.01)
        return True

    def wait_for_emulator(self, timeout: float = 20.0) -> bool:
        """Until the emulator's endpoints are matched and a sample has arrived."""
        n = len(self.samples)
        return self.spin_until(lambda: (self.pub_duty.get_subscription_count() > 0 and len(self.samples) > n),
                               timeout)

    def wait_for_diagnostics(self, predicate: Callable[[dict[str, str]], bool] = lambda d: True,
                             timeout: float = 10.0) -> dict[str, str] | None:
        """The first diagnostics message from now on that satisfies predicate (None on timeout)."""
        start = len(self.diagnostics)
        found: list[dict[str, str]] = []

        def check() -> bool:
            found[:] = [d for d in self.diagnostics[start:] if predicate(d)]
            return bool(found)

        return found[0] if self.spin_until(check, timeout) else None

    # --- inputs ------------------------------------------------------------------------------

    def send_duty(self, duty: float) -> None:
        self.pub_duty.publish(Float64(data=float(duty)))
        self.duty_sent.append((duty, time.time_ns()))

    def send_load_flow(self, q: float) -> None:
        self.pub_load_flow.publish(Float64(data=float(q)))

    def send_supply_pressure(self, p: float) -> None:
        msg = FluidPressure()
        msg.fluid_pressure = float(p)
        self.pub_supply.publish(msg)

    # --- services ----------------------------------------------------------------------------

    def _service_node(self) -> tuple[Any, Any]:
        return self.node, self.executor

    def set_parameters(self, values: dict[str, Any], timeout: float = 10.0) -> list[SetParametersResult]:
        """Set the emulator's parameters one by one (as `ros2 param set`); one result per name."""
        request = SetParameters.Request()
        request.parameters = [Parameter(k, value=v).to_parameter_msg() for k, v in values.items()]
        return list(self.call(SetParameters, f"{self.emulator_name}/set_parameters", request, timeout,
                              again=SERVICE_AGAIN).results)

    def close(self) -> None:
        # Detach the node before the executor goes and before its handles are destroyed: a wait
        # set still holding them is what rclpy's teardown segfaults have in common.
        self.executor.remove_node(self.node)
        self.executor.shutdown(timeout_sec=1.0)
        super().close()


