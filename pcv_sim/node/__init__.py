"""The ROS 2 side of pcv_sim: the `emulator` node and the `demo` client.

`emulator` and `demo` import rclpy; `device` and `settings` do not (they are tested without ROS).
"""

__all__ = ["device", "settings"]
