"""The rig without ROS: the valves and the steering cylinder in one `Simulator` at one fixed step.

Each valve's load port is one cylinder chamber: the valve's pressure state feeds the cylinder's
`pressure_a|b`; the chamber's displacement flow and volume feed the valve's `load_flow` and
`load_volume` (Eq. 15 with the chamber's V). Everything is integrated together at
`rig.time_step` (0.1 ms) with the valves' integrator (Heun for the simplified model), so the
load flow is never a step late.

The rig is a configuration of the one device (`pcv_sim.device.device.Device`, the emulator's
too): its valves and the cylinder as the plant. Inputs (`submit`: `<valve>.duty_cycle`,
`<valve>.supply_pressure`, `cylinder.external_force`, a valve option's `<valve>.<temperature>`),
fault commands, the watchdogs (waiting for a first command at the start: no controller yet is no
lost controller), the fall-rate limiter, the physical limits, `schedule`, `feed` (a profile's
values at given steps inside the compiled calls: no Python call per control period), restarts
and recording are the device's. The rig starts with each valve at rest at its `initial_duty` and
the piston at `initial_position`, at rest. A state that runs away raises RigError (the device's
`ModelFault`) and is the fault state until a reset.

Here: what is the rig's own (the cylinder as a plant, its faults and its external force, the
names of the signals from the rig YAML).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

from pcv_sim.device.device import TEMPERATURE_INPUTS, Device, InputHook, ModelFault, PlantSpec, ValveSpec
from pcv_sim.device.faults import CYLINDER
from pcv_sim.device.inputs import WatchdogState
from pcv_sim.device.spec import signal_kind
from pcv_sim.errors import CommandError
from pcv_sim.io import topics
from pcv_sim.io.topics import JOINT_FIELDS, LOAD_FLOW, OUTPUT_ROLES
from pcv_sim.model import kernel
from pcv_sim.plant import cylinder
from pcv_sim.plant.cylinder import cylinder_system
from pcv_sim.rig.params import RigParams

__all__ = [
    "CYLINDER_SIGNALS",
    "EXTERNAL_FORCE",
    "MAX_EXTERNAL_FORCE",
    "TEMPERATURE_INPUTS",
    "VALVE_SIGNALS",
    "InputHook",
    "Rig",
    "RigError",
    "check_external_force",
    "rig_signals",
    "signal_kind",
    "signal_names",
]

VALVE_SIGNALS = OUTPUT_ROLES
CYLINDER_SIGNALS = JOINT_FIELDS


def signal_names(valve_names: Sequence[str], options: Mapping[str, Sequence[str]] | None = None) -> tuple[str, ...]:
    """The rig's sampled signals in their order: `<valve>.<VALVE_SIGNALS>` per valve and the
    outputs its options bring (`options`: valve -> names), then `cylinder.<...>`."""
    opts = options or {}
    return tuple(f"{n}.{s}" for n in valve_names for s in (*VALVE_SIGNALS, *opts.get(n, ()))) + tuple(
        f"{CYLINDER}.{s}" for s in CYLINDER_SIGNALS)


def rig_signals(params: RigParams) -> tuple[str, ...]:
    """`signal_names` of a rig's valves with the outputs of their options (docs/model.md R33-R35:
    coil_temperature and coil_resistance of a heating coil, core_position of a separate core)."""
    kind = params.valves[0].params.simulation.model
    return signal_names([v.name for v in params.valves],
                        {v.name: kernel.layout(v.params, kind).outputs[len(kernel.OUTPUTS):] for v in params.valves})


#: N; beyond this an external force is a unit slip (kN for N), not a steering load.
MAX_EXTERNAL_FORCE = 1.0e6
#: The input name of the external force in `Rig.on_input` (valve inputs are `<valve>.duty_cycle`,
#: `<valve>.supply_pressure`).
EXTERNAL_FORCE = f"{CYLINDER}.{topics.EXTERNAL_FORCE}"


def check_external_force(force: Any) -> float:
    """The external force (N) as the rig takes it; CommandError saying what is accepted."""
    if isinstance(force, bool) or not isinstance(force, (int, float)) or not math.isfinite(force) \
            or abs(force) > MAX_EXTERNAL_FORCE:
        raise CommandError(f"external force {force!r}: accepted is a finite number of N within "
                           f"+-{MAX_EXTERNAL_FORCE:g} N")
    return float(force)


#: The rig cannot go on: the model state ran away (the device's fault state, the emulator's too).
RigError = ModelFault

class Rig(Device):
    """N valves + one cylinder at one fixed step (the device of valves and a plant; see the module
    docstring)."""

    params: RigParams

    def __init__(self, params: RigParams, *, seed: int = 0) -> None:
        self.params = params
        t = params.timing
        super().__init__(t.time_step, _valve_specs(params), _plant_spec(params), watchdog_timeout=t.watchdog_timeout,
                         safe_duty=t.safe_duty, sample_every=params.steps_per_period, seed=seed,
                         restart_at_start=True)

    def _valve_specs_of(self, params: RigParams) -> tuple[ValveSpec, ...]:
        if params.cylinder != self.params.cylinder or [(v.name, v.chamber) for v in params.valves] != \
                [(v.name, v.chamber) for v in self.params.valves] or params.timing != self.params.timing:
            from pcv_sim.errors import ParameterError
            raise ParameterError("while the rig runs only its valves' parameters may change; restart it for a new "
                                 "cylinder, timing or valve layout")
        return _valve_specs(params)

    @property
    def has_cylinder(self) -> bool:
        return True

    @property
    def watchdog_fired(self) -> dict[str, bool]:
        """Per valve: has its watchdog fired (and no command come since)."""
        return {name: w.state == WatchdogState.FIRED for name, w in self.watchdogs.items()}

    def set_external_force(self, force: Any) -> None:
        """The external force on the rod (N, + toward +x: extending) from the present step on."""
        self._put_plant_input(EXTERNAL_FORCE, check_external_force(force))

    def _apply_plant_faults(self) -> None:
        """The cylinder's parameter vector: healthy, then every active fault on it."""
        p = self._healthy_plant.copy()
        for (target, kind), f in self.faults.items():
            if target != CYLINDER:
                continue
            if kind == "cylinder_friction":
                friction = f.values["friction"]
                p[cylinder.F_C] = friction
                # The friction's slope at v = 0 (F / v_s) kept at most m / dt: a steeper one is a
                # stiffer piston than the explicit step can hold (as the sticking spool's).
                p[cylinder.V_S] = max(p[cylinder.V_S], friction * self.dt / p[cylinder.MASS])
            elif kind == "cylinder_jam":
                p[cylinder.JAMMED] = 1.0
                self.sim.x[self._state_off[-2] + 1] = 0.0      # seized where it is: no velocity
        self.sim.set_parameters(len(self.valve_names), p)


def _valve_specs(params: RigParams) -> tuple[ValveSpec, ...]:
    return tuple(ValveSpec(v.name, v.params, v.initial_duty) for v in params.valves)


def _plant_spec(params: RigParams) -> PlantSpec:
    """The cylinder, each valve's load port on its chamber (its pressure into the cylinder's, the
    chamber's displacement flow and volume into its load flow and volume), at rest at its initial
    position; it takes the external force."""
    wires: list[tuple[str, str]] = []
    for v in params.valves:
        c = v.chamber
        if c not in ("a", "b"):
            continue                    # on its own load volume: load_flow and load_volume stay inputs
        wires += [(f"{v.name}.pressure", f"cylinder.pressure_{c}"), (f"cylinder.flow_{c}", f"{v.name}.{LOAD_FLOW}"),
                  (f"cylinder.volume_{c}", f"{v.name}.load_volume")]
    return PlantSpec(cylinder_system(params.cylinder, CYLINDER), tuple(wires), (params.cylinder.initial_position, 0.0),
                     {EXTERNAL_FORCE: check_external_force}, tuple(f"{CYLINDER}.{s}" for s in CYLINDER_SIGNALS),
                     "piston at rest at its initial position")
