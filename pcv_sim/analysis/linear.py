"""Linear analysis of the simplified model in reducing mode (Sec. 5, Eqs. 34-36, appendix A.1).

Around a static working point (x0, p0, i0, p_s0):
    L di/dt     = dV_s - R di                                         (34)
    m d2x/dt2   = K_fi di - A dp - K_e dx - B dx/dt                  (35)
    V/beta dp/dt = K_q dx - K_c dp + K_cps dp_s + A dx/dt - dq_l      (36)
with K_e = K - K_fx + K_ff. The paper's Eqs. 35-36 write A_c; with p_c = p (no chamber) the
area the load pressure acts on is the net A_c - A_cc (reading R11), used here. Eq. 36 as
printed has V/beta where beta/V belongs (dimensions). The solenoid does not enter the
hydro-mechanical loop (Fig. 6), whose loop gain is
    L(s) = A (K_q + A s) / ((m s^2 + B s + K_e) (V s / beta + K_c)).
Derivatives are central differences of the model's own functions.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from pcv_sim.analysis.static import StaticPoint, static_point
from pcv_sim.model.valve import Hydraulics, ValveModel

__all__ = ["LinearModel", "Margins", "linearize", "loop_gain", "margins"]


@dataclass(frozen=True)
class Margins:
    """Stability margins of the loop gain L(jw).

    The gain margin is taken at the phase crossover (-180 deg, mod 360) nearest to instability,
    i.e. with the smallest |gain margin| in dB, searched over all frequencies, including w = 0
    when L(0) is negative real (K_e < 0, the open loop has a pole in the right half plane). A
    crossover where |L| > 1 gives a negative margin: the loop gain must fall by that much for
    the Nyquist plot to pass -1 there. inf (at inf rad/s) only when the phase never reaches -180.
    """

    gain_margin_db: float          # at the phase crossover nearest to instability; inf if none
    phase_crossover: float         # rad/s (0 = DC, inf if none)
    phase_margin_deg: float        # 180 + phase at the gain crossover (|L| = 1); nan if none
    gain_crossover: float          # rad/s
    phase_crossovers: tuple[tuple[float, float], ...] = ()   # every (w rad/s, gain margin dB) found


@dataclass(frozen=True)
class LinearModel:
    point: StaticPoint
    K_fi: float       # N/A
    K_fx: float       # N/m
    K_ff: float       # N/m
    K: float          # N/m
    K_e: float        # N/m
    K_q: float        # m^2/s
    K_c: float        # m^3/(s Pa)
    K_cps: float      # m^3/(s Pa)
    inductance: float  # H, dlambda/di at the point (Eq. 34's constant L)
    mass: float
    damping: float
    area: float
    volume: float
    beta: float
    resistance: float
    eigenvalues: np.ndarray = field(repr=False)          # closed loop (x, v, p) and the coil pole
    margins: Margins | None = None

    def state_matrix(self) -> np.ndarray:
        """A of d/dt [x, v, p] = A [x, v, p] (inputs held)."""
        m, b, a, c = self.mass, self.damping, self.area, self.beta / self.volume
        return np.array([
            [0.0, 1.0, 0.0],
            [-self.K_e / m, -b / m, -a / m],
            [c * self.K_q, c * a, -c * self.K_c],
        ])

    def loop_gain(self, w: np.ndarray) -> np.ndarray:
        return loop_gain(self, 1j * np.asarray(w))


def loop_gain(lin: LinearModel, s: np.ndarray) -> np.ndarray:
    """Fig. 6's hydro-mechanical loop gain L(s) (negative feedback through A p)."""
    mech = lin.mass * s**2 + lin.damping * s + lin.K_e
    hyd = lin.volume / lin.beta * s + lin.K_c
    return lin.area * (lin.K_q + lin.area * s) / (mech * hyd)


