"""The valve's equations over arrays: the one source that the compiled core and the analysis run.

A valve is described to the kernel by a parameter vector `p` (floats, SI, at the indices below)
and a tuple of tables `f` (the paper's curve fits), both made by `pack` from `ValveParams`.
State, inputs and outputs are float arrays (SI units):

    x  simplified (Sec. 4.3): lambda (Wb), x (m), v (m/s), p (Pa)
       full (Sec. 4.2):       lambda, x, v, p, p_c (Pa): with the damping chamber
    u  duty (0..1), load flow q_l (m^3/s, + drawn from the load port), supply pressure p_s (Pa),
       load volume V (m^3): the oil volume at the load port (Eq. 15's V; a single valve is fed
       `circuit.load_volume`, a valve on a cylinder the chamber's volume V0 + A x + hose)
    y  pressure (Pa), current (A), spool position (m)
    w  workspace: the last coil current (A), the Newton start of the next Eq. 2 solve

Options beyond the paper's bench (docs/model.md R33-R35), each off by default and then absent
from the layout (the paper's model, bit for bit), each appending to it when on (`layout`). A
valve with any option on runs its own functions (`rhs_options`, ...; `functions` names them):
numba compiles a function with everything it inlines, so the paper's valve, compiled alone,
compiles none of the options' code (the first start's compile stays the paper's).

    coil heating (R33)      state coil_temperature (K); input ambient_temperature (K);
                            outputs coil_temperature (K), coil_resistance (ohm)
    oil temperature (R34)   input oil_temperature (K)
    core separation (R35)   states core_position (m), core_velocity (m/s); output core_position

Every function here is compiled by `pcv_sim.jit` (or runs as Python); the equation functions it
calls (`solenoid`, `orifice`, `flow_force`) are compiled the same way. Each line names its
equation; the readings of the printed text are in docs/model.md.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from pcv_sim.jit import jit
from pcv_sim.model import flow_force as ff
from pcv_sim.model import orifice as orf
from pcv_sim.model import solenoid as sol
from pcv_sim.model import stops
from pcv_sim.params import ValveParams
from pcv_sim.units import CST_PER_M2S, MM_PER_M, kelvin

__all__ = [
    "INPUTS",
    "OUTPUTS",
    "STATES",
    "STATE_OUTPUTS",
    "U_DUTY",
    "U_LOAD_FLOW",
    "U_LOAD_VOLUME",
    "U_SUPPLY_PRESSURE",
    "Y_CURRENT",
    "Y_PRESSURE",
    "Y_SPOOL_POSITION",
    "Layout",
    "chamber_rate",
    "coil_current",
    "coil_current_in",
    "coil_resistance",
    "core_position",
    "edges",
    "edges_in",
    "functions",
    "layout",
    "oil_properties",
    "option_inputs",
    "option_states",
    "output",
    "output_options",
    "pack",
    "project",
    "project_options",
    "rhs",
    "rhs_options",
    "spool_rate",
    "state_output",
    "state_output_options",
    "static_force",
]

STATES = {
    "simplified": ("flux_linkage", "spool_position", "spool_velocity", "pressure"),
    "full": ("flux_linkage", "spool_position", "spool_velocity", "pressure", "chamber_pressure"),
}
INPUTS = ("duty_cycle", "load_flow", "supply_pressure", "load_volume")
OUTPUTS = ("pressure", "current", "spool_position")
#: Where each input sits in u and each output in y (the order of INPUTS, OUTPUTS): the kernels'
#: indices, constants to numba (a name costs nothing in the compiled step). The options' inputs
#: and outputs follow, at the indices `pack` puts into p (IU_AMBIENT, IY_COIL_T, ...).
U_DUTY, U_LOAD_FLOW, U_SUPPLY_PRESSURE, U_LOAD_VOLUME = range(len(INPUTS))
Y_PRESSURE, Y_CURRENT, Y_SPOOL_POSITION = range(len(OUTPUTS))
#: Outputs that depend on the state alone (no direct feedthrough): the ones a composition may
#: route into another system's input. The current is algebraic in the coil voltage (Eq. 2).
STATE_OUTPUTS = ("pressure", "spool_position")

# --- the parameter vector p -----------------------------------------------------------------
R_COIL, V_SUPPLY, CORE_OFFSET_MM, V_LO, V_HI, SWITCHED, PWM_PERIOD = 0, 1, 2, 3, 4, 5, 6
MASS, A_C, A_CC, A_NET, K_SPRING, F0, DAMPING, X_MIN, X_MAX = 7, 8, 9, 10, 11, 12, 13, 14, 15
R_HOLE, N_HOLES, H_GAP, R_PILOT, TANK_OFFSET, BLEND_K, GAP_PERIMETER = 16, 17, 18, 19, 20, 21, 22
RHO, BETA, NU, VOLUME, P_TANK, K_D, V_C, FULL = 23, 24, 25, 26, 27, 28, 29, 30
PUMP_JET_CAP, TANK_JET_CAP, G_CLOSED, GAMMA_CLOSED, COS_CLOSED, A_CLOSED = 31, 32, 33, 34, 35, 36
# Faults (a healthy valve: 1, 1, 0, 1e-3, 0, 0; each is a no-op at its healthy value, so the healthy
# model's arithmetic is untouched). R_COIL above carries a partial short (a lower resistance).
#   VOLTAGE_FACTOR  coil voltage factor: 0 = open circuit (no drive; the flux decays through R)
#   AREA_FACTOR     both metering edges' flow and flow force scaled (contamination: < 1)
#   SPOOL_FRICTION  extra Coulomb friction on the spool (N), smoothed over SPOOL_FRICTION_V (m/s)
#   STUCK           1 = the spool is held where it is (seized)
#   LEAK            internal leakage load -> tank, laminar conductance (m^3/(s Pa))
VOLTAGE_FACTOR, AREA_FACTOR, SPOOL_FRICTION, SPOOL_FRICTION_V, STUCK, LEAK = 37, 38, 39, 40, 41, 42
P_CAVITATION = 43           # Pa gauge: the load pressure's floor (reading R32)
# Coil heating (R33): flag, copper's alpha (1/K), T_ref (K) at which R_COIL holds, R_th (K/W),
# C_th (J/K); where its state and input sit in x and u, and its outputs in y.
THERMAL, ALPHA_CU, T_REF_COIL, R_TH, C_TH, IX_COIL_T, IU_AMBIENT, IY_COIL_T = 44, 45, 46, 47, 48, 49, 50, 51
# Oil temperature (R34): flag, where its input sits, T_ref (K) at which RHO, BETA, NU, K_D and
# DAMPING hold, Walther's A and B (log10 log10(nu_cSt + 0.7) = A - B log10 T), the thermal
# expansion (1/K) and the bulk modulus' relative fall (1/K).
OIL, IU_OIL, T_REF_OIL, WALTHER_A, WALTHER_B, EXPANSION, BETA_SLOPE = 52, 53, 54, 55, 56, 57, 58
# Core-spool separation (R35): flag, core mass (kg), core damping (Ns/m), the core's stop (m),
# where its states sit in x and its output in y.
SEPARATION, M_CORE, B_CORE, XC_MIN, IX_CORE, IY_CORE = 59, 60, 61, 62, 63, 64
# 1 when any option is on: the valve then runs the `*_options` functions (`functions`), the
# paper's valve `rhs`, `output`, ... which hold none of the options' code (bit for bit, and numba
# compiles only the path a valve runs).
OPTIONS = 65
# The spool's damping pole D(T) / m (1/s) at the oil's temperature (R34), with the core attached:
# the exponential integrator takes the spool velocity's linear decay exactly at this rate
# (`spool_rate`; 0: the velocity is integrated explicitly, as in the paper's valve).
V_RATE = 66
N_PARAMS = 67

# --- the tables f ---------------------------------------------------------------------------
T_F1, T_F2, T_F3, T_PD, T_FORCE, T_GAP, T_HOLE, T_HOLE_EXP, T_TANK, T_TANK_EXP, T_PUMP_JET, T_TANK_JET = range(12)


class Layout(NamedTuple):
    """The signal names of a valve with its options: the paper's first, the options' appended."""

    states: tuple[str, ...]
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    state_outputs: tuple[str, ...]


def layout(params: ValveParams, kind: str) -> Layout:
    """States, inputs and outputs of the valve `kind` with the options `params` switches on."""
    if kind not in STATES:
        raise ValueError(f"model kind {kind!r}: accepted are 'simplified' and 'full'")
    states: tuple[str, ...] = STATES[kind]
    inputs: tuple[str, ...] = INPUTS
    outputs: tuple[str, ...] = OUTPUTS
    state_outputs: tuple[str, ...] = STATE_OUTPUTS
    if params.solenoid.coil_thermal:
        states += ("coil_temperature",)
        inputs += ("ambient_temperature",)
        outputs += ("coil_temperature", "coil_resistance")
        state_outputs += ("coil_temperature", "coil_resistance")
    if params.fluid.oil_temperature_model:
        inputs += ("oil_temperature",)
    if params.spool.core_separation:
        states += ("core_position", "core_velocity")
        outputs += ("core_position",)
        state_outputs += ("core_position",)
    return Layout(states, inputs, outputs, state_outputs)


def functions(params: ValveParams) -> tuple[str, str, str, str]:
    """The names of the kernel functions (rhs, state_output, output, project) a valve with these
    options runs: the paper's, or with any option on the `*_options` ones."""
    if params.solenoid.coil_thermal or params.fluid.oil_temperature_model or params.spool.core_separation:
        return "rhs_options", "state_output_options", "output_options", "project_options"
    return "rhs", "state_output", "output", "project"


