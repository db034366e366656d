"""The valve as a `System` of the simulation core (equations: `pcv_sim.model.kernel`).

Signals (SI): inputs duty_cycle (0..1), load_flow (m^3/s, + drawn from the load port),
supply_pressure (Pa), load_volume (m^3: the oil volume at the load port, Eq. 15's V; a single
valve is fed `circuit.load_volume`, a valve on a cylinder its chamber's volume); outputs
pressure (Pa), current (A), spool_position (m); pressure and spool position depend on the state
alone and can be connected to other systems. The options beyond the paper's bench append their
signals when switched on in the valve YAML (`pcv_sim.model.kernel.layout`): inputs
ambient_temperature and oil_temperature (K), outputs coil_temperature (K), coil_resistance (ohm)
and core_position (m), all state outputs.

Also the inputs as a plant can give them (`check_load_flow`, `check_supply_pressure`,
`check_temperature`; `check_oil_step`: an oil too cold for an explicit step): beyond these the
value is no rig's (or a unit slip) and is refused with what is accepted, never integrated.
"""

from __future__ import annotations

import math

import numpy as np

from pcv_sim.errors import CommandError
from pcv_sim.model import kernel
from pcv_sim.params import ValveParams
from pcv_sim.simulation.system import Kernel, Stop, System
from pcv_sim.units import KELVIN_AT_0C, M3S_PER_LPM, PA_PER_BAR, bar

__all__ = [
    "KINDS", "MAX_LOAD_FLOW", "MAX_SUPPLY_PRESSURE", "MAX_TEMPERATURE", "MIN_SUPPLY_PRESSURE", "MIN_TEMPERATURE",
    "check_load_flow", "check_oil_step", "check_supply_pressure", "check_temperature", "valve_inputs",
    "valve_integrator", "valve_system",
]

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


# --- the inputs as a plant can give them -----------------------------------------------------

# Beyond these the input is not a plant any rig could produce: refuse rather than integrate it.
MAX_LOAD_FLOW = 100.0 * M3S_PER_LPM     # the valve passes ~50 L/min fully open
MAX_SUPPLY_PRESSURE = 400.0 * PA_PER_BAR
MIN_SUPPLY_PRESSURE = 1.0 * PA_PER_BAR   # below 1 bar a value is far more likely bar than Pa
def check_load_flow(value: float) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise CommandError(f"load flow {value!r}: accepted is a finite number in m^3/s")
    if abs(value) > MAX_LOAD_FLOW:
        # Name L/min only when the number read as L/min is a flow this valve can see.
        looks_lpm = abs(value) * M3S_PER_LPM <= MAX_LOAD_FLOW
        hint = f"; the unit is m^3/s, not L/min: {value:g} L/min is {value * M3S_PER_LPM:.4g} m^3/s" if looks_lpm else ""
        raise CommandError(
            f"load flow {value:g} m^3/s is beyond +-{MAX_LOAD_FLOW:.4g} m^3/s (100 L/min){hint}"
        )
    return float(value)


def check_supply_pressure(value: float) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise CommandError(f"supply pressure {value!r}: accepted is a finite number in Pa")
    if not MIN_SUPPLY_PRESSURE <= value <= MAX_SUPPLY_PRESSURE:
        # Name bar only when the number read as bar is in range (200 -> 200 bar), not for 5e8.
        looks_bar = MIN_SUPPLY_PRESSURE <= value * PA_PER_BAR <= MAX_SUPPLY_PRESSURE
        hint = f" (the unit is Pa, not bar: {value:g} bar is {value * PA_PER_BAR:.4g} Pa)" if looks_bar else ""
        raise CommandError(
            f"supply pressure {value:g} Pa: accepted is {MIN_SUPPLY_PRESSURE:.4g} .. {MAX_SUPPLY_PRESSURE:.4g} Pa "
            f"({bar(MIN_SUPPLY_PRESSURE):g} .. {bar(MAX_SUPPLY_PRESSURE):g} bar){hint}"
        )
    return float(value)


MIN_TEMPERATURE, MAX_TEMPERATURE = 213.15, 473.15    # K: -60 .. 200 degC, what a valve in a vehicle sees


def check_temperature(what: str, value: float) -> float:
    """A temperature input (K): refused beyond -60 .. 200 degC, with a hint when it reads as degC."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise CommandError(f"{what} {value!r}: accepted is a finite number in K")
    if not MIN_TEMPERATURE <= value <= MAX_TEMPERATURE:
        looks_c = MIN_TEMPERATURE <= value + KELVIN_AT_0C <= MAX_TEMPERATURE
        hint = f" (the unit is K, not degC: {value:g} degC is {value + KELVIN_AT_0C:.5g} K)" if looks_c else ""
        raise CommandError(f"{what} {value:g} K: accepted is {MIN_TEMPERATURE:g} .. {MAX_TEMPERATURE:g} K "
                           f"(-60 .. 200 degC){hint}")
    return float(value)


def check_oil_step(params: ValveParams, p: np.ndarray, dt: float, exact: bool, temperature: float) -> None:
    """Cold oil multiplies the laminar damping (R34): the spool's pole B_eq mu/mu_ref / m then
    outgrows an explicit step (Heun's bound on the real axis is h lambda = 2). With `exact` (erk2
    takes the pole, the core attached: `valve_system`) any temperature runs; otherwise one beyond
    the bound is refused (CommandError) with what would run it, rather than integrated into a
    diverging state. `p`: the valve's packed parameters."""
    if exact:
        return
    mu_ratio = float(kernel.oil_properties(temperature, p)[3])
    sp = params.spool
    mass = sp.mass - sp.core_mass if sp.core_separation else sp.mass
    z = params.equivalent_damping * mu_ratio / mass * dt
    if z > 2.0:
        exact_dt = dt * 2.0 / z
        scale = 10.0 ** (math.floor(math.log10(exact_dt)) - 1)
        limit = math.floor(exact_dt / scale) * scale        # two digits, rounded down: a step that runs
        raise CommandError(
            f"oil temperature {temperature - KELVIN_AT_0C:.1f} degC: the oil's viscosity ({mu_ratio:.3g}x the "
            f"reference's) makes the spool's damping pole {z / dt:.3g} 1/s, beyond what the "
            f"{dt:g} s step integrates (h lambda = {z:.2f} > 2); accepted is warmer oil, "
            f"simulation.time_step <= {limit:.2g} s for this temperature"
            + (", or simulation.integrator: erk2 (or auto), which takes the pole exactly"
               if not sp.core_separation else
               " (with spool.core: separate the spool and the core each have their own pole)"))
