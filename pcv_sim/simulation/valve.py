"""The valve as a `System` of the simulation core (equations: `pcv_sim.model.kernel`).

Signals (SI): inputs duty_cycle (0..1), load_flow (m^3/s, + drawn from the load port),
supply_pressure (Pa), load_volume (m^3: the oil volume at the load port, Eq. 15's V; a single
valve is fed `circuit.load_volume`, a valve on a cylinder its chamber's volume); outputs
pressure (Pa), current (A), spool_position (m); pressure and spool position depend on the state
alone and can be connected to other systems. The options beyond the paper's bench append their
signals when switched on in the valve YAML (`pcv_sim.model.kernel.layout`): inputs
ambient_temperature and oil_temperature (K), outputs coil_temperature (K), coil_resistance (ohm)
and core_position (m), all state outputs.
"""

from __future__ import annotations

import numpy as np

from pcv_sim.model import kernel
from pcv_sim.params import ValveParams
from pcv_sim.simulation.system import Kernel, Stop, System

__all__ = ["KINDS", "valve_inputs", "valve_integrator", "valve_system"]

KINDS = ("simplified", "full")


def valve_system(params: ValveParams, kind: str = "simplified", name: str = "valve") -> System:
    """The valve model (`simplified`: Sec. 4.3, 4 states; `full`: Sec. 4.2 with the damping chamber)."""
    p, f = kernel.pack(params, kind)
    names = kernel.layout(params, kind)
    rates = [0.0] * len(names.states)
    if kind == "full":
        rates[4] = float(kernel.chamber_rate(p))      # Eq. 29's linear part, integrated exactly
    # The spool's damping pole in oil of a changing temperature (R34), taken exactly by erk2. With
    # the core separate (R35) the spool and the core change between one body and two, each with
    # its own pole: they stay explicit (and cold oil then asks for a smaller step).
    exact_spool = ((2, kernel.V_RATE),) if params.fluid.oil_temperature_model and not params.spool.core_separation \
        else ()
    return System(
        name=name, states=names.states, inputs=names.inputs, outputs=names.outputs,
        state_outputs=names.state_outputs, kernel=Kernel("pcv_sim.model.kernel", *kernel.functions(params)), p=p, f=f,
        workspace=1, stiff_rates=np.array(rates), rate_parameters=exact_spool,
        stops=(Stop(1, 2, p[kernel.X_MIN], p[kernel.X_MAX]),),
    )


def valve_integrator(params: ValveParams, kind: str) -> str:
    """The integrator a valve of `kind` runs: the config's `simulation.integrator` for the
    config's model; 'auto' (or another kind) is Heun (rk2) for the simplified model, exponential
    Heun (erk2) for the full one (its chamber pole) and for either with the oil temperature as
    an input and the core attached (the spool's damping pole, ~100x in oil at -20 degC, taken
    exactly: R34)."""
    if kind == params.simulation.model and params.simulation.integrator != "auto":
        return params.simulation.integrator
    exact_spool = params.fluid.oil_temperature_model and not params.spool.core_separation
    return "erk2" if kind == "full" or exact_spool else "rk2"


def valve_inputs(params: ValveParams, duty: float, load_flow: float, supply_pressure: float,
                 load_volume: float | None = None) -> np.ndarray:
    """The valve's input vector in its layout: the paper's four, then the options' temperatures
    at their configured values (K): a single valve's inputs where nothing else feeds them."""
    volume = params.circuit.load_volume if load_volume is None else load_volume
    return np.array((duty, load_flow, supply_pressure, volume, *kernel.option_inputs(params)), dtype=np.float64)