def option_inputs(params: ValveParams) -> tuple[float, ...]:
    """The options' inputs at their configured values (K), in the layout's order: what a single
    valve is fed where nothing else feeds them."""
    out: tuple[float, ...] = ()
    if params.solenoid.coil_thermal:
        out += (kelvin(params.solenoid.ambient_temperature_c),)
    if params.fluid.oil_temperature_model:
        out += (kelvin(params.fluid.oil_temperature_c),)
    return out


def option_states(params: ValveParams, x: float) -> tuple[float, ...]:
    """The options' states at rest with the spool at x (m): the coil at the ambient temperature
    (a coil just switched on), the core on the spool at rest."""
    out: tuple[float, ...] = ()
    if params.solenoid.coil_thermal:
        out += (kelvin(params.solenoid.ambient_temperature_c),)
    if params.spool.core_separation:
        out += (x, 0.0)
    return out


def _walther(params: ValveParams) -> tuple[float, float]:
    """(A, B) of Walther's relation (ASTM D341) through the oil's two reference points."""
    fl = params.fluid
    t1, t2 = kelvin(fl.reference_temperature_c), kelvin(fl.second_viscosity_temperature_c)
    z1 = math.log10(math.log10(fl.kinematic_viscosity * CST_PER_M2S + 0.7))
    z2 = math.log10(math.log10(fl.second_viscosity * CST_PER_M2S + 0.7))
    b = (z1 - z2) / (math.log10(t2) - math.log10(t1))
    return z1 + b * math.log10(t1), b


