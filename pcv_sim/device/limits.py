"""What a valve can show: beyond it the model has diverged, and nothing leaves a device.

`PhysicalLimits` per valve (its parameters' supply, coil voltage and resistance) is checked on
every sample and record before it leaves a device (`pcv_sim.device.device`) and on a new rest
state's trial run before it is installed.
"""

from __future__ import annotations

from dataclasses import dataclass

from pcv_sim.params import ValveParams
from pcv_sim.simulation.valve import MAX_SUPPLY_PRESSURE
from pcv_sim.units import PA_PER_BAR, bar

__all__ = ["TRIAL_STEPS", "PhysicalLimits"]

#: Model steps a new rest state is run on trial before it is accepted (20 ms at 0.1 ms): a model
#: that diverges at rest at the present operating point is refused, not installed.
TRIAL_STEPS = 200


@dataclass(frozen=True)
class PhysicalLimits:
    """What a valve of these parameters can show; beyond it the model has diverged (a fault).

    pressure: -1 bar (vacuum, gauge) .. 2 x the highest supply the device accepts or is configured
    with (a reducing valve cannot exceed its supply; the factor leaves room for compression of the
    load by a pushed-in flow). current: |i| <= 2 x supply voltage / coil resistance (the steady
    current at duty 1 is V/R; the factor leaves room for the induced voltage)."""

    pressure_min: float     # Pa
    pressure_max: float     # Pa
    current_max: float      # A

    @classmethod
    def of(cls, params: ValveParams) -> PhysicalLimits:
        sol = params.solenoid
        return cls(-PA_PER_BAR, 2.0 * max(MAX_SUPPLY_PRESSURE, params.circuit.supply_pressure),
                   2.0 * sol.supply_voltage / sol.coil_resistance)

    def problem(self, pressure: float, current: float) -> str | None:
        """Why (pressure, current) is no valve's, or None."""
        if not self.pressure_min <= pressure <= self.pressure_max:
            return (f"pressure {bar(pressure):.4g} bar outside the physical range {bar(self.pressure_min):g} .. "
                    f"{bar(self.pressure_max):g} bar: the model diverged")
        if not abs(current) <= self.current_max:
            return (f"coil current {current:.4g} A beyond the coil's possible +-{self.current_max:.3g} A: "
                    "the model diverged")
        return None
