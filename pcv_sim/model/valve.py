"""The complete valve: solenoid + spool + orifices + flow forces + load volume (+ damping chamber).

`ValveModel` turns `ValveParams` into the right-hand side of the paper's equations:

- full model (Sec. 4.2): state (lambda, x, v, p, p_c), with the damping chamber (Eqs. 28-29);
- simplified model (Sec. 4.3): state (lambda, x, v, p), p_c = p, the chamber replaced by the
  damping coefficient B_simplified.

States in SI: lambda (Wb), x (m, + opens pump -> load), v (m/s), p and p_c (Pa). Inputs: duty
D (0..1), load flow q_l (m^3/s, + drawn from the load port: reducing; - pushed into it:
relieving), supply pressure p_s (Pa). The right-hand side is a pure function of
(t, state, inputs); integrators live in `pcv_sim.simulation`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

from pcv_sim.model import flow_force as ff
from pcv_sim.model import orifice as orf
from pcv_sim.model import solenoid as sol
from pcv_sim.params import ValveParams
from pcv_sim.units import MM_PER_M, to_fit_mm

__all__ = ["ValveModel", "Hydraulics", "ModelKind", "STATE_NAMES"]

ModelKind = Literal["simplified", "full"]
STATE_NAMES = {
    "simplified": ("flux_linkage", "spool_position", "spool_velocity", "pressure"),
    "full": ("flux_linkage", "spool_position", "spool_velocity", "pressure", "chamber_pressure"),
}


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
    """The paper's equations for one parameter set. Cheap to call: constants are unpacked once."""

    def __init__(self, params: ValveParams, kind: ModelKind = "simplified") -> None:
        if kind not in ("simplified", "full"):
            raise ValueError(f"model kind {kind!r}: accepted are 'simplified' and 'full'")
        self.params = params
        self.kind: ModelKind = kind
        s, o, f = params.solenoid, params.orifice, params.fits
        self.f1, self.f2, self.f3 = s.restoring_f1, s.restoring_f2, s.restoring_f3
        self.pd = s.dissipating
        self.force_map = s.force
        self.core_offset_mm = s.core_offset_mm
        self.resistance = s.coil_resistance
        self.v_supply = s.supply_voltage
        self.switched = s.pwm == "switched"
        self.pwm_period = 1.0 / s.pwm_frequency
        sp = params.spool
        self.mass = sp.mass
        self.a_c, self.a_cc = sp.pressure_area, params.chamber_area
        self.a_net = params.net_area
        self.k_spring, self.f0 = sp.spring_stiffness, sp.spring_preload
        self.damping = sp.viscous_friction if kind == "full" else params.simplified_damping
        self.x_min, self.x_max = sp.stroke_min_mm / MM_PER_M, sp.stroke_max_mm / MM_PER_M
        self.r, self.n_holes, self.h_gap = o.hole_radius, o.hole_count, o.gap_height
        self.r_pilot, self.tank_offset = o.tank_pilot_hole_radius, o.tank_hole_offset
        self.blend_k = o.blend_steepness_per_mm
        # Wetted perimeter of the pump-side leakage slots (Eq. 18, reading R5): n rectangles 2r x h.
        self.gap_perimeter = self.n_holes * 2.0 * (2.0 * self.r + self.h_gap)
        self.fit = f
        self.rho = params.fluid.density
        self.beta = params.fluid.bulk_modulus
        self.nu = params.fluid.kinematic_viscosity
        self.volume = params.circuit.load_volume
        self.p_tank = params.circuit.tank_pressure
        self.p_supply = params.circuit.supply_pressure
        self.k_d = params.damping.restrictor_conductance
        self.v_c = params.damping.chamber_volume

    # --- building blocks ---------------------------------------------------------------------

    def core_mm(self, x: float) -> float:
        """Reading R2: core position of the solenoid fits (mm) = spool x (mm) + core offset."""
        return to_fit_mm(x) + self.core_offset_mm

    def coil_voltage(self, duty: float, t: float) -> float:
        """V_s (V): the PWM average D * V (reading R15) or the switched 200 Hz waveform."""
        if self.switched:
            return self.v_supply if (t % self.pwm_period) < duty * self.pwm_period else 0.0
        return duty * self.v_supply

    def steady_current(self, duty: float) -> float:
        """Steady-state coil current (A): V_L = 0 in Eq. 1, so i = D V / R."""
        return duty * self.v_supply / self.resistance

    def restoring(self, x: float) -> tuple[float, float, float]:
        """Eqs. 5-7 at the spool position x (m)."""
        return sol.restoring_coefficients(self.core_mm(x), self.f1, self.f2, self.f3)

    def current(self, lam: float, x: float, v_s: float, i_guess: float) -> float:
        """Eqs. 1-8: the coil current for flux linkage lam at spool x and coil voltage v_s."""
        c1, c2, c3 = self.restoring(x)
        return sol.solve_current(sol.restoring_current(lam, c1, c2, c3), v_s, self.resistance, self.pd, i_guess)

    def solenoid_force(self, i: float, x: float) -> float:
        """Eqs. 9-13: N, toward +x."""
        return sol.solenoid_force(i, self.core_mm(x), self.force_map)

    def flux_linkage_at_rest(self, i: float, x: float) -> float:
        """Steady-state lambda for current i at spool x."""
        return sol.flux_linkage_at_rest(i, *self.restoring(x), self.pd)

    def hydraulics(self, x: float, p: float, p_s: float) -> Hydraulics:
        """Eqs. 16-27 and 30-32 at spool x (m), load pressure p and supply pressure p_s (Pa)."""
        x_mm = to_fit_mm(x)
        fit, rho = self.fit, self.rho
        # Pump side: gap leakage and holes blended by the logistic (Eqs. 17-23, 26-27).
        dp_p = p_s - p
        a_p = orf.pump_area(x, self.r, self.n_holes, self.h_gap)
        weight = orf.blend(x_mm, self.blend_k)
        cq_gap = orf.gap_discharge_coefficient(
            orf.gap_geometry_factor(x_mm, fit.gap_geometry), a_p, self.gap_perimeter, self.nu, rho, dp_p
        )
        if weight > 1e-15:
            g = orf.hole_geometry_factor(x_mm, fit.hole_geometry)
            cq_hole = orf.hole_discharge_coefficient(g, orf.transition_exponent(x_mm, fit.hole_exponent), dp_p)
        else:  # far inside the gap region the hole term carries no weight: skip its cost
            cq_hole = 0.0
        cq_p = orf.pump_discharge_coefficient(cq_gap, cq_hole, weight)
        q_p = orf.orifice_flow(cq_p, a_p, dp_p, rho)
        f_p = ff.flow_force(cq_p, a_p, dp_p, ff.jet_cosine(x_mm, fit.pump_jet, fit.pump_jet_cap))
        # Tank side: fits in the opening |x| for x < 0; for x >= 0 frozen at the closing edge (R22).
        dp_t = p - self.p_tank
        s_mm = -x_mm if x_mm < 0.0 else 0.0
        a_t = orf.tank_area(x, self.r, self.n_holes, self.h_gap, self.r_pilot, self.tank_offset)
        cq_t = orf.tank_discharge_coefficient(
            orf.tank_geometry_factor(s_mm, fit.tank_geometry),
            orf.transition_exponent(s_mm, fit.tank_exponent),
            dp_t,
        )
        q_t = orf.orifice_flow(cq_t, a_t, dp_t, rho)
        f_t = ff.flow_force(cq_t, a_t, dp_t, ff.jet_cosine(s_mm, fit.tank_jet, fit.tank_jet_cap))
        return Hydraulics(q_p, q_t, f_p, f_t)

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
        return self.spool_force(i, x, 0.0, p, p, self.hydraulics(x, p, p_s))

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
        """d(state)/dt and the coil current. Eqs. 1-3 (solenoid), 14 (spool), 15 + 29 (continuity).

        Continuity (reading R13): the spool's motion displaces the load side by A_c v and the
        chamber by A_cc v. Simplified model: the chamber is rigid and lossless, its flow A_cc v
        comes from the load volume, so the load side sees (A_c - A_cc) v.
        The end stops (Sec. 4.2) are inelastic: at a stop with the force pushing into it, the
        spool stays (see `at_stop`); integrators also project x and v back.
        """
        lam, x, v, p = state[0], state[1], state[2], state[3]
        v_s = self.coil_voltage(duty, t)
        i = self.current(lam, x, v_s, i_guess)
        hyd = self.hydraulics(x, p, supply_pressure)
        c = self.beta / self.volume
        if self.kind == "full":
            p_c = state[4]
            q_c = self.k_d * (p - p_c)                               # Eq. 28
            force = self.spool_force(i, x, v, p, p_c, hyd)
            dpc = self.beta / self.v_c * (q_c - self.a_cc * v)         # Eq. 29
            dp = c * (hyd.valve_flow - q_c - load_flow + self.a_c * v)  # Eq. 15
        else:
            force = self.spool_force(i, x, v, p, p, hyd)
            dp = c * (hyd.valve_flow - load_flow + self.a_net * v)     # Eq. 15, p_c = p
        dx, dv = self.stop_motion(x, v, force)
        dlam = sol.flux_linkage_derivative(v_s, i, self.resistance)  # Eq. 3
        if self.kind == "full":
            return (dlam, dx, dv, dp, dpc), i
        return (dlam, dx, dv, dp), i

    def stop_motion(self, x: float, v: float, force: float) -> tuple[float, float]:
        """Eq. 14 with inelastic end stops: (dx/dt, dv/dt)."""
        if (x <= self.x_min and v <= 0.0 and force <= 0.0) or (x >= self.x_max and v >= 0.0 and force >= 0.0):
            return 0.0, 0.0
        return v, force / self.mass

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
        return base + (p,) if self.kind == "full" else base

    @property
    def state_names(self) -> tuple[str, ...]:
        return STATE_NAMES[self.kind]

    def finite(self, state: tuple[float, ...]) -> bool:
        return all(math.isfinite(s) for s in state)