def pack(params: ValveParams, kind: str) -> tuple[np.ndarray, tuple[np.ndarray, ...]]:
    """(p, f) of a valve for the kernel: `kind` is 'simplified' or 'full'."""
    if kind not in STATES:
        raise ValueError(f"model kind {kind!r}: accepted are 'simplified' and 'full'")
    s, o, fit, sp = params.solenoid, params.orifice, params.fits, params.spool
    v_lo, v_hi = sol.dissipating_range(s.dissipating)
    arr = np.ascontiguousarray

    def table(rows: tuple[tuple[float, ...], ...]) -> np.ndarray:
        return arr(np.array(rows, dtype=np.float64))

    f = (
        arr(np.array(s.restoring_f1, float)), arr(np.array(s.restoring_f2, float)),
        arr(np.array(s.restoring_f3, float)), arr(np.array(s.dissipating, float)), table(s.force),
        arr(np.array(fit.gap_geometry, float)), table(fit.hole_geometry), arr(np.array(fit.hole_exponent, float)),
        table(fit.tank_geometry), arr(np.array(fit.tank_exponent, float)), table(fit.pump_jet), table(fit.tank_jet),
    )
    p = np.zeros(N_PARAMS)
    p[R_COIL], p[V_SUPPLY], p[CORE_OFFSET_MM] = s.coil_resistance, s.supply_voltage, s.core_offset_mm
    p[V_LO], p[V_HI] = max(v_lo, -1e300), min(v_hi, 1e300)
    p[SWITCHED], p[PWM_PERIOD] = float(s.pwm == "switched"), 1.0 / s.pwm_frequency
    p[MASS], p[A_C], p[A_CC], p[A_NET] = sp.mass, sp.pressure_area, params.chamber_area, params.net_area
    p[K_SPRING], p[F0] = sp.spring_stiffness, sp.spring_preload
    p[DAMPING] = sp.viscous_friction if kind == "full" else params.simplified_damping
    p[X_MIN], p[X_MAX] = sp.stroke_min_mm / MM_PER_M, sp.stroke_max_mm / MM_PER_M
    p[R_HOLE], p[N_HOLES], p[H_GAP] = o.hole_radius, o.hole_count, o.gap_height
    p[R_PILOT], p[TANK_OFFSET], p[BLEND_K] = o.tank_pilot_hole_radius, o.tank_hole_offset, o.blend_steepness_per_mm
    # Wetted perimeter of the pump-side leakage slots (Eq. 18, reading R5): n rectangles 2r x h.
    p[GAP_PERIMETER] = o.hole_count * 2.0 * (2.0 * o.hole_radius + o.gap_height)
    p[RHO], p[BETA], p[NU] = params.fluid.density, params.fluid.bulk_modulus, params.fluid.kinematic_viscosity
    p[VOLUME], p[P_TANK] = params.circuit.load_volume, params.circuit.tank_pressure
    p[K_D], p[V_C] = params.damping.restrictor_conductance, params.damping.chamber_volume
    p[FULL] = float(kind == "full")
    p[PUMP_JET_CAP], p[TANK_JET_CAP] = fit.pump_jet_cap, fit.tank_jet_cap
    # The tank edge's fits at its closing point, which hold for all x >= 0 (reading R22).
    p[G_CLOSED] = orf.tank_geometry_factor(0.0, f[T_TANK])
    p[GAMMA_CLOSED] = orf.transition_exponent(0.0, f[T_TANK_EXP])
    p[COS_CLOSED] = ff.jet_cosine(0.0, f[T_TANK_JET], fit.tank_jet_cap)
    p[A_CLOSED] = orf.tank_area(0.0, o.hole_radius, o.hole_count, o.gap_height, o.tank_pilot_hole_radius,
                                o.tank_hole_offset)
    p[VOLTAGE_FACTOR], p[AREA_FACTOR], p[SPOOL_FRICTION_V] = 1.0, 1.0, 1e-3
    p[P_CAVITATION] = params.fluid.cavitation_pressure
    names = layout(params, kind)
    p[OPTIONS] = float(s.coil_thermal or params.fluid.oil_temperature_model or sp.core_separation)
    if s.coil_thermal:
        p[THERMAL], p[ALPHA_CU], p[T_REF_COIL] = 1.0, s.coil_temperature_coefficient, kelvin(
            s.coil_reference_temperature_c)
        p[R_TH], p[C_TH] = s.coil_thermal_resistance, s.coil_heat_capacity
        p[IX_COIL_T] = names.states.index("coil_temperature")
        p[IU_AMBIENT] = names.inputs.index("ambient_temperature")
        p[IY_COIL_T] = names.outputs.index("coil_temperature")
    fl = params.fluid
    if fl.oil_temperature_model:
        p[OIL], p[IU_OIL], p[T_REF_OIL] = 1.0, names.inputs.index("oil_temperature"), kelvin(
            fl.reference_temperature_c)
        p[WALTHER_A], p[WALTHER_B] = _walther(params)
        p[EXPANSION], p[BETA_SLOPE] = fl.thermal_expansion, fl.bulk_modulus_temperature_coefficient
        if not sp.core_separation:
            p[V_RATE] = spool_rate(kelvin(fl.oil_temperature_c), p)
    if sp.core_separation:
        p[SEPARATION], p[M_CORE], p[B_CORE] = 1.0, sp.core_mass, sp.core_damping
        p[XC_MIN] = sp.core_stroke_min_mm / MM_PER_M
        p[IX_CORE], p[IY_CORE] = names.states.index("core_position"), names.outputs.index("core_position")
    return p, f


