"""The device client's services (`pcv_sim.node.client.DeviceClient`): the device's `reset` and
`set_parameters`, called with `call_service`, which asks again where a request may be repeated.
"""

from __future__ import annotations

import time
from typing import Any

import rclpy
from rcl_interfaces.msg import SetParametersResult
from rcl_interfaces.srv import SetParameters
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from std_srvs.srv import Trigger

from pcv_sim.io import topics

__all__ = ["SERVICE_AGAIN", "ServiceCalls", "call_service"]

SERVICE_AGAIN = 5.0     # s without an answer before a repeatable request (set_parameters) is sent again


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


class ServiceCalls:
    """The services of the device node `device_name`, called from the client's node (or, for a node
    given, from a node of its own: see `_service_node`)."""

    node: Any
    executor: SingleThreadedExecutor | None
    device_name: str
    _srv: tuple[Any, SingleThreadedExecutor] | None
    _clients: dict[str, Any]

    def _service_node(self) -> tuple[Any, Any]:
        """The node service clients live on and the executor that spins it while a call waits: the
        client's own; for a node given, a node of its own made at the first call (spinning the node
        given would take what its owner polls)."""
        if self.executor is not None:
            return self.node, self.executor
        if self._srv is None:
            node = rclpy.create_node(f"{self.node.get_name()}_services", namespace=self.node.get_namespace(),
                                     context=self.node.context)
            executor = SingleThreadedExecutor(context=node.context)
            executor.add_node(node)
            self._srv = (node, executor)
        return self._srv

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

    def set_parameters(self, values: dict[str, Any], timeout: float = 10.0) -> list[SetParametersResult]:
        """Set the node's parameters one by one (as `ros2 param set`); one result per name."""
        request = SetParameters.Request()
        request.parameters = [Parameter(k, value=v).to_parameter_msg() for k, v in values.items()]
        return list(self.call(SetParameters, f"{self.device_name}/set_parameters", request, timeout,
                              again=SERVICE_AGAIN).results)
