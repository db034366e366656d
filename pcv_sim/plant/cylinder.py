"""A double-acting steering cylinder whose two chambers are the load ports of two valves.

The chamber pressures are the valves' states (Eq. 15 with the chamber's volume as V, fed by
this system's `volume_a` / `volume_b` outputs); the cylinder gives each valve the flow its
chamber draws and the volume it has, and moves under the pressure force.

    states   position x (m, 0 = mid-stroke, + extends: chamber a grows), velocity v (m/s)
    inputs   pressure_a, pressure_b (Pa gauge: the valves' pressures), external_force (N, + toward +x)
    outputs  volume_a, volume_b (m^3: chamber + hose, the valves' `load_volume`),
             flow_a, flow_b (m^3/s drawn from each valve's load port, the valves' `load_flow`),
             position (m), velocity (m/s): these depend on the state alone (connectable);
             effort (N): the net hydraulic force A_a p_a - A_b p_b (depends on the inputs)

Equations (SI):

    V_a = V_hose,a + V_dead,a + A_a (x - x_min)         V_b = V_hose,b + V_dead,b + A_b (x_max - x)
    q_a = A_a v   (chamber a grows with +x: drawn from valve a's port)
    q_b = -A_b v  (chamber b shrinks with +x: pushed back into valve b's port)
    m dv/dt = A_a p_a - A_b p_b - k x - (c_load + c_visc) v - F_c tanh(v / v_s) + F_ext

The Coulomb friction is smoothed with tanh over the velocity scale v_s (`friction_velocity`):
an exact sign(v) would chatter at v = 0 under a fixed step; with v_s = 1 mm/s the friction is
within 4 % of F_c above 2 mm/s. The end stops at x_min, x_max are inelastic: at a stop with
the force pushing into it the piston stays; `project` sets the velocity to 0 at impact.
"""

from __future__ import annotations

import math

import numpy as np

from pcv_sim.jit import jit
from pcv_sim.model import stops
from pcv_sim.plant.params import CylinderParams
from pcv_sim.simulation.system import Kernel, Stop, System

__all__ = ["INPUTS", "OUTPUTS", "STATES", "STATE_OUTPUTS", "cylinder_system", "pack"]

STATES = ("position", "velocity")
INPUTS = ("pressure_a", "pressure_b", "external_force")
OUTPUTS = ("volume_a", "volume_b", "flow_a", "flow_b", "position", "velocity", "effort")
STATE_OUTPUTS = OUTPUTS[:-1]

A_A, A_B, MASS, K_LOAD, DAMPING, F_C, V_S, X_MIN, X_MAX, V0_A, V0_B = range(11)
JAMMED = 11                 # fault (pcv_sim.device.faults): 1 = the piston is held where it is
N_PARAMS = 12


def pack(params: CylinderParams) -> np.ndarray:
    """The parameter vector of the kernel (SI)."""
    p = np.zeros(N_PARAMS)
    p[A_A], p[A_B], p[MASS] = params.area_a, params.area_b, params.mass
    p[K_LOAD], p[DAMPING] = params.load_stiffness, params.load_damping + params.viscous_friction
    p[F_C], p[V_S] = params.coulomb_friction, params.friction_velocity
    p[X_MIN], p[X_MAX] = params.stroke_min, params.stroke_max
    p[V0_A] = params.hose_volume_a + params.dead_volume_a       # chamber a's volume at x = x_min
    p[V0_B] = params.hose_volume_b + params.dead_volume_b       # chamber b's volume at x = x_max
    return p


@jit(inline=True)
def net_force(x, u, p):
    """m dv/dt (N): A_a p_a - A_b p_b - k x - c v - F_c tanh(v / v_s) + F_ext (+ toward +x)."""
    pos, v = x[0], x[1]
    return (p[A_A] * u[0] - p[A_B] * u[1] - p[K_LOAD] * pos - p[DAMPING] * v
            - p[F_C] * math.tanh(v / p[V_S]) + u[2])


@jit(inline=True)
def rhs(t, x, u, p, f, w, dx):
    """dx/dt = v, m dv/dt = net_force; held at an end stop while the force pushes into it, and
    anywhere while jammed (a fault; the rig zeroes the velocity when it is set)."""
    force = net_force(x, u, p)
    if p[JAMMED] != 0.0 or stops.held(x[0], x[1], force, p[X_MIN], p[X_MAX]):
        dx[0] = 0.0
        dx[1] = 0.0
    else:
        dx[0] = x[1]
        dx[1] = force / p[MASS]


@jit(inline=True)
def state_output(t, x, p, f, y):
    """Chamber volumes (m^3), displacement flows (m^3/s, + drawn from the valve), position, velocity."""
    y[0] = p[V0_A] + p[A_A] * (x[0] - p[X_MIN])
    y[1] = p[V0_B] + p[A_B] * (p[X_MAX] - x[0])
    y[2] = p[A_A] * x[1]
    y[3] = -p[A_B] * x[1]
    y[4] = x[0]
    y[5] = x[1]


@jit(inline=True)
def output(t, x, u, p, f, w, y):
    """State outputs and the effort A_a p_a - A_b p_b (N, the joint's effort, + toward +x)."""
    state_output(t, x, p, f, y)
    y[6] = p[A_A] * u[0] - p[A_B] * u[1]


@jit(inline=True)
def project(x, p):
    """Inelastic end stops: position clamped to the stroke, velocity into the stop zeroed."""
    stops.impact(x, 0, 1, p[X_MIN], p[X_MAX])


def cylinder_system(params: CylinderParams, name: str = "cylinder") -> System:
    """The cylinder as a `System` of the simulation core."""
    p = pack(params)
    return System(
        name=name, states=STATES, inputs=INPUTS, outputs=OUTPUTS, state_outputs=STATE_OUTPUTS,
        kernel=Kernel("pcv_sim.plant.cylinder"), p=p, f=(np.zeros(1),), workspace=1,
        stops=(Stop(0, 1, float(p[X_MIN]), float(p[X_MAX])),),
    )