def spool_rate(temperature: float, p: np.ndarray) -> float:
    """The spool's damping pole D(T) / m (1/s) in oil at `temperature` (K) (R34): the viscous
    friction and, in the full model, the damping chamber's share A_cc^2 / K_d (the chamber sits
    on its slow manifold, p_c = p - A_cc v / K_d), both laminar, so both scale with mu / mu_ref.
    At -20 degC (mu ~110x) it is ~8e5 1/s: h lambda ~ 80 at the 0.1 ms step, which no explicit
    method survives and the exponential integrator takes exactly (Cox & Matthews' ETD2RK)."""
    damping = p[DAMPING] + (p[A_CC] ** 2 / p[K_D] if p[FULL] != 0.0 else 0.0)
    return float(damping * oil_properties(temperature, p)[3] / p[MASS])


@jit(inline=True)
def coil_resistance(x, p):
    """The coil's resistance (ohm): R_COIL, or with coil heating R_ref (1 + alpha (T - T_ref)) at
    the coil temperature state (R33; copper's alpha). A partial short (fault) scales R_COIL."""
    if p[THERMAL] == 0.0:
        return p[R_COIL]
    return p[R_COIL] * (1.0 + p[ALPHA_CU] * (x[int(p[IX_COIL_T])] - p[T_REF_COIL]))


@jit(inline=True)
def core_position(x, p):
    """Where the magnet core is (m, spool coordinates): with the spool unless separation is on."""
    if p[SEPARATION] == 0.0:
        return x[1]
    return x[int(p[IX_CORE])]


@jit(inline=True)
def oil_properties(temperature, p):
    """(nu m^2/s, rho kg/m^3, beta Pa, mu / mu_ref) of the oil at `temperature` (K) (R34):
    Walther's relation (ASTM D341) for nu, rho = rho_ref / (1 + e (T - T_ref)),
    beta = beta_ref exp(-s (T - T_ref)); at T_ref exactly the reference values."""
    dt = temperature - p[T_REF_OIL]
    if dt == 0.0:
        return p[NU], p[RHO], p[BETA], 1.0
    nu = (10.0 ** (10.0 ** (p[WALTHER_A] - p[WALTHER_B] * math.log10(temperature))) - 0.7) / CST_PER_M2S
    rho = p[RHO] / (1.0 + p[EXPANSION] * dt)
    return nu, rho, p[BETA] * math.exp(-p[BETA_SLOPE] * dt), (nu * rho) / (p[NU] * p[RHO])


@jit(inline=True)
def coil_voltage(duty, t, p):
    """V_s (V): the PWM average D * V (reading R15) or the switched 200 Hz waveform, times the
    fault factor VOLTAGE_FACTOR (0: coil open circuit, the driver no longer drives it)."""
    if p[SWITCHED] != 0.0:
        # Phase in periods; edges fall on sample instants, so round away float noise there.
        phase = t / p[PWM_PERIOD]
        phase -= math.floor(phase + 1e-9)
        v = p[V_SUPPLY] if phase < duty - 1e-9 else 0.0
    else:
        v = duty * p[V_SUPPLY]
    if p[VOLTAGE_FACTOR] != 1.0:
        v *= p[VOLTAGE_FACTOR]
    return v


@jit(inline=True)
def edges(x, x_mm, p_load, p_s, p, f):
    """Eqs. 16-27 and 30-32 at spool x (m and mm), load pressure and supply pressure (Pa):
    (pump flow + pump -> load, tank flow + load -> tank, pump flow force, tank flow force)."""
    return edges_in(x, x_mm, p_load, p_s, p[RHO], p[NU], p, f)