def margins(lin: LinearModel, w: np.ndarray | None = None) -> Margins:
    """Gain and phase margins of L(jw) on a dense log grid (phase unwrapped from low frequency)."""
    w = np.logspace(-1, 7, 20001) if w is None else w
    resp = lin.loop_gain(w)
    mag = np.abs(resp)
    phase = np.degrees(np.unwrap(np.angle(resp)))
    # Phase is referred to the -180 deg line nearest its low-frequency value's branch.
    gc = np.nonzero(np.diff(np.sign(mag - 1.0)))[0]
    if gc.size:
        k = int(gc[-1])
        f = (1.0 - mag[k]) / (mag[k + 1] - mag[k])
        w_gc = float(w[k] + f * (w[k + 1] - w[k]))
        ph = float(phase[k] + f * (phase[k + 1] - phase[k]))
        pm = ((ph + 180.0 + 180.0) % 360.0) - 180.0
    else:
        w_gc, pm = math.nan, math.nan
    shifted = ((phase + 180.0 + 180.0) % 360.0) - 180.0  # 0 at -180 deg (mod 360)
    pc = np.nonzero((np.abs(np.diff(shifted)) < 180.0) & (np.diff(np.sign(shifted)) != 0))[0]
    crossings: list[tuple[float, float]] = []
    dc = complex(loop_gain(lin, np.array([0.0 + 0.0j]))[0])
    if dc.real < 0.0 and abs(dc.imag) <= 1e-9 * abs(dc):  # L(0) negative real: -180 deg at DC
        crossings.append((0.0, -20.0 * math.log10(abs(dc))))
    for k in (int(k) for k in pc):
        f = -shifted[k] / (shifted[k + 1] - shifted[k])
        w_k = float(w[k] + f * (w[k + 1] - w[k]))
        crossings.append((w_k, -20.0 * math.log10(float(np.interp(w_k, w[k : k + 2], mag[k : k + 2])))))
    if crossings:
        w_pc, gm = min(crossings, key=lambda c: abs(c[1]))
    else:
        w_pc, gm = math.inf, math.inf
    return Margins(gm, w_pc, pm, w_gc, tuple(crossings))


def linearize(model: ValveModel, duty: float, x0: float, supply_pressure: float | None = None) -> LinearModel:
    """The Sec. 5 linear model at the static point with the spool at x0 (m) and duty D."""
    if model.kind != "simplified":
        model = ValveModel(model.params, "simplified")
    ps = model.p_supply if supply_pressure is None else supply_pressure
    pt = static_point(model, duty, x0, ps)
    i0, p0 = pt.current, pt.pressure
    hx, hp, hi = 1e-8, 1e2, 1e-6

    def fs(i: float, x: float) -> float:
        return model.solenoid_force(i, x)

    def hyd(x: float, p: float, p_s: float) -> Hydraulics:
        return model.hydraulics(x, p, p_s)

    k_fi = (fs(i0 + hi, x0) - fs(i0 - hi, x0)) / (2 * hi)
    k_fx = (fs(i0, x0 + hx) - fs(i0, x0 - hx)) / (2 * hx)
    k_ff = (hyd(x0 + hx, p0, ps).flow_force - hyd(x0 - hx, p0, ps).flow_force) / (2 * hx)
    k_q = (hyd(x0 + hx, p0, ps).valve_flow - hyd(x0 - hx, p0, ps).valve_flow) / (2 * hx)
    k_c = -(hyd(x0, p0 + hp, ps).valve_flow - hyd(x0, p0 - hp, ps).valve_flow) / (2 * hp)
    k_cps = (hyd(x0, p0, ps + hp).valve_flow - hyd(x0, p0, ps - hp).valve_flow) / (2 * hp)
    # Eq. 34's constant inductance: the slope of the restoring curve (Eq. 4) at the point.
    lam0 = model.flux_linkage_at_rest(i0, x0)
    c1, c2, c3 = model.restoring(x0)
    inductance = 1.0 / ((3 * c1 * lam0 + 2 * c2) * lam0 + c3)
    k_e = model.k_spring - k_fx + k_ff
    lin = LinearModel(
        pt, k_fi, k_fx, k_ff, model.k_spring, k_e, k_q, k_c, k_cps, inductance,
        model.mass, model.damping, model.a_net, model.volume, model.beta, model.resistance,
        np.array([]),
    )
    eig = np.concatenate([np.linalg.eigvals(lin.state_matrix()), [-model.resistance / inductance]])
    return LinearModel(**{**lin.__dict__, "eigenvalues": eig, "margins": margins(lin)})
