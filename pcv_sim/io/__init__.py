"""Bag input/output (rosbag2 directories with MCAP files) without rclpy."""

from pcv_sim.io.bag import (
    DECODABLE_TYPES,
    FLOAT64,
    FLUID_PRESSURE,
    BagContents,
    BagWriter,
    Qos,
    TopicSeries,
    detect_ros_distro,
    read_bag,
)

__all__ = [
    "DECODABLE_TYPES",
    "FLOAT64",
    "FLUID_PRESSURE",
    "BagContents",
    "BagWriter",
    "Qos",
    "TopicSeries",
    "detect_ros_distro",
    "read_bag",
]