@jit(inline=True)
def edges_in(x, x_mm, p_load, p_s, rho, nu, p, f):
    """`edges` with the oil's density and kinematic viscosity given (an oil temperature, R34)."""
    r, n, h = p[R_HOLE], p[N_HOLES], p[H_GAP]
    # Pump side: gap leakage and holes blended by the logistic (Eqs. 17-23, 26-27).
    dp_p = p_s - p_load
    a_p = orf.pump_area(x, r, n, h)
    weight = orf.blend(x_mm, p[BLEND_K])
    cq_p = orf.gap_discharge_coefficient(orf.gap_geometry_factor(x_mm, f[T_GAP]), a_p, p[GAP_PERIMETER], nu, rho,
                                         dp_p)
    if weight > 1e-15:  # far inside the gap region the hole term carries no weight: skip its cost
        cq_hole = orf.hole_discharge_coefficient(orf.hole_geometry_factor(x_mm, f[T_HOLE]),
                                                 orf.transition_exponent(x_mm, f[T_HOLE_EXP]), dp_p)
        cq_p = orf.pump_discharge_coefficient(cq_p, cq_hole, weight)
    q_p = orf.orifice_flow(cq_p, a_p, dp_p, rho)
    f_p = ff.flow_force(cq_p, a_p, dp_p, ff.jet_cosine(x_mm, f[T_PUMP_JET], p[PUMP_JET_CAP]))
    # Tank side: fits in the opening |x| for x < 0; for x >= 0 frozen at the closing edge (R22).
    dp_t = p_load - p[P_TANK]
    if x_mm < 0.0:
        a_t = orf.tank_area(x, r, n, h, p[R_PILOT], p[TANK_OFFSET])
        cq_t = orf.tank_discharge_coefficient(orf.tank_geometry_factor(-x_mm, f[T_TANK]),
                                              orf.transition_exponent(-x_mm, f[T_TANK_EXP]), dp_t)
        cos_t = ff.jet_cosine(-x_mm, f[T_TANK_JET], p[TANK_JET_CAP])
    else:
        cq_t = orf.tank_discharge_coefficient(p[G_CLOSED], p[GAMMA_CLOSED], dp_t)
        cos_t = p[COS_CLOSED]
        a_t = p[A_CLOSED]
    q_t = orf.orifice_flow(cq_t, a_t, dp_t, rho)
    f_t = ff.flow_force(cq_t, a_t, dp_t, cos_t)
    if p[AREA_FACTOR] != 1.0:
        # Contamination: silt narrows both edges. Flow (Eq. 16) and flow force (Eq. 30) are both
        # proportional to the area at a given C_q and dp; C_q is kept (the fits know no silt).
        k = p[AREA_FACTOR]
        q_p, q_t, f_p, f_t = k * q_p, k * q_t, k * f_p, k * f_t
    return q_p, q_t, f_p, f_t


@jit(inline=True)
def coil_current(lam, x, v_s, i_guess, p, f):
    """Eqs. 1-8: the coil current for flux linkage lam at core x (m, spool coordinates) and coil
    voltage v_s, with the resistance R_COIL."""
    return coil_current_in(lam, x, v_s, p[R_COIL], i_guess, p, f)


@jit(inline=True)
def coil_current_in(lam, x, v_s, resistance, i_guess, p, f):
    """`coil_current` with the resistance given (a heated coil, R33)."""
    c1, c2, c3, _, _, _, _ = sol.coefficients_at(x * MM_PER_M + p[CORE_OFFSET_MM], f[T_F1], f[T_F2], f[T_F3],
                                                 f[T_FORCE])
    return sol.solve_current_in(sol.restoring_current(lam, c1, c2, c3), v_s, resistance, f[T_PD], i_guess,
                                p[V_LO], p[V_HI])


@jit(inline=True)
def static_force(i, x, p_load, p_s, p, f):
    """Eq. 14 at rest (v = 0, p_c = p): the net force on the spool (N, + toward +x) with coil
    current i at spool x (m), load and supply pressure (Pa): what the static characteristic and
    the rest states solve (pcv_sim.model.statics)."""
    x_mm = x * MM_PER_M
    _, _, _, k1, k2, k3, k4 = sol.coefficients_at(x_mm + p[CORE_OFFSET_MM], f[T_F1], f[T_F2], f[T_F3], f[T_FORCE])
    _, _, f_p, f_t = edges(x, x_mm, p_load, p_s, p, f)
    return (sol.force_from_coefficients(i, k1, k2, k3, k4) - p[A_C] * p_load + p[A_CC] * p_load
            - p[K_SPRING] * x - (f_p - f_t) - p[F0])


