"""Service requests of a node that runs without an executor: taken and answered in its loop
(`_poll_services`), those of `_deferred_callbacks` (parameter sets, a reset) computed on a worker
thread one at a time in arrival order, what they prepared applied by the loop at a step boundary
and only then answered (`_pump`, `hold_answer`). The QoS events are polled with them."""

from __future__ import annotations

import sys
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor, wait
from typing import Any

from rclpy.exceptions import InvalidHandle
from rclpy.node import Node

__all__ = ["EVENT_POLL_EVERY", "JOB_SWITCH_INTERVAL", "SERVICE_POLL_PERIOD", "WORKER_STOP_BOUND", "ServicePolling"]

EVENT_POLL_EVERY = 10                       # service polls between QoS event polls
SERVICE_POLL_PERIOD = 0.01                  # s (wall) between polls for service requests (reset, parameters)
JOB_SWITCH_INTERVAL = 2e-4                  # s, interpreter switch interval while the worker computes
#: s the stop waits for the deferred request in progress (a rest state: 25-60 ms, ~1 s under load).
WORKER_STOP_BOUND = 3.0


class ServicePolling(Node):
    """The service part of the package's node (`pcv_sim.node.base.NodeBase`)."""

    _poll_events: Callable[[], None]                            # pcv_sim.node.qos_events
    _staged: Any                                                # pcv_sim.node.parameters: a checked change
    _pending: Any

    def _init_services(self) -> None:
        # Parameter sets (and what else a node lists in `_deferred_callbacks`) go to a worker thread:
        # it validates them and prepares what they need (an emulator's rest state: 25-60 ms of model
        # solves), the loop swaps the result in at its next wake and only then answers. One request
        # at a time, in arrival order (`_pump`).
        self._worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="pcv_sim_prepare")
        self._deferred: deque[tuple[Any, Any, Any]] = deque()       # (service, request, header)
        self._job: tuple[Any, Any, Future[Any]] | None = None       # (service, header, answer)
        self._ready: list[Callable[[], None]] = []                  # worker-built, applied by the loop
        self._hold: list[bool] | None = None                        # `hold_answer` of the job being applied
        self._held: tuple[Any, Any, Any, list[bool]] | None = None  # (service, header, answer, acted) held back
        self._switch_interval = sys.getswitchinterval()
        self._deferred_callbacks: tuple[Any, ...] = ()
        self._polls = 0

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

    def _stop_worker(self) -> None:
        """After the loop: the worker stopped (a job still queued is dropped). The request in progress
        is waited for WORKER_STOP_BOUND s at most, then left behind unanswered (said): the process
        ends without joining its thread (`pcv_sim.node.process`)."""
        self._worker.shutdown(wait=False, cancel_futures=True)
        job = self._job
        if job is not None and wait([job[2]], timeout=WORKER_STOP_BOUND).not_done:
            self.get_logger().warning(f"stopping: the request to {job[0].srv_name} in progress is left "
                                      f"unanswered after {WORKER_STOP_BOUND:g} s")
