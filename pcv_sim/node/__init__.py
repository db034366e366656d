"""The ROS 2 side of pcv_sim: the `emulator` and `rig` processes (`emulator`, `rig`), their one node
class over a device (`device_node`, what differs between them in `kinds`), the client of any
device (`client`) and the `demo`. All of them import rclpy; what they adapt lives in `pcv_sim.device`
and `pcv_sim.rig` (the devices, their settings, parameter plumbing and diagnostics), which do not.
"""

__all__ = ["client", "demo", "device_node", "emulator", "kinds", "rig"]