@jit(inline=True)
def rhs(t, x, u, p, f, w, dx):
    """d(state)/dt into dx; the coil current into w[0]. Eqs. 1-3 (solenoid), 14 (spool), 15 and
    28-29 (continuity, chamber).

    Continuity (reading R13): the spool's motion displaces the load side by A_c v and the
    chamber by A_cc v. Simplified model: the chamber is rigid and lossless, its flow A_cc v
    comes from the load volume, so the load side sees (A_c - A_cc) v. The end stops (Sec. 4.2)
    are inelastic: at a stop with the force pushing into it the spool stays (`project` does
    the impact).
    """
    lam, xs, v, pl = x[0], x[1], x[2], x[3]
    duty, q_l, p_s = u[U_DUTY], u[U_LOAD_FLOW], u[U_SUPPLY_PRESSURE]
    v_s = coil_voltage(duty, t, p)
    x_mm = xs * MM_PER_M
    c1, c2, c3, k1, k2, k3, k4 = sol.coefficients_at(x_mm + p[CORE_OFFSET_MM], f[T_F1], f[T_F2], f[T_F3],
                                                     f[T_FORCE])
    i = sol.solve_current_in(sol.restoring_current(lam, c1, c2, c3), v_s, p[R_COIL], f[T_PD], w[0],
                             p[V_LO], p[V_HI])                                            # Eqs. 1-8
    w[0] = i
    q_p, q_t, f_p, f_t = edges(xs, x_mm, pl, p_s, p, f)
    # Eq. 14 without the chamber and damping terms, which differ per variant.
    force = sol.force_from_coefficients(i, k1, k2, k3, k4) - p[A_C] * pl - p[K_SPRING] * xs - (f_p - f_t) - p[F0]
    dx[0] = sol.flux_linkage_derivative(v_s, i, p[R_COIL])                               # Eq. 3
    c_load = p[BETA] / u[U_LOAD_VOLUME]                 # Eq. 15: beta / V, V the load port's volume (an input)
    if p[LEAK] != 0.0:
        # Internal leakage fault: a laminar path load -> tank, q = G (p - p_t), drawn like a load flow.
        q_l = q_l + p[LEAK] * (pl - p[P_TANK])
    if p[SPOOL_FRICTION] != 0.0:
        # Sticking spool fault: Coulomb friction F tanh(v / v_s) against the motion (N).
        force -= p[SPOOL_FRICTION] * math.tanh(v / p[SPOOL_FRICTION_V])
    if p[FULL] != 0.0:
        p_c = x[4]
        q_c = p[K_D] * (pl - p_c)                                                         # Eq. 28
        force += p[A_CC] * p_c - p[DAMPING] * v                                           # Eq. 14
        dx[4] = p[BETA] / p[V_C] * (q_c - p[A_CC] * v)                                    # Eq. 29
        dx[3] = c_load * (q_p - q_t - q_c - q_l + p[A_C] * v)                            # Eq. 15
    else:
        force += p[A_CC] * pl - p[DAMPING] * v                                            # Eq. 14, p_c = p
        dx[3] = c_load * (q_p - q_t - q_l + p[A_NET] * v)                                 # Eq. 15
    # Cavitation (R32): at the floor the oil releases gas instead of falling further in pressure
    # (a load that draws more than the valve feeds: a piston pulled on by its inertia).
    if pl <= p[P_CAVITATION] and dx[3] < 0.0:
        dx[3] = 0.0
    # Inelastic end stops (Sec. 4.2): held while the force pushes into the stop. A stuck spool
    # (fault) is held anywhere; the rig zeroes its velocity when the fault is set.
    if p[STUCK] != 0.0 or stops.held(xs, v, force, p[X_MIN], p[X_MAX]):
        dx[1] = 0.0
        dx[2] = 0.0
    else:
        dx[1] = v
        dx[2] = force / p[MASS]


