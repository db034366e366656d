"""The rig without ROS: valves on the chambers of a steering cylinder at one fixed step, faults,
and a lockstep runner for a controller (`pcv_sim.rig.lockstep`)."""

from pcv_sim.device.faults import SENSOR_FAULTS, VALVE_FAULTS, Fault, FaultError, parse_fault
from pcv_sim.rig.lockstep import ControllerError, RigRun, run_lockstep
from pcv_sim.rig.params import DEFAULT_RIG, RigParams, load_rig, rig_from_mapping
from pcv_sim.rig.rig import Rig, RigError

__all__ = [
    "DEFAULT_RIG",
    "SENSOR_FAULTS",
    "VALVE_FAULTS",
    "ControllerError",
    "Fault",
    "FaultError",
    "Rig",
    "RigError",
    "RigParams",
    "RigRun",
    "load_rig",
    "parse_fault",
    "rig_from_mapping",
    "run_lockstep",
]
