"""Rosbag2 bags (directory with ``metadata.yaml`` and MCAP files) without rclpy, by role:

- :mod:`.writer`: :class:`BagWriter` (bounded-loss flushing, file splitting, bulk samples);
- :mod:`.reader`: :func:`read_bag` (also unclosed and cut-off files) into :class:`TopicSeries`;
- :mod:`.metadata`: ``metadata.yaml``, offered QoS profiles (:class:`Qos`), the ROS distribution;
- :mod:`.cdr`: CDR (de)serialisation, per message and in bulk with numpy;
- :mod:`.mcap_chunks`: the one dependency on private parts of the ``mcap`` package, with its
  version check and the message-by-message fallback.
"""

from pcv_sim.io.bag.cdr import DECODABLE_TYPES, FLOAT64, FLUID_PRESSURE
from pcv_sim.io.bag.metadata import COMMAND_QOS, SENSOR_DATA_QOS, Qos, detect_ros_distro
from pcv_sim.io.bag.reader import BagContents, TopicSeries, read_bag
from pcv_sim.io.bag.writer import BagWriter

__all__ = [
    "COMMAND_QOS",
    "DECODABLE_TYPES",
    "FLOAT64",
    "FLUID_PRESSURE",
    "SENSOR_DATA_QOS",
    "BagContents",
    "BagWriter",
    "Qos",
    "TopicSeries",
    "detect_ros_distro",
    "read_bag",
]