@jit(inline=True)
def rhs_options(t, x, u, p, f, w, dx):
    """d(state)/dt into dx; the coil current into w[0]. Eqs. 1-3 (solenoid), 14 (spool), 15 and
    28-29 (continuity, chamber).

    Continuity (reading R13): the spool's motion displaces the load side by A_c v and the
    chamber by A_cc v. Simplified model: the chamber is rigid and lossless, its flow A_cc v
    comes from the load volume, so the load side sees (A_c - A_cc) v. The end stops (Sec. 4.2)
    are inelastic: at a stop with the force pushing into it the spool stays (`project` does
    the impact). The options (R33-R35) each act only when switched on in `p`.
    """
    lam, xs, v, pl = x[0], x[1], x[2], x[3]
    duty, q_l, p_s = u[U_DUTY], u[U_LOAD_FLOW], u[U_SUPPLY_PRESSURE]
    v_s = coil_voltage(duty, t, p)
    x_mm = xs * MM_PER_M
    xc_mm = x_mm if p[SEPARATION] == 0.0 else x[int(p[IX_CORE])] * MM_PER_M    # the core (R35)
    c1, c2, c3, k1, k2, k3, k4 = sol.coefficients_at(xc_mm + p[CORE_OFFSET_MM], f[T_F1], f[T_F2], f[T_F3],
                                                     f[T_FORCE])
    r_coil = coil_resistance(x, p)                                                       # R33
    i = sol.solve_current_in(sol.restoring_current(lam, c1, c2, c3), v_s, r_coil, f[T_PD], w[0],
                             p[V_LO], p[V_HI])                                            # Eqs. 1-8
    w[0] = i
    rho, nu, beta, k_d, damping, chamber_scale = p[RHO], p[NU], p[BETA], p[K_D], p[DAMPING], 1.0
    if p[OIL] != 0.0 and u[int(p[IU_OIL])] != p[T_REF_OIL]:
        # R34: the oil at its temperature; laminar conductance and viscous damping go with mu.
        nu, rho, beta, mu_ratio = oil_properties(u[int(p[IU_OIL])], p)
        damping *= mu_ratio
        k_d /= mu_ratio
        # The chamber's pole K_d beta / V_c (~1e8 1/s) is kept at its reference value (its
        # relaxation is far below a step either way); its slow manifold, the damping the spool
        # feels, follows the temperature. The exponential integrator's rate stays exact.
        chamber_scale = mu_ratio * p[BETA] / beta
    q_p, q_t, f_p, f_t = edges_in(xs, x_mm, pl, p_s, rho, nu, p, f)
    f_s = sol.force_from_coefficients(i, k1, k2, k3, k4)
    # Eq. 14 without the chamber and damping terms, which differ per variant.
    force = f_s - p[A_C] * pl - p[K_SPRING] * xs - (f_p - f_t) - p[F0]
    dx[0] = sol.flux_linkage_derivative(v_s, i, r_coil)                                  # Eq. 3
    if p[THERMAL] != 0.0:
        # R33: the coil's lumped heat balance, C_th dT/dt = i^2 R(T) - (T - T_ambient) / R_th.
        it = int(p[IX_COIL_T])
        dx[it] = (i * i * r_coil - (x[it] - u[int(p[IU_AMBIENT])]) / p[R_TH]) / p[C_TH]
    c_load = beta / u[U_LOAD_VOLUME]              # Eq. 15: beta / V, V the load port's volume (an input)
    if p[LEAK] != 0.0:
        # Internal leakage fault: a laminar path load -> tank, q = G (p - p_t), drawn like a load flow.
        q_l = q_l + p[LEAK] * (pl - p[P_TANK])
    if p[SPOOL_FRICTION] != 0.0:
        # Sticking spool fault: Coulomb friction F tanh(v / v_s) against the motion (N).
        force -= p[SPOOL_FRICTION] * math.tanh(v / p[SPOOL_FRICTION_V])
    if p[FULL] != 0.0:
        p_c = x[4]
        q_c = k_d * (pl - p_c)                                                            # Eq. 28
        force += p[A_CC] * p_c - damping * v                                              # Eq. 14
        dx[4] = beta / p[V_C] * (q_c - p[A_CC] * v)                                       # Eq. 29
        if chamber_scale != 1.0:
            dx[4] *= chamber_scale
        dx[3] = c_load * (q_p - q_t - q_c - q_l + p[A_C] * v)                            # Eq. 15
    else:
        force += p[A_CC] * pl - damping * v                                               # Eq. 14, p_c = p
        dx[3] = c_load * (q_p - q_t - q_l + p[A_NET] * v)                                 # Eq. 15
    # Cavitation (R32): at the floor the oil releases gas instead of falling further in pressure
    # (a load that draws more than the valve feeds: a piston pulled on by its inertia).
    if pl <= p[P_CAVITATION] and dx[3] < 0.0:
        dx[3] = 0.0
    if p[SEPARATION] != 0.0:
        _two_bodies(x, v, xs, f_s, force, p, dx)
        return
    # Inelastic end stops (Sec. 4.2): held while the force pushes into the stop. A stuck spool
    # (fault) is held anywhere; the rig zeroes its velocity when the fault is set.
    if p[STUCK] != 0.0 or stops.held(xs, v, force, p[X_MIN], p[X_MAX]):
        dx[1] = 0.0
        dx[2] = 0.0
    else:
        dx[1] = v
        dx[2] = force / p[MASS]


@jit(inline=True)
def _two_bodies(x, v, xs, f_s, force, p, dx):
    """R35: spool and magnet core as two bodies in a unilateral contact. The core sits on the -x
    side and can only push the spool (+x): they move as one body while the contact force that
    keeps them together is a push, apart otherwise (the core flies on when the spool stops, or
    lags when the spool is driven away). `force` is Eq. 14's net force on both; the solenoid's
    f_s and the core's share of the damping act on the core."""
    ic = int(p[IX_CORE])
    xc, vc = x[ic], x[ic + 1]
    m_core = p[M_CORE]
    m_spool = p[MASS] - m_core
    f_core = f_s - p[B_CORE] * vc
    f_spool = force - f_s + p[B_CORE] * v
    spool_free, core_free = True, True
    if xc >= xs and vc >= v:                  # touching and not parting
        joint = f_spool + f_core
        if p[STUCK] != 0.0 or stops.held(xs, v, joint, p[X_MIN], p[X_MAX]):
            spool_free = False
            core_free = f_core < 0.0          # held against the held spool unless it pulls away
        else:
            a = joint / p[MASS]
            if m_spool * a - f_spool >= 0.0:  # the contact pushes: one body
                dx[1], dx[2], dx[ic], dx[ic + 1] = v, a, vc, a
                return
    elif p[STUCK] != 0.0:
        spool_free = False
    if spool_free and not stops.held(xs, v, f_spool, p[X_MIN], p[X_MAX]):
        dx[1], dx[2] = v, f_spool / m_spool
    else:
        dx[1], dx[2] = 0.0, 0.0
    if core_free and not stops.held(xc, vc, f_core, p[XC_MIN], 1e300):
        dx[ic], dx[ic + 1] = vc, f_core / m_core
    else:
        dx[ic], dx[ic + 1] = 0.0, 0.0


