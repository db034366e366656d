"""Inelastic end stops of a moving part (the spool's Sec. 4.2 stroke, a piston's): the one
definition every system of the simulation core uses. Positions and velocities in SI units."""

from __future__ import annotations

from pcv_sim.jit import jit

__all__ = ["held", "impact"]


@jit(inline=True)
def held(position, velocity, force, lo, hi):
    """True while the part rests on a stop with the force pushing into it: it stays (dx = dv = 0)."""
    return (position <= lo and velocity <= 0.0 and force <= 0.0) or (position >= hi and velocity >= 0.0
                                                                      and force >= 0.0)


@jit(inline=True)
def impact(x, i_position, i_velocity, lo, hi):
    """After a step: a position beyond a stop is put back on it, a velocity into it is lost
    (an inelastic impact). Changes the state vector x in place."""
    if x[i_position] < lo:
        x[i_position] = lo
        x[i_velocity] = max(x[i_velocity], 0.0)
    elif x[i_position] > hi:
        x[i_position] = hi
        x[i_velocity] = min(x[i_velocity], 0.0)
