"""The interface registry: every topic and service of the emulator, the rig and a ROS scenario
(docs/interface.md) with its name, message type, unit and QoS, in one place.

The node uses the relative names (so ``--ros-args -r __ns:=/left`` moves a whole valve); a bag
recorded by the emulator in the root namespace holds them as ``/<name>`` (:data:`BAG_TOPICS`).
Replay and CSV import refer to signals by *role*: the relative topic name, or one of the short
aliases in :data:`ROLE_ALIASES` (``duty``, ``position``).

Units on the wire are SI (REP 103): duty as a fraction 0..1, flow m^3/s, pressure Pa, current A,
position m (the paper's sign convention: + opens pump -> load).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final, Literal

from pcv_sim.io.bag import COMMAND_QOS, FLOAT64, FLUID_PRESSURE, SENSOR_DATA_QOS, Qos

__all__ = [
    "AMBIENT_TEMPERATURE",
    "BAG_TOPICS",
    "CHAMBER_PRESSURE",
    "CLOCK",
    "COIL_RESISTANCE",
    "COIL_TEMPERATURE",
    "CONTROLLER_FLAGS",
    "CORE_POSITION",
    "CURRENT",
    "CYLINDER",
    "DIAGNOSTICS",
    "DUTY_CYCLE",
    "EMULATOR_INTERFACE",
    "EVENTS",
    "EXTERNAL_FORCE",
    "FAULTS",
    "FLAGS_QOS",
    "INPUT_ROLES",
    "JOINT_FIELDS",
    "JOINT_NAME",
    "JOINT_STATE",
    "JOINT_STATES",
    "LOAD_FLOW",
    "LOCKSTEP_COMMAND",
    "LOCKSTEP_SAMPLE",
    "OIL_TEMPERATURE",
    "OPTION_INTERFACE",
    "OUTPUT_ROLES",
    "PRESSURE",
    "RELIABLE_10",
    "RESET",
    "RIG_INTERFACE",
    "ROLES",
    "ROLE_ALIASES",
    "ROLE_QOS",
    "ROLE_TYPES",
    "ROLE_UNITS",
    "SCENARIO_INTERFACE",
    "SETPOINT",
    "SPOOL_POSITION",
    "STRING",
    "SUPPLY_PRESSURE",
    "Endpoint",
    "InputTopic",
    "OutputTopic",
    "bag_topic",
    "chamber_topic",
    "cylinder_topic",
    "input_topics",
    "output_topics",
    "qos_of",
    "role_of",
    "topic_of",
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

# The valve's options beyond the paper's bench (docs/model.md R33-R35), present when the valve
# YAML switches them on (:data:`OPTION_INTERFACE`):
AMBIENT_TEMPERATURE: Final = "ambient_temperature"  # in, std_msgs/Float64, K (solenoid.coil_temperature: lumped)
OIL_TEMPERATURE: Final = "oil_temperature"          # in, std_msgs/Float64, K (fluid.temperature: input)
COIL_TEMPERATURE: Final = "coil_temperature"        # out, std_msgs/Float64, K
COIL_RESISTANCE: Final = "coil_resistance"          # out, std_msgs/Float64, ohm
CORE_POSITION: Final = "core_position"              # out, std_msgs/Float64, m (spool.core: separate)

# The rig node (`pcv_sim.node.rig`): each valve's topics above under `<valve>/`, and
CYLINDER: Final = "cylinder"                # namespace of the cylinder's topics
JOINT_STATES: Final = "joint_states"        # out, sensor_msgs/JointState: prismatic joint, m, m/s, N
CHAMBER_PRESSURE: Final = "pressure_{}"     # out, sensor_msgs/FluidPressure, Pa, chamber a | b (= its valve's)
FAULTS: Final = "faults"                    # in, std_msgs/String: {fault: coil_open, valve: left} (YAML)
EVENTS: Final = "rig/events"                # in bags only, std_msgs/String: the rig's log (faults, watchdog, reset)
EXTERNAL_FORCE: Final = "external_force"    # in, std_msgs/Float64, N on the rod, + extending (under cylinder/)
LOCKSTEP_SAMPLE: Final = "lockstep/sample"      # out, sensor_msgs/JointState: a control instant's signals by name
LOCKSTEP_COMMAND: Final = "lockstep/command"    # in, sensor_msgs/JointState: its answer, <valve>.duty and flags

# A scenario whose controller is a ROS node (`pcv_sim.node.scenario_host`), relative to its namespace:
SETPOINT: Final = "setpoint"                # out (rig side), std_msgs/Float64, m
CONTROLLER_FLAGS: Final = "controller/flags"  # in (rig side), diagnostic_msgs/DiagnosticArray

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
#: The QoS the emulator offers per role (docs/interface.md), written into a bag as each topic's
#: ``offered_qos_profiles`` so that ``ros2 bag play`` republishes it the same way.
ROLE_QOS: Final[dict[str, Qos]] = {
    **{r: SENSOR_DATA_QOS for r in OUTPUT_ROLES},
    **{r: COMMAND_QOS for r in INPUT_ROLES},
}
#: The type of the text topics (fault commands, events).
STRING: Final = "std_msgs/msg/String"
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


def cylinder_topic(name: str) -> str:
    """The rig node's relative topic of one of the cylinder's endpoints (``cylinder/external_force``)."""
    return f"{CYLINDER}/{name}"


#: The QoS of the diagnostics, the clock and the controller's flags (reliable, volatile).
RELIABLE_10: Final = COMMAND_QOS
FLAGS_QOS: Final = Qos("reliable", 100)


@dataclass(frozen=True)
class Endpoint:
    """One topic or service of a node: what docs/interface.md lists, and what the node, the clients
    and the recorder use. `unit` is the SI unit of the value ("1": a fraction; "": none)."""

    direction: Literal["in", "out", "out/in", "srv"]
    name: str
    type: str
    unit: str
    qos: Qos | None = None         # None for a service


EMULATOR_INTERFACE: Final = (
    Endpoint("in", DUTY_CYCLE, FLOAT64, ROLE_UNITS[DUTY_CYCLE], COMMAND_QOS),
    Endpoint("in", LOAD_FLOW, FLOAT64, ROLE_UNITS[LOAD_FLOW], COMMAND_QOS),
    Endpoint("in", SUPPLY_PRESSURE, FLUID_PRESSURE, ROLE_UNITS[SUPPLY_PRESSURE], COMMAND_QOS),
    Endpoint("out", PRESSURE, FLUID_PRESSURE, ROLE_UNITS[PRESSURE], SENSOR_DATA_QOS),
    Endpoint("out", CURRENT, FLOAT64, ROLE_UNITS[CURRENT], SENSOR_DATA_QOS),
    Endpoint("out", SPOOL_POSITION, FLOAT64, ROLE_UNITS[SPOOL_POSITION], SENSOR_DATA_QOS),
    Endpoint("out", DIAGNOSTICS, "diagnostic_msgs/msg/DiagnosticArray", "", RELIABLE_10),
    Endpoint("out/in", CLOCK, "rosgraph_msgs/msg/Clock", "s", RELIABLE_10),
    Endpoint("srv", RESET, "std_srvs/srv/Trigger", ""),
    Endpoint("in", FAULTS, "std_msgs/msg/String", "", COMMAND_QOS),      # faults.enabled only
    Endpoint("out", LOCKSTEP_SAMPLE, "sensor_msgs/msg/JointState", "", COMMAND_QOS),   # simulated lockstep only
    Endpoint("in", LOCKSTEP_COMMAND, "sensor_msgs/msg/JointState", "1", COMMAND_QOS),
)
#: The valve options' topics (docs/model.md R33-R35), each present when its option is on. The
#: device gives them as signals (`pcv_sim.device.valve.OPTION_SIGNALS`); the emulator serves them
#: (outputs with each sample), reports them in its diagnostics and records them (record.enabled).
OPTION_INTERFACE: Final = (
    Endpoint("in", AMBIENT_TEMPERATURE, FLOAT64, "K", COMMAND_QOS),
    Endpoint("in", OIL_TEMPERATURE, FLOAT64, "K", COMMAND_QOS),
    Endpoint("out", COIL_TEMPERATURE, FLOAT64, "K", SENSOR_DATA_QOS),
    Endpoint("out", COIL_RESISTANCE, FLOAT64, "ohm", SENSOR_DATA_QOS),
    Endpoint("out", CORE_POSITION, FLOAT64, "m", SENSOR_DATA_QOS),
)
#: Beside each valve's outputs and duty_cycle under ``<valve>/`` (:func:`valve_topic`).
RIG_INTERFACE: Final = (
    Endpoint("out", cylinder_topic(JOINT_STATES), "sensor_msgs/msg/JointState", "m", SENSOR_DATA_QOS),
    Endpoint("out", chamber_topic("a"), FLUID_PRESSURE, "Pa", SENSOR_DATA_QOS),
    Endpoint("out", chamber_topic("b"), FLUID_PRESSURE, "Pa", SENSOR_DATA_QOS),
    Endpoint("in", cylinder_topic(EXTERNAL_FORCE), FLOAT64, "N", COMMAND_QOS),
    Endpoint("in", FAULTS, "std_msgs/msg/String", "", COMMAND_QOS),
    Endpoint("srv", RESET, "std_srvs/srv/Trigger", ""),
    Endpoint("out", DIAGNOSTICS, "diagnostic_msgs/msg/DiagnosticArray", "", RELIABLE_10),
    Endpoint("out/in", CLOCK, "rosgraph_msgs/msg/Clock", "s", RELIABLE_10),
    Endpoint("out", LOCKSTEP_SAMPLE, "sensor_msgs/msg/JointState", "", COMMAND_QOS),
    Endpoint("in", LOCKSTEP_COMMAND, "sensor_msgs/msg/JointState", "1", COMMAND_QOS),
)
#: Seen from the rig's side.
SCENARIO_INTERFACE: Final = (
    Endpoint("out", SETPOINT, FLOAT64, "m", COMMAND_QOS),
    Endpoint("in", CONTROLLER_FLAGS, "diagnostic_msgs/msg/DiagnosticArray", "", FLAGS_QOS),
)
#: The QoS of every relative topic the registry lists (a valve's under `<valve>/` by its role).
_QOS: Final = {e.name: e.qos for e in (*EMULATOR_INTERFACE, *OPTION_INTERFACE, *RIG_INTERFACE, *SCENARIO_INTERFACE)
               if e.qos is not None}


def qos_of(topic: str, default: Qos | None = None) -> Qos:
    """The QoS the nodes offer on a relative topic (``left/pressure``: the role's, ``pressure``), the one
    the node's endpoints are made with and a bag's metadata states; `default` for a topic the registry
    does not list (ValueError without one)."""
    qos = _QOS.get(topic, _QOS.get(topic.rpartition("/")[2]))
    if qos is not None:
        return qos
    if default is None:
        raise ValueError(f"topic {topic!r} is not in the interface registry (pcv_sim.io.topics)")
    return default


# --- a device's interface as topics ----------------------------------------------------------
# The node serves any device from these tables: a device names its inputs and signals
# (`<owner>.<role>`, or the bare role for the emulator's one valve) and the topic, message type and
# what a message carries follow from the name here, once.

JOINT_STATE: Final = "sensor_msgs/msg/JointState"
#: The prismatic joint of the cylinder in `cylinder/joint_states`.
JOINT_NAME: Final = "steering"
#: The cylinder's signals, in the order a JointState carries them (position m, velocity m/s, effort N).
JOINT_FIELDS: Final = ("position", "velocity", "effort")
#: The roles whose messages are FluidPressure (stamped, Pa); the rest are Float64.
_PRESSURE_ROLES: Final = (SUPPLY_PRESSURE, PRESSURE)


def topic_of(name: str) -> str:
    """A device's input or signal name as its relative topic: `left.duty_cycle` -> `left/duty_cycle`,
    the emulator's `duty_cycle` -> `duty_cycle`."""
    owner, _, role = name.rpartition(".")
    return valve_topic(owner, role) if owner else role


@dataclass(frozen=True)
class InputTopic:
    """One input topic of a device: its relative topic, message type, the device's input name and,
    for a valve's duty, the valve whose answer it is in a lockstep (else "")."""

    topic: str
    type: str
    input: str
    answers: str = ""


@dataclass(frozen=True)
class OutputTopic:
    """One output topic of a device's samples: the signals it carries (one; the cylinder's three for
    a JointState) and the header.frame_id of a stamped message ("" = the node's frame_id)."""

    topic: str
    type: str
    signals: tuple[str, ...]
    frame_id: str = ""


def input_topics(inputs: tuple[str, ...] | list[str], valves: tuple[str, ...] | list[str]) -> tuple[InputTopic, ...]:
    """The topics of a device's inputs (`valves`: its valve names; a valve's duty_cycle answers a lockstep
    for it). The valves' duties first, in the order of `valves` (a lockstep waits on them)."""
    def answers(name: str) -> str:
        owner, _, role = name.rpartition(".")
        if role != DUTY_CYCLE:
            return ""
        return owner or valves[0]

    duties = sorted((n for n in inputs if answers(n)), key=lambda n: valves.index(answers(n)))
    return tuple(InputTopic(topic_of(n), FLUID_PRESSURE if n.rpartition(".")[2] in _PRESSURE_ROLES else FLOAT64,
                            n, answers(n))
                 for n in (*duties, *(n for n in inputs if n not in duties)))


def output_topics(signals: tuple[str, ...] | list[str], chambers: dict[str, str] | None = None) -> tuple[OutputTopic, ...]:
    """The topics of a device's sampled signals: one per valve signal (`left/pressure`...), the
    cylinder's signals as one JointState (`cylinder/joint_states`), and per chamber (`chambers`:
    valve -> a | b) the pressure of the valve on it again as `cylinder/pressure_<chamber>`."""
    out = []
    for name in signals:
        owner, _, role = name.rpartition(".")
        if owner == CYLINDER:
            continue
        out.append(OutputTopic(topic_of(name), FLUID_PRESSURE if role in _PRESSURE_ROLES else FLOAT64, (name,)))
    for valve, chamber in (chambers or {}).items():
        out.append(OutputTopic(chamber_topic(chamber), FLUID_PRESSURE, (f"{valve}.{PRESSURE}",), f"chamber_{chamber}"))
    joint = tuple(f"{CYLINDER}.{f}" for f in JOINT_FIELDS)
    if all(s in signals for s in joint):
        out.append(OutputTopic(cylinder_topic(JOINT_STATES), JOINT_STATE, joint, CYLINDER))
    return tuple(out)
