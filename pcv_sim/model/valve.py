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
from typing import Callable, Literal

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
        self.v_range = sol.dissipating_range(self.pd)
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
        self._edges = self._make_edges()
        self._derivatives = self._make_derivatives()
        self.derivatives = self._derivatives  # type: ignore[method-assign] - skip one call layer

    # --- building blocks ---------------------------------------------------------------------

    def core_mm(self, x: float) -> float:
        """Reading R2: core position of the solenoid fits (mm) = spool x (mm) + core offset."""
        return to_fit_mm(x) + self.core_offset_mm

    def coil_voltage(self, duty: float, t: float) -> float:
        """V_s (V): the PWM average D * V (reading R15) or the switched 200 Hz waveform."""
        if self.switched:
            # Phase in periods; edges fall on sample instants, so round away float noise there.
            phase = t / self.pwm_period
            phase -= math.floor(phase + 1e-9)
            return self.v_supply if phase < duty - 1e-9 else 0.0
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
        return sol.solve_current(
            sol.restoring_current(lam, c1, c2, c3), v_s, self.resistance, self.pd, i_guess, self.v_range
        )

    def solenoid_force(self, i: float, x: float) -> float:
        """Eqs. 9-13: N, toward +x."""
        return sol.solenoid_force(i, self.core_mm(x), self.force_map)

    def flux_linkage_at_rest(self, i: float, x: float) -> float:
        """Steady-state lambda for current i at spool x."""
        return sol.flux_linkage_at_rest(i, *self.restoring(x), self.pd)

    def hydraulics(self, x: float, p: float, p_s: float) -> Hydraulics:
        """Eqs. 16-27 and 30-32 at spool x (m), load pressure p and supply pressure p_s (Pa)."""
        return Hydraulics(*self._edges(x, to_fit_mm(x), p, p_s))

    def _make_edges(self) -> Callable[[float, float, float, float], tuple[float, float, float, float]]:
        """The body of `hydraulics` as a closure over the constants (it runs twice per 0.1 ms step)."""
        fit, rho, nu = self.fit, self.rho, self.nu
        r, n, h, r_pilot, offset = self.r, self.n_holes, self.h_gap, self.r_pilot, self.tank_offset
        perimeter, k_blend, p_tank = self.gap_perimeter, self.blend_k, self.p_tank
        gg, hg, he = fit.gap_geometry, fit.hole_geometry, fit.hole_exponent
        tg, te = fit.tank_geometry, fit.tank_exponent
        pj, pcap, tj, tcap = fit.pump_jet, fit.pump_jet_cap, fit.tank_jet, fit.tank_jet_cap
        pump_area, tank_area, blend = orf.pump_area, orf.tank_area, orf.blend
        gap_factor, gap_cq = orf.gap_geometry_factor, orf.gap_discharge_coefficient
        hole_factor, exponent, hole_cq = orf.hole_geometry_factor, orf.transition_exponent, orf.hole_discharge_coefficient
        pump_cq, tank_factor, tank_cq = orf.pump_discharge_coefficient, orf.tank_geometry_factor, orf.tank_discharge_coefficient
        flow, force, jet = orf.orifice_flow, ff.flow_force, ff.jet_cosine
        # The tank edge's fits at its closing point, which hold for all x >= 0 (R22).
        g_closed, gamma_closed, cos_closed = tank_factor(0.0, tg), exponent(0.0, te), jet(0.0, tj, tcap)
        a_closed = tank_area(0.0, r, n, h, r_pilot, offset)

        def edges(x: float, x_mm: float, p: float, p_s: float) -> tuple[float, float, float, float]:
            """(pump flow, tank flow, pump flow force, tank flow force); x in m and in mm."""
            # Pump side: gap leakage and holes blended by the logistic (Eqs. 17-23, 26-27).
            dp_p = p_s - p
            a_p = pump_area(x, r, n, h)
            weight = blend(x_mm, k_blend)
            cq_p = gap_cq(gap_factor(x_mm, gg), a_p, perimeter, nu, rho, dp_p)
            if weight > 1e-15:  # far inside the gap region the hole term carries no weight: skip its cost
                cq_p = pump_cq(cq_p, hole_cq(hole_factor(x_mm, hg), exponent(x_mm, he), dp_p), weight)
            q_p = flow(cq_p, a_p, dp_p, rho)
            f_p = force(cq_p, a_p, dp_p, jet(x_mm, pj, pcap))
            # Tank side: fits in the opening |x| for x < 0; for x >= 0 frozen at the closing edge (R22).
            dp_t = p - p_tank
            if x_mm < 0.0:
                a_t = tank_area(x, r, n, h, r_pilot, offset)
                cq_t = tank_cq(tank_factor(-x_mm, tg), exponent(-x_mm, te), dp_t)
                cos_t = jet(-x_mm, tj, tcap)
            else:
                cq_t, cos_t = tank_cq(g_closed, gamma_closed, dp_t), cos_closed
                a_t = a_closed
            q_t = flow(cq_t, a_t, dp_t, rho)
            f_t = force(cq_t, a_t, dp_t, cos_t)
            return q_p, q_t, f_p, f_t

        return edges

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

    def _make_derivatives(self) -> Callable[..., tuple[tuple[float, ...], float]]:
        """`derivatives` as a closure over the constants: the hot path of every integrator."""
        edges, full, switched = self._edges, self.kind == "full", self.switched
        f1, f2, f3, fmap, pd, v_range = self.f1, self.f2, self.f3, self.force_map, self.pd, self.v_range
        offset, resistance, v_supply, coil_voltage = self.core_offset_mm, self.resistance, self.v_supply, self.coil_voltage
        a_c, a_cc, a_net, k_spring, f0, damping = self.a_c, self.a_cc, self.a_net, self.k_spring, self.f0, self.damping
        c_load, c_chamber, k_d = self.beta / self.volume, self.beta / self.v_c, self.k_d
        x_min, x_max, mass = self.x_min, self.x_max, self.mass
        coefficients_at, restoring_current = sol.coefficients_at, sol.restoring_current
        solve_current, force_from, dlam_dt = sol.solve_current, sol.force_from_coefficients, sol.flux_linkage_derivative

        def derivatives(
            t: float, state: tuple[float, ...], duty: float, load_flow: float, supply_pressure: float, i_guess: float
        ) -> tuple[tuple[float, ...], float]:
            lam, x, v, p = state[0], state[1], state[2], state[3]
            v_s = coil_voltage(duty, t) if switched else duty * v_supply
            x_mm = to_fit_mm(x)
            c1, c2, c3, k1, k2, k3, k4 = coefficients_at(x_mm + offset, f1, f2, f3, fmap)
            i = solve_current(restoring_current(lam, c1, c2, c3), v_s, resistance, pd, i_guess, v_range)  # Eqs. 1-8
            q_p, q_t, f_p, f_t = edges(x, x_mm, p, supply_pressure)
            # Eq. 14 without the chamber and damping terms, which differ per variant.
            force = force_from(i, k1, k2, k3, k4) - a_c * p - k_spring * x - (f_p - f_t) - f0
            dlam = dlam_dt(v_s, i, resistance)                                                   # Eq. 3
            if full:
                p_c = state[4]
                q_c = k_d * (p - p_c)                                                            # Eq. 28
                force += a_cc * p_c - damping * v                                                # Eq. 14
                dpc = c_chamber * (q_c - a_cc * v)                                               # Eq. 29
                dp = c_load * (q_p - q_t - q_c - load_flow + a_c * v)                            # Eq. 15
            else:
                force += a_cc * p - damping * v                                                  # Eq. 14, p_c = p
                dp = c_load * (q_p - q_t - load_flow + a_net * v)                                # Eq. 15
            # Inelastic end stops (Sec. 4.2): held while the force pushes into the stop.
            if (x <= x_min and v <= 0.0 and force <= 0.0) or (x >= x_max and v >= 0.0 and force >= 0.0):
                dx = dv = 0.0
            else:
                dx, dv = v, force / mass
            if full:
                return (dlam, dx, dv, dp, dpc), i
            return (dlam, dx, dv, dp), i

        derivatives.__doc__ = ValveModel.derivatives.__doc__
        return derivatives

    def derivatives(
        self,
        t: float,
        state: tuple[float, ...],
        duty: float,
        load_flow: float,
        supply_pressure: float,
        i_guess: float,
    ) -> tuple[tuple[float, ...], float]:
        """d(state)/dt and the coil current. Eqs. 1-3 (solenoid), 14 (spool), 15 + 28-29 (continuity).

        Continuity (reading R13): the spool's motion displaces the load side by A_c v and the
        chamber by A_cc v. Simplified model: the chamber is rigid and lossless, its flow A_cc v
        comes from the load volume, so the load side sees (A_c - A_cc) v.
        The end stops (Sec. 4.2) are inelastic: at a stop with the force pushing into it, the
        spool stays; integrators also project x and v back (`project`).
        (Replaced per instance by the closure from `_make_derivatives`; same equations.)
        """
        return self._derivatives(t, state, duty, load_flow, supply_pressure, i_guess)

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
