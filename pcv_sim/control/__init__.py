"""Controllers shipped with the package, without ROS: the example steering position controller
(`pcv_sim.control.steering.PositionController`), called in-process by a scenario
(`controller: steering:PositionController`, examples/steering.py) and by the ROS node
`steering_controller` (`pcv_sim.node.steering_controller`): one control law for both. Its gains
and settings are declared once in `pcv_sim.control.params` (`PositionControllerParams`)."""

from pcv_sim.control.params import PositionControllerParams
from pcv_sim.control.steering import PositionController

__all__ = ["PositionController", "PositionControllerParams"]
