"""`NodeBase`: what a node of the package does whatever its device, written once (the one node class
over a device, `pcv_sim.node.device_node.DeviceNode`, is made of it), one idea per module:

- `pcv_sim.node.parameters`: declared from the node's schema, checked at start and at run time;
- `pcv_sim.node.inputs`: the device's input topics and the fault topic, taken by polling, acting at
  the step `acting_step` gives, refusals logged, the device's log forwarded;
- `pcv_sim.node.services`: service requests answered in the loop, deferred ones on a worker thread;
- `pcv_sim.node.qos_events`: QoS incompatibility events, logged with the way out;
- `pcv_sim.node.loops`: the loops of the three time modes and /clock;
- `pcv_sim.node.recording`: the bag recorder's opening and closing;
- `pcv_sim.node.tuning`: timer slack, the frozen heap, SCHED_FIFO.

Here: construction (a ParameterError while setting up is logged to stderr and /rosout, the
half-built node destroyed, the error raised for the process to exit 2, `pcv_sim.node.process`),
/diagnostics, and the end of a run.
"""

from __future__ import annotations

import sys
import time
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

from pcv_sim.device.diagnostics import Status
from pcv_sim.device.parameters import check_params_files, command_line_overrides
from pcv_sim.errors import ParameterError
from pcv_sim.io.recorder import RecorderStatus
from pcv_sim.node.inputs import NodeInputs
from pcv_sim.node.loops import StopFlag, TimeModeLoops
from pcv_sim.node.parameters import NodeParameters
from pcv_sim.node.polling import linger_for_rosout
from pcv_sim.node.qos_events import QosEvents
from pcv_sim.node.recording import NodeRecording
from pcv_sim.node.services import ServicePolling
from pcv_sim.units import NS_PER_S

__all__ = ["NodeBase", "StopFlag"]


class NodeBase(NodeParameters, NodeInputs, ServicePolling, QosEvents, TimeModeLoops, NodeRecording):
    """The device-independent part of the package's node (see the module docstring). A subclass sets
    up in `_setup(argv)` and runs in `run(stop)`."""

    recorder: Any                   # the bag recorder (record.enabled), or None
    _pub_diag: Any

    def __init__(self, node_name: str, *, argv: list[str] | None = None, **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self._argv = list(sys.argv if argv is None else argv)
        self._init_services()
        self._init_parameters()
        self._init_qos_events()
        self._init_inputs()
        self._init_loops()
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

    def _publish_diagnostics(self, now: float) -> None:
        """/diagnostics: the device's statuses (`_statuses`), stamped with the model time in simulated
        time and with an external clock (the node's ROS clock is not updated without an executor),
        with wall time in real time."""
        msg = DiagnosticArray()
        model_clock = self.simulated or self.external_clock
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(
            self.device.stamp_ns() if model_clock else time.time_ns(), NS_PER_S)
        for st in self._statuses(now, self.recorder.status() if self.recorder is not None else None):
            d = DiagnosticStatus(level=bytes([st.level]), name=st.name, message=st.message, hardware_id=st.hardware_id)
            d.values = [KeyValue(key=k, value=v) for k, v in st.values.items()]
            msg.status.append(d)
        self._pub_diag.publish(msg)

    def _statuses(self, now: float, recorder: RecorderStatus | None) -> list[Status]:
        """The device's statuses (`recorder`: the recording's status, record.enabled)."""
        raise NotImplementedError


    def _finish(self) -> None:
        """After the loop: the worker stopped, the recorder closed."""
        self._stop_worker()
        self.close_recorder(self.recorder)