@jit(inline=True)
def chamber_rate(p):
    """The damping chamber's pole K_d beta / V_c (1/s, ~2.6e8): the exact linear decay of p_c in
    Eq. 29, which the exponential integrator treats exactly (0 for the simplified model)."""
    return p[K_D] * p[BETA] / p[V_C] if p[FULL] != 0.0 else 0.0


@jit(inline=True)
def state_output(t, x, p, f, y):
    """The outputs that depend on the state alone: pressure and spool position."""
    y[Y_PRESSURE] = x[3]
    y[Y_SPOOL_POSITION] = x[1]


@jit(inline=True)
def state_output_options(t, x, p, f, y):
    """The outputs that depend on the state alone: pressure, spool position and the options'
    (coil temperature and resistance, core position)."""
    y[Y_PRESSURE] = x[3]
    y[Y_SPOOL_POSITION] = x[1]
    _option_outputs(x, p, y)


@jit(inline=True)
def _option_outputs(x, p, y):
    if p[THERMAL] != 0.0:
        iy = int(p[IY_COIL_T])
        y[iy] = x[int(p[IX_COIL_T])]
        y[iy + 1] = coil_resistance(x, p)
    if p[SEPARATION] != 0.0:
        y[int(p[IY_CORE])] = x[int(p[IX_CORE])]


@jit(inline=True)
def output(t, x, u, p, f, w, y):
    """All outputs at time t with the inputs in force from t on: the coil current is algebraic
    in the coil voltage (Eqs. 1-2), so it jumps with the duty (reading R27)."""
    y[Y_PRESSURE] = x[3]
    y[Y_CURRENT] = coil_current(x[0], x[1], coil_voltage(u[U_DUTY], t, p), w[0], p, f)
    y[Y_SPOOL_POSITION] = x[1]


@jit(inline=True)
def output_options(t, x, u, p, f, w, y):
    """All outputs at time t with the inputs in force from t on: the coil current is algebraic
    in the coil voltage (Eqs. 1-2), so it jumps with the duty (reading R27)."""
    y[Y_PRESSURE] = x[3]
    y[Y_CURRENT] = coil_current_in(x[0], core_position(x, p), coil_voltage(u[U_DUTY], t, p), coil_resistance(x, p),
                                   w[0], p, f)
    y[Y_SPOOL_POSITION] = x[1]
    _option_outputs(x, p, y)


@jit(inline=True)
def project(x, p):
    """Keep (x, v) inside the stroke: an inelastic impact at a stop (Sec. 4.2); the load pressure
    not below the cavitation floor (R32)."""
    stops.impact(x, 1, 2, p[X_MIN], p[X_MAX])
    x[3] = max(x[3], p[P_CAVITATION])


@jit(inline=True)
def project_options(x, p):
    """Keep (x, v) inside the stroke: an inelastic impact at a stop (Sec. 4.2); the load pressure
    not below the cavitation floor (R32); the core (R35) not past the spool."""
    if p[SEPARATION] != 0.0:
        _core_impact(x, p)
        return
    stops.impact(x, 1, 2, p[X_MIN], p[X_MAX])
    x[3] = max(x[3], p[P_CAVITATION])


@jit(inline=True)
def _core_impact(x, p):
    """R35 after a step: a core that reached the spool meets it in an inelastic impact (momentum
    kept, the relative velocity lost: the kinetic energy falls by m_s m_c / (2 M) dv^2), then
    the spool's end stops; a core touching a spool that a stop holds stays with it, and the core
    has its own stop on the -x side."""
    ic = int(p[IX_CORE])
    m_core = p[M_CORE]
    m_spool = p[MASS] - m_core
    if x[ic] > x[1] or (x[ic] == x[1] and x[ic + 1] > x[2]):
        x[1] = (m_spool * x[1] + m_core * x[ic]) / p[MASS]
        x[2] = (m_spool * x[2] + m_core * x[ic + 1]) / p[MASS]
        x[ic], x[ic + 1] = x[1], x[2]
    stops.impact(x, 1, 2, p[X_MIN], p[X_MAX])
    if x[ic] >= x[1]:
        x[ic] = x[1]
        x[ic + 1] = min(x[ic + 1], x[2])
    if x[ic] < p[XC_MIN]:
        x[ic] = p[XC_MIN]
        x[ic + 1] = max(x[ic + 1], 0.0)
    x[3] = max(x[3], p[P_CAVITATION])
