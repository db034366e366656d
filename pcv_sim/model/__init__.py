"""The valve model: the paper's equations as pure functions of floats (SI units, x in mm for
fits only). Knows nothing about ROS or integrators."""
