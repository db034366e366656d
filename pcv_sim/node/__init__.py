"""The ROS 2 side of pcv_sim: the `emulator` process (`emulator`), its node (`adapter`), a client
(`client`) and the `demo`. All of them import rclpy; what they adapt lives in `pcv_sim.device`
(the device, its settings, parameter plumbing and diagnostics), which does not.
"""

__all__ = ["adapter", "client", "demo", "emulator"]
