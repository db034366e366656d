"""The complete valve: solenoid + spool + orifices + flow forces + load volume (+ damping chamber).

`ValveModel` turns `ValveParams` into the right-hand side of the paper's equations:

- full model (Sec. 4.2): state (lambda, x, v, p, p_c), with the damping chamber (Eqs. 28-29);
- simplified model (Sec. 4.3): state (lambda, x, v, p), p_c = p, the chamber replaced by the
  damping coefficient B_simplified.

States in SI: lambda (Wb), x (m, + opens pump -> load), v (m/s), p and p_c (Pa). Inputs: duty
D (0..1), load flow q_l (m^3/s, + drawn from the load port: reducing; - pushed into it:
relieving), supply pressure p_s (Pa). The right-hand side is a pure function of
(t, state, inputs); integrators live in `pcv_sim.simulation`. The equations themselves are in
`pcv_sim.model.kernel` (one source, compiled for the simulation core); this class serves them to
the analysis one state at a time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from pcv_sim.model import kernel
from pcv_sim.model import solenoid as sol
from pcv_sim.params import ValveParams
from pcv_sim.units import MM_PER_M, to_fit_mm

__all__ = ["STATE_NAMES", "Hydraulics", "ModelKind", "ValveModel"]

ModelKind = Literal["simplified", "full"]
STATE_NAMES = kernel.STATES


@dataclass(frozen=True)
class Hydraulics:
    """Flows (m^3/s) and forces (N) of the metering edges at one (x, p, p_s)."""

    pump_flow: float       # q through the pump-side orifice, + pump -> load
    tank_flow: float       # q through the tank-side orifice, + load -> tank
    pump_force: float      # Eq. 30 at the pump side, >= 0, acts toward -x
    tank_force: float      # Eq. 30 at the tank side, >= 0, acts toward +x

    @property
    def valve_flow(self) -> float:
        """q_v of Eq. 15: net flow into the load volume through the valve."""
        return self.pump_flow - self.tank_flow

    @property
    def flow_force(self) -> float:
        """F_f of Eq. 14, + toward -x."""
        return self.pump_force - self.tank_force


class ValveModel:
    """The paper's equations for one parameter set, for analysis (scalars in, scalars out).

    A thin layer over `pcv_sim.model.kernel`, the one source of the equations that the compiled
    simulation core runs too: the parameters are packed once into the kernel's vector and tables.
    """

    def __init__(self, params: ValveParams, kind: ModelKind = "simplified") -> None:
        if kind not in ("simplified", "full"):
            raise ValueError(f"model kind {kind!r}: accepted are 'simplified' and 'full'")
        self.params = params
        self.kind: ModelKind = kind
        self.p, self.f = kernel.pack(params, kind)
        self._rhs = getattr(kernel, kernel.functions(params)[0])     # the paper's, or with the options
        s = params.solenoid
        self.f1, self.f2, self.f3 = self.f[kernel.T_F1], self.f[kernel.T_F2], self.f[kernel.T_F3]
        self.pd = s.dissipating
        self.v_range = sol.dissipating_range(self.pd)
        self.force_map = s.force
        self.core_offset_mm = s.core_offset_mm
        # With coil heating (R33): the resistance of a coil at the ambient temperature (a rest state's).
        self.resistance = (s.coil_resistance if not s.coil_thermal else s.coil_resistance * (
            1.0 + s.coil_temperature_coefficient * (s.ambient_temperature_c - s.coil_reference_temperature_c)))
        self.v_supply = s.supply_voltage
        self.switched = s.pwm == "switched"
        self.pwm_period = 1.0 / s.pwm_frequency
        sp = params.spool
        self.mass = sp.mass
        self.a_c, self.a_cc = sp.pressure_area, params.chamber_area
        self.a_net = params.net_area
        self.k_spring, self.f0 = sp.spring_stiffness, sp.spring_preload
        self.damping = float(self.p[kernel.DAMPING])
        self.x_min, self.x_max = sp.stroke_min_mm / MM_PER_M, sp.stroke_max_mm / MM_PER_M
        self.rho = params.fluid.density
        self.beta = params.fluid.bulk_modulus
        self.nu = params.fluid.kinematic_viscosity
        self.volume = params.circuit.load_volume
        self.p_tank = params.circuit.tank_pressure
        self.p_supply = params.circuit.supply_pressure
        self.gap_perimeter = float(self.p[kernel.GAP_PERIMETER])   # Eq. 18's O (reading R5)
        self.k_d = params.damping.restrictor_conductance
        self.v_c = params.damping.chamber_volume
        self.layout = kernel.layout(params, kind)
        n = len(self.layout.states)
        self._x, self._w, self._dx = np.zeros(n), np.zeros(1), np.zeros(n)
        self._u = np.array((*[0.0] * len(kernel.INPUTS), *kernel.option_inputs(params)))

    # --- building blocks ---------------------------------------------------------------------

    def core_mm(self, x: float) -> float:
        """Reading R2: core position of the solenoid fits (mm) = spool x (mm) + core offset."""
        return to_fit_mm(x) + self.core_offset_mm

    def coil_voltage(self, duty: float, t: float) -> float:
        """V_s (V): the PWM average D * V (reading R15) or the switched 200 Hz waveform."""
        return float(kernel.coil_voltage(duty, t, self.p))

    def steady_current(self, duty: float) -> float:
        """Steady-state coil current (A): V_L = 0 in Eq. 1, so i = D V / R."""
        return duty * self.v_supply / self.resistance

    def restoring(self, x: float) -> tuple[float, float, float]:
        """Eqs. 5-7 at the spool position x (m)."""
        return sol.restoring_coefficients(self.core_mm(x), self.f1, self.f2, self.f3)

    def current(self, lam: float, x: float, v_s: float, i_guess: float) -> float:
        """Eqs. 1-8: the coil current for flux linkage lam at spool x and coil voltage v_s."""
        return float(kernel.coil_current(lam, x, v_s, i_guess, self.p, self.f))

    def solenoid_force(self, i: float, x: float) -> float:
        """Eqs. 9-13: N, toward +x."""
        return sol.solenoid_force(i, self.core_mm(x), self.force_map)

    def flux_linkage_at_rest(self, i: float, x: float) -> float:
        """Steady-state lambda for current i at spool x (the core on the spool)."""
        return sol.flux_linkage_at_rest(i, *self.restoring(x), self.pd)

    def hydraulics(self, x: float, p: float, p_s: float) -> Hydraulics:
        """Eqs. 16-27 and 30-32 at spool x (m), load pressure p and supply pressure p_s (Pa)."""
        return Hydraulics(*kernel.edges(x, to_fit_mm(x), p, p_s, self.p, self.f))

    def spool_force(self, i: float, x: float, v: float, p: float, p_c: float, hyd: Hydraulics) -> float:
        """Eq. 14, right-hand side: net force on the moving parts (N), + toward +x."""
        return (
            self.solenoid_force(i, x)
            - self.a_c * p
            + self.a_cc * p_c
            - self.k_spring * x
            - self.damping * v
            - hyd.flow_force
            - self.f0
        )

    def static_force(self, i: float, x: float, p: float, p_s: float) -> float:
        """Eq. 14 at rest (v = 0, p_c = p): the force balance the static characteristic solves."""
        return float(kernel.static_force(i, x, p, p_s, self.p, self.f))

    # --- the right-hand side -----------------------------------------------------------------

    def derivatives(
        self,
        t: float,
        state: tuple[float, ...],
        duty: float,
        load_flow: float,
        supply_pressure: float,
        i_guess: float,
    ) -> tuple[tuple[float, ...], float]:
        """d(state)/dt and the coil current: `pcv_sim.model.kernel.rhs` (or `rhs_options`) (Eqs. 1-3, 14, 15, 28-29)
        for one state given as a tuple, as the analysis and the stiff reference use it."""
        x, u, w, dx = self._x, self._u, self._w, self._dx
        x[:] = state
        u[kernel.U_DUTY], u[kernel.U_LOAD_FLOW], u[kernel.U_SUPPLY_PRESSURE] = duty, load_flow, supply_pressure
        u[kernel.U_LOAD_VOLUME] = self.params.circuit.load_volume      # a single valve: the configured load volume
        w[0] = i_guess
        self._rhs(t, x, u, self.p, self.f, w, dx)
        return tuple(float(v) for v in dx), float(w[0])

    def project(self, x: float, v: float) -> tuple[float, float]:
        """Keep (x, v) inside the stroke: an inelastic impact at a stop."""
        if x < self.x_min:
            return self.x_min, (v if v > 0.0 else 0.0)
        if x > self.x_max:
            return self.x_max, (v if v < 0.0 else 0.0)
        return x, v

    def initial_state(self, duty: float, x: float, p: float) -> tuple[float, ...]:
        """A state at rest: steady flux linkage for D's current at x, chamber pressure = p."""
        lam = self.flux_linkage_at_rest(self.steady_current(duty), x)
        base = (lam, x, 0.0, p)
        return (*base, p, *kernel.option_states(self.params, x)) if self.kind == "full" else (
            *base, *kernel.option_states(self.params, x))

    @property
    def state_names(self) -> tuple[str, ...]:
        return self.layout.states

    def finite(self, state: tuple[float, ...]) -> bool:
        return all(math.isfinite(s) for s in state)
