"""A node's bag recorder: opened as record.* asks (one `WriterSettings` for every device's recorder),
started with the first sample, closed at the end saying what it wrote."""

from __future__ import annotations

import os
import sys
from collections.abc import Callable
from typing import Any

from rclpy.node import Node

from pcv_sim.errors import BagError, ParameterError
from pcv_sim.io.recorder import SWITCH_INTERVAL, WriterSettings

__all__ = ["NodeRecording"]


class NodeRecording(Node):
    """The recording part of the package's node (`pcv_sim.node.base.NodeBase`)."""

    settings: Any
    simulated: bool

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
