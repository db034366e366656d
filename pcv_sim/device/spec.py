"""What a device composes and what it hands out, as data: its valves (`ValveSpec`) and plant
(`PlantSpec`), the inputs it takes (`InputKind`, `InputCounts`), its samples (`Sample`), its
status (`DeviceStatus`), the recorder it calls (`Recorder`) and how it fails (`ModelFault`). The
device itself is `pcv_sim.device.device.Device`. No ROS.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple, Protocol

import numpy as np

from pcv_sim.errors import PcvSimError
from pcv_sim.io import topics
from pcv_sim.params import ValveParams
from pcv_sim.simulation.simulator import Simulator
from pcv_sim.simulation.system import System

__all__ = [
    "MODEL_FAILURES", "RECORD_INPUTS", "TEMPERATURE_INPUTS", "DeviceStatus", "InputCounts", "InputHook", "InputKind",
    "ModelFault", "PlantSpec", "Prepared", "Recorder", "Sample", "ValveSpec", "signal_kind",
]

#: What the model may raise when its state runs away (e.g. no coil current solves Eq. 2): a fault.
MODEL_FAILURES = (ArithmeticError, ValueError)


#: The valve options' temperature inputs (R33, R34) and the valve YAML's switch that brings each.
TEMPERATURE_INPUTS = {topics.AMBIENT_TEMPERATURE: "solenoid.coil_temperature: lumped",
                      topics.OIL_TEMPERATURE: "fluid.temperature: input"}


#: What a recorder gets of each valve besides its outputs (`Device.record_values`): the duty in force
#: (the command, or the watchdog's), the duty after the fall-rate limiter, load flow, supply pressure.
RECORD_INPUTS = ("duty_command", "duty", topics.LOAD_FLOW, topics.SUPPLY_PRESSURE)


def signal_kind(signal: str) -> str:
    """The physical kind (`pcv_sim.units.KINDS`) of a device's signal by its name (`left.pressure`,
    the emulator's `pressure`), of a duty, the rig's setpoint or a controller flag."""
    if signal.startswith("controller."):
        return "number"
    tail = signal.rsplit(".", 1)[-1]
    return {topics.PRESSURE: "pressure", topics.CURRENT: "current", topics.SPOOL_POSITION: "length", "duty": "fraction",
            "position": "length", "velocity": "velocity", "effort": "force", "setpoint": "length",
            topics.COIL_TEMPERATURE: "temperature", topics.CORE_POSITION: "length",
            topics.OIL_TEMPERATURE: "temperature", topics.AMBIENT_TEMPERATURE: "temperature"}.get(tail, "number")


#: `Device.on_input(step, name, value)`: an input of the model changed, acting from `step` on.
InputHook = Callable[[int, str, float], None]


class ModelFault(PcvSimError, RuntimeError):
    """The device cannot go on: its model ran away (the fault state, `Device.fault`, until a restart)."""


class Recorder(Protocol):
    """Receives one model sample: t_ns (stamp of the sample's model time), values by `record_values` name."""

    def __call__(self, t_ns: int, signals: Mapping[str, float]) -> None: ...


@dataclass(frozen=True)
class ValveSpec:
    """One valve of a device: its name (its namespace, a fault's target), its parameters, and the
    duty it holds at a start until a first command (None: the device's safe duty)."""

    name: str
    params: ValveParams
    initial_duty: float | None = None


@dataclass(frozen=True)
class PlantSpec:
    """What the valves act on: its system, the wires between it and the valves (`compose`'s
    `(a.output, b.input)`), its state at a start (at rest), the inputs a device takes for it
    (composite name -> check; 0 at a start) and its sampled outputs (composite names)."""

    system: System
    wires: tuple[tuple[str, str], ...]
    rest: tuple[float, ...]
    inputs: Mapping[str, Callable[[Any], float]]
    signals: tuple[str, ...]
    #: How the log says it is at its start state.
    at_rest: str = "the plant at its start state"


@dataclass(frozen=True)
class Prepared:
    """What `Device.prepare` made: new parameters and their valves (None: the present ones) and a
    simulator at rest (None: the device's start state, put in by `install`)."""

    params: Any
    valves: tuple[ValveSpec, ...] | None
    sim: Simulator | None
    what: str


@dataclass(frozen=True)
class InputKind:
    """One input a device takes: `check(value)` on arrival (the value as the model takes it, or
    CommandError saying what is accepted), `apply(value)` at the step it acts from (may raise
    CommandError or FaultError when what was valid on arrival no longer is: refused then)."""

    check: Callable[[Any], Any]
    apply: Callable[[Any], None]


@dataclass
class InputCounts:
    """Inputs accepted and refused per input name (and `FAULTS`), and the last refusal's reason."""

    accepted: dict[str, int] = field(default_factory=dict)
    rejected: dict[str, int] = field(default_factory=dict)
    last_rejection: str = ""

    def declare(self, names: Sequence[str]) -> None:
        for name in names:
            self.accepted.setdefault(name, 0)
            self.rejected.setdefault(name, 0)

    def clear(self) -> None:
        """Every count back to 0 (a fresh start)."""
        self.accepted = dict.fromkeys(self.accepted, 0)
        self.rejected = dict.fromkeys(self.rejected, 0)
        self.last_rejection = ""


class Sample(NamedTuple):
    """A device's true outputs at model step `step` (stamp `stamp_ns(step)`): `values` in the order of
    its `signals`, SI units."""

    step: int
    values: np.ndarray


@dataclass(frozen=True)
class DeviceStatus:
    """What diagnostics show of a device at one instant (model time `time`, s); per valve where keyed
    by valve name."""

    time: float
    commands: dict[str, float]            # the last valid duty command
    duties: dict[str, float]              # the duty in force (the safe duty once the watchdog fired)
    watchdogs: dict[str, str]             # `WatchdogState`
    watchdog_fired: dict[str, int]        # how often each watchdog fired
    faults: tuple[str, ...]               # active injected faults, "kind@target"
    fault: str | None                     # why the model stands still (it ran away), or None
    accepted: dict[str, int]              # inputs accepted per input name (and FAULTS)
    rejected: dict[str, int]              # refused
    last_rejection: str

