"""Rest states of the valve: equilibria of Eq. 14 (v = 0) with continuity Eq. 15 (dp/dt = 0).

At rest the spool balance fixes the load pressure for each spool position x, and continuity
then says which load flow holds it there: q_l = q_v(x, p). Parametrising by x turns the
pressure-flow curve (the paper's Fig. 10) into 1-D root finding, with no 2-D solve.
Sign convention: load flow q_l > 0 is drawn from the load port (reducing mode), q_l < 0 is
pushed into it and relieved to tank (relieving mode).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import brentq

from pcv_sim.errors import PcvSimError
from pcv_sim.model.valve import ValveModel

__all__ = [
    "EquilibriumError",
    "StaticPoint",
    "balance_pressure",
    "equilibrium_at_flow",
    "static_point",
    "stop_point",
    "zero_flow_equilibrium",
]


class EquilibriumError(PcvSimError, ArithmeticError):
    """No static equilibrium exists for the inputs asked (e.g. a load flow beyond the valve's reach)."""


@dataclass(frozen=True)
class StaticPoint:
    """One equilibrium: SI units."""

    duty: float
    current: float          # A
    spool_position: float   # m
    pressure: float         # Pa
    load_flow: float        # m^3/s
    pump_flow: float        # m^3/s
    tank_flow: float        # m^3/s
    flow_force: float       # N, + toward -x


def balance_pressure(model: ValveModel, current: float, x: float, supply_pressure: float) -> float:
    """The load pressure (Pa) at which the spool at x is at rest with coil current `current`.

    Solves Eq. 14 with v = 0, p_c = p for p. The net force falls monotonically with p (the area
    term dominates the flow-force change), so the root is bracketed between tank pressure and
    well above supply.
    """
    lo, hi = model.p_tank, 3.0 * supply_pressure

    def residual(p: float) -> float:
        return model.static_force(current, x, p, supply_pressure)

    r_lo, r_hi = residual(lo), residual(hi)
    if r_lo <= 0.0:
        # Even at tank pressure the solenoid cannot hold the spool at x against spring and flow
        # forces: no free equilibrium there (only one held by an end stop).
        raise EquilibriumError(f"the spool cannot rest at x={x:.4g} m with i={current:.4g} A at any load pressure")
    if r_hi > 0.0:
        raise EquilibriumError(f"no balance pressure below {hi:.3g} Pa at x={x:.3g} m, i={current:.3g} A")
    return float(brentq(residual, lo, hi, xtol=1e-6, rtol=1e-12))


def static_point(model: ValveModel, duty: float, x: float, supply_pressure: float | None = None) -> StaticPoint:
    """The equilibrium with the spool at x (m) at duty D: pressure from Eq. 14, flow from Eq. 15."""
    ps = model.p_supply if supply_pressure is None else supply_pressure
    i = model.steady_current(duty)
    p = balance_pressure(model, i, x, ps)
    hyd = model.hydraulics(x, p, ps)
    return StaticPoint(duty, i, x, p, hyd.valve_flow, hyd.pump_flow, hyd.tank_flow, hyd.flow_force)


def stop_point(model: ValveModel, duty: float, at_max: bool, load_flow: float, supply_pressure: float) -> StaticPoint:
    """An equilibrium held by an end stop: x at the stop, p from continuity q_v(x, p) = q_l."""
    x = model.x_max if at_max else model.x_min
    i = model.steady_current(duty)

    def excess(p: float) -> float:
        return model.hydraulics(x, p, supply_pressure).valve_flow - load_flow

    lo, hi = model.p_tank, 3.0 * supply_pressure
    if not excess(lo) >= 0.0 >= excess(hi):
        raise EquilibriumError(
            f"load flow {load_flow:.4g} m^3/s cannot be held with the spool on its {'max' if at_max else 'min'} stop"
        )
    p = brentq(excess, lo, hi, xtol=1e-6, rtol=1e-12)
    hyd = model.hydraulics(x, p, supply_pressure)
    return StaticPoint(duty, i, x, p, hyd.valve_flow, hyd.pump_flow, hyd.tank_flow, hyd.flow_force)


def equilibrium_at_flow(
    model: ValveModel, duty: float, load_flow: float = 0.0, supply_pressure: float | None = None, *, grid: int = 281
) -> StaticPoint:
    """The rest state that delivers `load_flow` (m^3/s) at duty D.

    A free equilibrium (spool floating, Eq. 14 balanced) exists only where the solenoid can hold
    the spool at some pressure: at low duty and large opening it cannot, and at 0 % nowhere.
    The stroke is scanned on `grid` points for the first bracket of valid positions where the
    net valve flow crosses `load_flow`; if the flow is out of reach of the free positions on the
    side of a stop, the spool rests on that stop with the pressure continuity sets.
    """
    ps = model.p_supply if supply_pressure is None else supply_pressure
    xs = np.linspace(model.x_min, model.x_max, grid)
    points: list[StaticPoint | None] = []
    for x in xs:
        try:
            b: StaticPoint | None = static_point(model, duty, float(x), ps)
        except EquilibriumError:
            b = None
        a = points[-1] if points else None
        points.append(b)
        # The first bracket in the scan's order; points beyond it are not needed (the rest state
        # of a replay, a restart or a rig reset computes ~40 % of the grid instead of all of it).
        if a is not None and b is not None and (a.load_flow - load_flow) * (b.load_flow - load_flow) <= 0.0:
            root = brentq(
                lambda xs: static_point(model, duty, xs, ps).load_flow - load_flow,
                a.spool_position, b.spool_position, xtol=1e-13, rtol=1e-12,
            )
            return static_point(model, duty, root, ps)
    valid = [p for p in points if p is not None]
    # No free equilibrium delivers it: the spool is pushed onto a stop. The solenoid too weak
    # everywhere (or more flow than wanted even at x_min) -> min stop; too little -> max stop.
    if not valid or min(p.load_flow for p in valid) > load_flow:
        return stop_point(model, duty, False, load_flow, ps)
    if points[-1] is not None and points[-1].load_flow < load_flow:
        return stop_point(model, duty, True, load_flow, ps)
    reach = (min(p.load_flow for p in valid), max(p.load_flow for p in valid))
    raise EquilibriumError(
        f"load flow {load_flow:.4g} m^3/s is outside what the valve holds at rest at duty {duty:.3g}: "
        f"{reach[0]:.4g} .. {reach[1]:.4g} m^3/s"
    )


def zero_flow_equilibrium(model: ValveModel, duty: float, supply_pressure: float | None = None) -> StaticPoint:
    """The rest point with no load flow (the dynamic tests' condition, Sec. 3.2)."""
    return equilibrium_at_flow(model, duty, 0.0, supply_pressure)
