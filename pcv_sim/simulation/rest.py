"""The one way to find where the valve rests for given inputs (used by the emulator, replay and
the stiff reference alike).

First the static equilibrium (`pcv_sim.model.statics.equilibrium_at_flow`: Eq. 14 at rest with
continuity Eq. 15). Where none exists (below ~0.3 duty the spool sits on its end stop, where the
1-D search finds no free equilibrium), the model itself is run from a feasible equilibrium with
these inputs until it settles (over 10 ms: pressure within 1 Pa, spool within 1 nm, current
within 1 uA; at most 2 s of model time), with the integrator the caller will use.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pcv_sim.model import kernel
from pcv_sim.model.statics import EquilibriumError, equilibrium_at_flow
from pcv_sim.model.valve import ValveModel
from pcv_sim.params import ValveParams
from pcv_sim.simulation.simulator import Simulator
from pcv_sim.simulation.valve import valve_inputs, valve_system

__all__ = ["EquilibriumError", "Rest", "rest_state"]

_FALLBACK_DUTIES = (0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0)
_SETTLE_CHUNK = 100          # steps between convergence checks
_SETTLE_MAX = 2.0            # s of model time at most


@dataclass(frozen=True)
class Rest:
    """A rest state: the state vector (the model kind's layout) and the coil current there."""

    state: np.ndarray
    current: float
    settled: bool            # True: found by running the model (no static equilibrium exists)


def _static(model: ValveModel, duty: float, load_flow: float, supply_pressure: float) -> Rest:
    eq = equilibrium_at_flow(model, duty, load_flow, supply_pressure)
    return Rest(np.array(model.initial_state(duty, eq.spool_position, eq.pressure)), eq.current, False)


def rest_state(params: ValveParams, kind: str, duty: float, load_flow: float = 0.0,
               supply_pressure: float | None = None, *, integrator: str = "rk2") -> Rest:
    """Where the valve rests at `duty`, `load_flow` (m^3/s) and `supply_pressure` (Pa, default
    the config's). Raises EquilibriumError when the model does not settle."""
    model = ValveModel(params, kind)  # type: ignore[arg-type]
    ps = model.p_supply if supply_pressure is None else supply_pressure
    try:
        return _static(model, duty, load_flow, ps)
    except EquilibriumError:
        pass
    start = None
    for d in _FALLBACK_DUTIES:
        try:
            start = _static(model, d, load_flow, ps)
            break
        except EquilibriumError:
            continue
    if start is None:
        raise EquilibriumError("the model has no rest equilibrium at any duty 0.3 .. 1 to start from")
    sim = Simulator(valve_system(params, kind), params.simulation.time_step, integrator)
    sim.x[:] = start.state
    sim.W[0] = start.current
    sim.u[:] = valve_inputs(params, duty, load_flow, ps)
    for _ in range(int(_SETTLE_MAX / (_SETTLE_CHUNK * sim.dt))):
        before = sim.x.copy()
        i_before = float(sim.outputs()[1])
        sim.advance(_SETTLE_CHUNK)
        if not sim.finite():
            raise EquilibriumError(f"the model does not settle at duty {duty:g}, load flow {load_flow:g} m^3/s")
        i_now = float(sim.outputs()[1])
        if (abs(sim.x[3] - before[3]) < 1.0 and abs(sim.x[1] - before[1]) < 1e-9
                and abs(i_now - i_before) < 1e-6):
            break
    state = sim.x.copy()
    if params.solenoid.coil_thermal:      # the coil as switched on, not as warmed by the settling run
        state[sim.plant.index("state", "valve.coil_temperature")] = kernel.option_states(params, 0.0)[0]
    return Rest(state, float(sim.outputs()[1]), True)
