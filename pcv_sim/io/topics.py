"""The device's topics and service (docs/interface.md): names, message types and units, in one place.

The node uses the relative names (so ``--ros-args -r __ns:=/left`` moves a whole valve); a bag
recorded by the emulator in the root namespace holds them as ``/<name>`` (:data:`BAG_TOPICS`).
Replay and CSV import refer to signals by *role*: the relative topic name, or one of the short
aliases in :data:`ROLE_ALIASES` (``duty``, ``position``).

Units on the wire are SI (REP 103): duty as a fraction 0..1, flow m^3/s, pressure Pa, current A,
position m (the paper's sign convention: + opens pump -> load).
"""

from __future__ import annotations

from typing import Final

from pcv_sim.io.bag import FLOAT64, FLUID_PRESSURE

__all__ = [
    "BAG_TOPICS",
    "CHAMBER_PRESSURE",
    "CLOCK",
    "CURRENT",
    "CYLINDER",
    "DIAGNOSTICS",
    "DUTY_CYCLE",
    "FAULTS",
    "INPUT_ROLES",
    "JOINT_STATES",
    "LOAD_FLOW",
    "OUTPUT_ROLES",
    "PRESSURE",
    "RESET",
    "ROLES",
    "ROLE_ALIASES",
    "ROLE_TYPES",
    "ROLE_UNITS",
    "SPOOL_POSITION",
    "SUPPLY_PRESSURE",
    "bag_topic",
    "chamber_topic",
    "role_of",
    "valve_topic",
]

# Relative topic names: the node's endpoints.
DUTY_CYCLE: Final = "duty_cycle"            # in, std_msgs/Float64, fraction 0..1
LOAD_FLOW: Final = "load_flow"              # in, std_msgs/Float64, m^3/s (+ drawn from the load port)
SUPPLY_PRESSURE: Final = "supply_pressure"  # in, sensor_msgs/FluidPressure, Pa
PRESSURE: Final = "pressure"                # out, sensor_msgs/FluidPressure, Pa, stamp = sample time
CURRENT: Final = "current"                  # out, std_msgs/Float64, A
SPOOL_POSITION: Final = "spool_position"    # out, std_msgs/Float64, m
DIAGNOSTICS: Final = "/diagnostics"         # out, diagnostic_msgs/DiagnosticArray (absolute by ROS habit)
CLOCK: Final = "/clock"                     # out (simulated time) or in (use_sim_time), rosgraph_msgs/Clock
RESET: Final = "reset"                      # service, std_srvs/Trigger

# The rig node (`pcv_sim.node.rig`): each valve's topics above under `<valve>/`, and
CYLINDER: Final = "cylinder"                # namespace of the cylinder's topics
JOINT_STATES: Final = "joint_states"        # out, sensor_msgs/JointState: prismatic joint, m, m/s, N
CHAMBER_PRESSURE: Final = "pressure_{}"     # out, sensor_msgs/FluidPressure, Pa, chamber a | b (= its valve's)
FAULTS: Final = "faults"                    # in, std_msgs/String: {fault: coil_open, valve: left} (YAML)

INPUT_ROLES: Final = (DUTY_CYCLE, LOAD_FLOW, SUPPLY_PRESSURE)
OUTPUT_ROLES: Final = (PRESSURE, CURRENT, SPOOL_POSITION)
ROLES: Final = INPUT_ROLES + OUTPUT_ROLES

ROLE_TYPES: Final = {
    DUTY_CYCLE: FLOAT64,
    LOAD_FLOW: FLOAT64,
    SUPPLY_PRESSURE: FLUID_PRESSURE,
    PRESSURE: FLUID_PRESSURE,
    CURRENT: FLOAT64,
    SPOOL_POSITION: FLOAT64,
}
ROLE_UNITS: Final = {
    DUTY_CYCLE: "1",
    LOAD_FLOW: "m^3/s",
    SUPPLY_PRESSURE: "Pa",
    PRESSURE: "Pa",
    CURRENT: "A",
    SPOOL_POSITION: "m",
}
#: Short names accepted wherever a role is named (``--topic``, ``--columns``).
ROLE_ALIASES: Final = {
    "duty": DUTY_CYCLE,
    "position": SPOOL_POSITION,
    "spool": SPOOL_POSITION,
    "flow": LOAD_FLOW,
    "supply": SUPPLY_PRESSURE,
}


def bag_topic(role: str, namespace: str = "/") -> str:
    """The absolute topic a role has in a bag recorded with the node in ``namespace``."""
    if role.startswith("/"):
        return role  # already absolute (e.g. /diagnostics)
    ns = namespace.strip("/")
    return f"/{ns}/{role}" if ns else f"/{role}"


#: Topic -> type as the emulator in the root namespace records them.
BAG_TOPICS: Final = {bag_topic(role): msgtype for role, msgtype in ROLE_TYPES.items()}


def valve_topic(valve: str, role: str) -> str:
    """The rig node's relative topic of one valve's role (``left/pressure``)."""
    return f"{valve}/{role}"


def chamber_topic(chamber: str) -> str:
    """The rig node's relative topic of a chamber's pressure (``cylinder/pressure_a``)."""
    return f"{CYLINDER}/{CHAMBER_PRESSURE.format(chamber)}"


def role_of(name: str) -> str | None:
    """The role a user's name refers to (``pressure``, ``duty``, ``spool_position``...), or None."""
    key = name.strip().lower()
    if key in ROLE_TYPES:
        return key
    return ROLE_ALIASES.get(key)
