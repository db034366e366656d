"""The ROS 2 side of pcv_sim: the `emulator` node and the `demo` client.

`emulator` (the process), `adapter` (the node), `client` and `demo` import rclpy; `device`,
`settings`, `parameters` and `diagnostics` do not (they are tested without ROS).
"""

__all__ = ["device", "diagnostics", "parameters", "settings"]
