"""pcv_sim: a solenoid proportional pressure control valve (Hydac PDR08-11 class) as a model and a ROS 2 device.

The model follows Ljungberg, Sjöberg, Krus (Int. J. Fluid Power), see docs/model.md for every
reading of the printed equations. Model, simulation and analysis code never import rclpy.
"""

__version__ = "0.1.0"
