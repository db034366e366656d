"""A spring-loaded piston between two valve load ports: the smallest plant of the simulation core.

Also the worked example of how a new system plugs in: four functions over float arrays in the
numba subset (`rhs`, `state_output`, `output`, `project`) and a factory that describes them as a
`System` with named signals and a parameter vector.

    states   position x (m, + toward chamber b), velocity v (m/s)
    inputs   pressure_a, pressure_b (Pa): the pressures in the chambers on either side
    outputs  flow_a, flow_b (m^3/s drawn from the port feeding each chamber: chamber a grows
             with +x and draws A v, chamber b shrinks and pushes A v back: flow_b = -A v),
             position, velocity; all depend on the state alone (connectable)

    m dv/dt = A (p_a - p_b) - k x - c v, with inelastic end stops at x_min, x_max.
"""

from __future__ import annotations

import numpy as np

from pcv_sim.jit import jit
from pcv_sim.model import stops
from pcv_sim.simulation.system import Kernel, Stop, System

__all__ = ["mass_spring"]

AREA, MASS, STIFFNESS, DAMPING, X_MIN, X_MAX = 0, 1, 2, 3, 4, 5


@jit(inline=True)
def rhs(t, x, u, p, f, w, dx):
    force = p[AREA] * (u[0] - u[1]) - p[STIFFNESS] * x[0] - p[DAMPING] * x[1]
    if stops.held(x[0], x[1], force, p[X_MIN], p[X_MAX]):
        dx[0] = 0.0
        dx[1] = 0.0
    else:
        dx[0] = x[1]
        dx[1] = force / p[MASS]


@jit(inline=True)
def state_output(t, x, p, f, y):
    y[0] = p[AREA] * x[1]
    y[1] = -p[AREA] * x[1]
    y[2] = x[0]
    y[3] = x[1]


@jit(inline=True)
def output(t, x, u, p, f, w, y):
    state_output(t, x, p, f, y)


@jit(inline=True)
def project(x, p):
    stops.impact(x, 0, 1, p[X_MIN], p[X_MAX])


def mass_spring(name: str = "piston", *, area: float, mass: float, stiffness: float, damping: float,
                x_min: float = -np.inf, x_max: float = np.inf) -> System:
    """The piston as a `System` (SI units)."""
    if not (area > 0 and mass > 0 and stiffness >= 0 and damping >= 0 and x_min < x_max):
        raise ValueError("mass_spring: accepted are area > 0, mass > 0, stiffness >= 0, damping >= 0, x_min < x_max")
    p = np.array([area, mass, stiffness, damping, max(x_min, -1e300), min(x_max, 1e300)], dtype=np.float64)
    return System(
        name=name, states=("position", "velocity"), inputs=("pressure_a", "pressure_b"),
        outputs=("flow_a", "flow_b", "position", "velocity"),
        state_outputs=("flow_a", "flow_b", "position", "velocity"),
        kernel=Kernel("pcv_sim.plant.mass_spring"), p=p, f=(np.zeros(1),), workspace=1,
        stops=(Stop(0, 1, float(p[X_MIN]), float(p[X_MAX])),),
    )
