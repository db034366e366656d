"""The valve beyond the paper's bench (docs/model.md R33-R35), each effect against its physics:
coil heating (copper's resistance, the first-order heat balance), oil temperature (the grade's
viscosity, the paper's model at the paper's temperature) and core-spool separation (none at the
paper's rate limit; at the spool's end stop after a release to 0 %: contact regained, energy lost
at the impact; inside the stroke the margin that keeps the contact, R35: Sec. 3.2's undershoot is
not reproduced).

The simulations run the valve with all three options on and the coil's reference temperature at
the ambient's (40 degC): at rest that is the paper's bench, so each test sees the one effect it
is about (and one compiled layout per model serves them all).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from offline_valve import advance, at_rest, now, output, put

from pcv_sim.device.valve import VALVE
from pcv_sim.errors import CommandError, ParameterError
from pcv_sim.model import kernel
from pcv_sim.model.valve import ValveModel
from pcv_sim.params import default_params, replace_param
from pcv_sim.units import kelvin

ALPHA_COPPER = 3.93e-3      # 1/K, annealed copper at 20 degC (IEC 60028)


def options(**changes):
    """All three options on, the coil's resistance holding at the ambient 40 degC, plus `changes`
    (`section__key=value`)."""
    p = default_params()
    for key, value in {"solenoid.coil_temperature": "lumped", "solenoid.coil_reference_temperature_c": 40.0,
                       "fluid.temperature": "input", "spool.core": "separate",
                       **{k.replace("__", "."): v for k, v in changes.items()}}.items():
        p = replace_param(p, key, value)
    return p


# --- coil heating (R33) ------------------------------------------------------------------------


def test_resistance_follows_copper_at_two_temperatures():
    st = at_rest(options(solenoid__coil_reference_temperature_c=20.0), 0.7)
    ix = st.sim.plant.index("state", "valve.coil_temperature")
    for t_c in (20.0, 80.0):
        st.sim.x[ix] = kelvin(t_c)
        assert output(st, "coil_temperature") == kelvin(t_c)
        assert output(st, "coil_resistance") == pytest.approx(5.6 * (1.0 + ALPHA_COPPER * (t_c - 20.0)), rel=1e-12)
    # The hot coil (6.92 ohm) draws less current at the same duty: 0.7 * 12 V / R once the flux settles.
    advance(st, 5000)
    assert now(st).current == pytest.approx(0.7 * 12.0 / (5.6 * (1.0 + ALPHA_COPPER * 60.0)), rel=2e-3)


def test_thermal_step_response_is_first_order():
    """alpha = 0 and a constant duty: constant heat P = (D V)^2 / R, so T(t) = T_a + P R_th (1 - e^(-t/tau)),
    tau = R_th C_th (a small heat capacity: tau = 5 s)."""
    r_th, c_th, duty = 2.5, 2.0, 0.7
    params = options(solenoid__coil_temperature_coefficient=0.0, solenoid__coil_heat_capacity=c_th,
                     solenoid__coil_thermal_resistance=r_th)
    st = at_rest(params, 0.0)
    put(st, "duty_cycle", duty)
    t_a, power, tau = kelvin(40.0), (duty * 12.0) ** 2 / 5.6, r_th * c_th
    times, temps = [], []
    for _ in range(20):
        advance(st, 5000)                            # 0.5 s
        times.append(st.time)
        temps.append(output(st, "coil_temperature"))
    # Once the coil's electrical transient (tens of ms) is over the heat input is constant: from the
    # first sample on, T(t) = T_inf + (T(t1) - T_inf) exp(-(t - t1) / tau) exactly.
    t, temps_a = np.array(times), np.array(temps)
    t_inf = t_a + power * r_th
    expected = t_inf + (temps_a[0] - t_inf) * np.exp(-(t - t[0]) / tau)
    assert np.max(np.abs(temps_a - expected)) < 2e-3            # of a 31.5 K rise
    # The start: the first 0.5 s as from t = 0, less the heat the rising current did not bring yet.
    assert temps_a[0] - t_a == pytest.approx(power * r_th * (1 - math.exp(-0.5 / tau)), abs=0.2)


def test_thermal_steady_state_with_copper():
    """With alpha the heat falls as the coil warms (P = (D V)^2 / R(T)): the steady state solves
    (T - T_a) / R_th = (D V)^2 / (R_ref (1 + alpha (T - T_ref))), a quadratic."""
    r_th, c_th, duty = 2.5, 2.0, 1.0
    st = at_rest(options(solenoid__coil_heat_capacity=c_th), duty)
    advance(st, 400_000)                             # 40 s = 8 tau
    v2, r_ref, a = (duty * 12.0) ** 2, 5.6, ALPHA_COPPER
    # d = T - T_a (T_ref = T_a): d (1 + a d) = v2 R_th / R_ref
    rise = (-1.0 + math.sqrt(1.0 + 4.0 * a * v2 * r_th / r_ref)) / (2.0 * a)
    assert output(st, "coil_temperature") - kelvin(40.0) == pytest.approx(rise, abs=0.01)   # 46.6 K
    assert now(st).current == pytest.approx(12.0 / (r_ref * (1 + a * rise)), rel=1e-4)


def test_ambient_temperature_input_is_checked():
    st = at_rest(options(), 0.0)
    st.set_temperature(VALVE, "ambient_temperature", kelvin(-20.0))
    assert st.sim.u[st.sim.plant.index("input", "valve.ambient_temperature")] == kelvin(-20.0)
    with pytest.raises(CommandError, match="not degC"):
        st.set_temperature(VALVE, "ambient_temperature", -20.0)
    with pytest.raises(CommandError, match="accepted are ambient_temperature, oil_temperature"):
        st.set_temperature(VALVE, "coil_temperature", 300.0)
    with pytest.raises(CommandError, match=r"no ambient temperature input; the valve YAML's solenoid\.coil_temperature: lumped brings it"):
        at_rest(default_params(), 0.0).set_temperature(VALVE, "ambient_temperature", 300.0)


# --- oil temperature (R34) ---------------------------------------------------------------------


def test_viscosity_against_the_grade():
    """ISO VG 46: 46 cSt at 40 degC (ISO 3448); an HM 46 of viscosity index ~100: 6.8 cSt at
    100 degC and ~580 cSt at 0 degC (typical data sheets); at -20 degC 'tens of times' 40 degC's."""
    p, _ = kernel.pack(options(), "simplified")
    nu = {t: kernel.oil_properties(kelvin(t), p)[0] * 1e6 for t in (-20.0, 0.0, 40.0, 40.0001, 100.0)}
    assert nu[40.0] == 46.0
    assert nu[40.0001] == pytest.approx(46.0, rel=1e-4)
    assert nu[100.0] == pytest.approx(6.8, rel=1e-9)
    assert nu[0.0] == pytest.approx(580.0, rel=0.05)
    assert 30 < nu[-20.0] / 46.0 < 300
    _, rho, beta, mu_ratio = kernel.oil_properties(kelvin(0.0), p)
    assert rho == pytest.approx(900.0 / (1 - 7e-4 * 40.0))
    assert beta == pytest.approx(1e9 * math.exp(4e-3 * 40.0))
    assert mu_ratio == pytest.approx(nu[0.0] * rho / (46.0 * 900.0))


def test_at_the_papers_temperature_the_model_is_the_papers():
    paper, oil = ValveModel(default_params(), "full"), ValveModel(
        replace_param(default_params(), "fluid.temperature", "input"), "full")
    state = paper.initial_state(0.7, 1e-4, 110e5)
    for duty, q in ((0.7, 0.0), (0.3, 1e-5), (1.0, -2e-5)):
        (d_oil, i_oil), (d_paper, i_paper) = (m.derivatives(0.0, state, duty, q, 200e5, 1.5) for m in (oil, paper))
        assert i_oil == pytest.approx(i_paper, rel=1e-14)
        assert d_oil == pytest.approx(d_paper, rel=1e-12, abs=1e-12 * max(abs(v) for v in d_paper))
    # Colder oil: more damping on the moving spool, less gap leakage.
    oil._u[4] = kelvin(0.0)
    moving = (*state[:2], -0.01, *state[3:])
    d_paper, _ = paper.derivatives(0.0, moving, 0.7, 0.0, 200e5, 1.5)
    d_cold, _ = oil.derivatives(0.0, moving, 0.7, 0.0, 200e5, 1.5)
    assert d_cold[2] > d_paper[2]                   # the viscous force on v < 0 pushes harder toward +x


def test_cold_oil_slows_the_full_model():
    """A duty step with oil at 0 degC (13x the viscosity): the laminar damping 13x (B and the
    chamber's restrictor), the spool's pole 13x: at a 10 us step the pressure follows later."""
    warm, cold = (at_rest(options(fluid__oil_temperature_c=t, simulation__time_step=1e-5, spool__core="attached"), 0.5, kind="full") for t in (40.0, 0.0))
    start = now(warm).pressure
    assert now(cold).pressure == pytest.approx(start, abs=0.5e5)       # the same rest, to the leakage
    for st in (warm, cold):
        put(st, "duty_cycle", 0.7)
        advance(st, 1000)                            # 10 ms
    assert now(cold).pressure - start < 0.5 * (now(warm).pressure - start)


def test_too_cold_oil_for_an_explicit_step_is_refused():
    """Heun (rk2) integrates the spool's damping pole explicitly: beyond h lambda = 2 the cold oil
    is refused, naming a step that runs it and the integrator that takes the pole exactly."""
    cold = options(fluid__oil_temperature_c=0.0, spool__core="attached", simulation__integrator="rk2")
    with pytest.raises(ParameterError, match=r"oil_temperature_c: oil temperature 0.0 degC: .* simulation.time_step <= \S+ s .*erk2") as err:
        at_rest(cold, 0.5)
    step = float(str(err.value).rsplit("<= ", 1)[1].split(" ")[0])
    assert 1e-5 < step < 1e-4                       # 13x the viscosity: about a tenth of the step
    at_rest(replace_param(cold, "simulation.time_step", step), 0.5)
    # Core separate: spool and core each have their own pole, integrated explicitly.
    st = at_rest(options(), 0.5)
    with pytest.raises(CommandError, match=r"beyond what the 0\.0001 s step integrates.*each have their own pole"):
        st.set_temperature(VALVE, "oil_temperature", kelvin(-20.0))
    assert st.sim.u[st.sim.plant.index("input", "valve.oil_temperature")] == kelvin(40.0)   # the last valid stays


def _cold(t_c, kind, dt=1e-4, **changes):
    return at_rest(options(fluid__oil_temperature_c=t_c, spool__core="attached", simulation__time_step=dt,
                                   **changes), 0.5, kind=kind)


@pytest.mark.parametrize("kind", ["simplified", "full"])
def test_cold_start_at_the_nodes_step_against_the_stiff_reference(kind):
    """Oil at -20 degC (~110x the viscosity): at the node's 0.1 ms step the exponential integrator
    takes the spool's damping pole (~8e5 1/s, h lambda ~ 80) exactly. From the rest the warm
    statics give, a duty step 50 -> 70 %: the cold valve settles (its gap leakage 110x smaller)
    and answers the step over 50 ms; against Radau on the same equations, and the error shrinks
    with the step."""
    from pcv_sim.simulation.reference import integrate_reference

    atol = {"flux_linkage": 1e-9, "spool_position": 1e-12, "spool_velocity": 1e-9, "pressure": 1e-3,
            "chamber_pressure": 1e-3, "coil_temperature": 1e-9}
    errors = []
    for dt in (1e-4, 5e-5, 2.5e-5):
        st = _cold(-20.0, kind, dt)
        assert st.sim.integrator == "erk2"
        x0, w0 = st.sim.x.copy(), st.sim.W.copy()
        put(st, "duty_cycle", 0.7)
        n = round(0.05 / dt)
        pressures = [now(st).pressure]
        for _ in range(n):
            advance(st, 1)
            pressures.append(now(st).pressure)
        if dt == 1e-4:
            held = st.sim.u.copy()                  # the inputs from the step on (held)
            xs, _ = integrate_reference(st.sim.plant, x0, lambda t, u=held: u, [], np.arange(n + 1) * dt,
                                        atol=np.array([atol[name.partition(".")[2]] for name in st.sim.plant.states]),
                                        workspace=w0)
            reference = xs[3]
        errors.append(float(np.max(np.abs(np.array(pressures)[:: round(1e-4 / dt)] - reference))))
    assert float(np.ptp(reference)) > 10e5           # the pressure moved by > 10 bar
    assert errors[0] < 0.01e5                        # within 0.01 bar at the node's step
    assert errors[2] < errors[1] < errors[0]         # converges as the step shrinks


def test_cold_spool_moves_slower_by_the_viscosity_ratio():
    """Eq. 14 with the laminar damping D(T) = D_ref mu/mu_ref: in cold oil the spool's motion is
    quasi-static (its inertia time m/D is microseconds), so the force the duty step adds drives
    it at v = F/D: over the first millisecond the spool moves less by the ratio of viscosities."""
    moves = {}
    mu = {}
    for t_c in (-20.0, 0.0):
        st = _cold(t_c, "simplified")
        x0 = now(st).spool_position
        mu[t_c] = float(kernel.oil_properties(kelvin(t_c), st.sim.P[: kernel.N_PARAMS])[3])
        put(st, "duty_cycle", 0.7)
        advance(st, 10)                              # 1 ms
        moves[t_c] = now(st).spool_position - x0
    assert moves[0.0] > 0 and moves[-20.0] > 0
    assert moves[0.0] / moves[-20.0] == pytest.approx(mu[-20.0] / mu[0.0], rel=0.1)


def test_oil_warming_at_run_time_keeps_the_step_exact():
    """The oil temperature set at run time moves the spool's pole the integrator takes exactly:
    a valve started warm and cooled to -20 degC follows the one started at -20 degC."""
    warm, cold = _cold(40.0, "full"), _cold(-20.0, "full")
    warm.set_temperature(VALVE, "oil_temperature", kelvin(-20.0))
    for st in (warm, cold):
        put(st, "duty_cycle", 0.7)
        advance(st, 200)
    assert warm.sim.P[kernel.V_RATE] == cold.sim.P[kernel.V_RATE]
    assert np.array_equal(warm.sim.x, cold.sim.x)   # the same rest, the same pole: the same steps


def test_oil_second_point_is_checked():
    with pytest.raises(ParameterError, match="second point"):
        options(fluid__second_viscosity=60e-6)


# --- core-spool separation (R35) ---------------------------------------------------------------


def test_impact_keeps_momentum_and_loses_energy():
    p, _ = kernel.pack(options(), "simplified")
    ic = int(p[kernel.IX_CORE])
    x = np.array([0.0, 1e-4, -0.02, 100e5, kelvin(40.0), 1.01e-4, 0.05])    # the core caught the spool
    m, mc = p[kernel.MASS], p[kernel.M_CORE]
    ms = m - mc
    before_p = ms * x[2] + mc * x[ic + 1]
    before_e = 0.5 * ms * x[2] ** 2 + 0.5 * mc * x[ic + 1] ** 2
    dv = x[ic + 1] - x[2]
    kernel.project_options(x, p)
    assert x[1] == x[ic] and x[2] == x[ic + 1]
    assert m * x[2] == pytest.approx(before_p, rel=1e-12)
    after_e = 0.5 * m * x[2] ** 2
    assert before_e - after_e == pytest.approx(0.5 * ms * mc / m * dv**2, rel=1e-9)
    assert before_e - after_e > 0


@pytest.mark.parametrize("kind", ["simplified", "full"])
def test_release_to_zero_separates_and_contact_is_regained(kind):
    """A sudden release to 0 % duty: the spool stops on its end stop and the core flies on (the
    solenoid no longer holds it against the spool); when the duty returns the core meets the spool
    again (an inelastic impact) and they move as one."""
    params = options()
    st = at_rest(params, 1.0, kind=kind)
    put(st, "duty_cycle", 0.0)
    gaps = []
    for _ in range(1000):                           # 100 ms
        advance(st, 1)
        gaps.append(now(st).spool_position - output(st, "core_position"))
    assert now(st).spool_position == params.spool.stroke_min_mm * 1e-3
    assert max(gaps) > 1e-6                         # > 1 um apart
    put(st, "duty_cycle", 0.6)
    for _ in range(3000):
        advance(st, 1)
    assert output(st, "core_position") == now(st).spool_position      # contact regained, one body again
    ic = st.sim.plant.index("state", "valve.core_velocity")
    assert st.sim.x[ic] == st.sim.x[2]


@pytest.mark.parametrize("kind", ["simplified", "full"])
def test_no_separation_at_the_papers_rate_limit(kind):
    """Sec. 3.2: the rig's fall-rate limit (2 /s) keeps core and spool together over the duties the
    rig drove (30 .. 100 %)."""
    st = at_rest(options(command__duty_fall_rate_limit=2.0), 1.0, kind=kind)
    put(st, "duty_cycle", 0.3)
    for _ in range(60):                             # 0.6 s: the ramp to 0 and beyond
        advance(st, 100)
        assert output(st, "core_position") == now(st).spool_position


@pytest.mark.parametrize(("start", "damping"), [(1.0, "equivalent"), (0.7, "equivalent"), (1.0, 20.0)])
def test_fast_release_inside_the_stroke_keeps_the_contact(start, damping):
    """docs/model.md R35: a sudden release to 30 % (no rate limit) turns the spool short of its
    stop, and in that quasi-static motion the contact force (D_s F_s - B_c F_r) / (D_s + B_c) stays
    a push, also with the spool's damping cut 15-fold: the core never leaves the spool, and the
    separate core's valve gives the attached one's pressure (Sec. 3.2's undershoot not reproduced)."""
    runs = {}
    for core in ("attached", "separate"):
        st = at_rest(options(spool__core=core, spool__viscous_friction_simplified=damping,
                                     fluid__temperature="fixed"), start)
        put(st, "duty_cycle", 0.3)
        pressures, positions = [], []
        for _ in range(800):                        # 80 ms: the pressure falls to its new level
            advance(st, 1)
            pressures.append(now(st).pressure)
            positions.append(now(st).spool_position)
            if core == "separate":
                assert output(st, "core_position") == now(st).spool_position
        runs[core] = np.array(pressures), np.array(positions)
    (p_att, x_att), (p_sep, _) = runs["attached"], runs["separate"]
    assert p_att[0] - p_att[-1] > 80e5              # a release of > 80 bar
    assert min(x_att) > st.params.spool.stroke_min_mm * 1e-3 + 2e-5       # turned > 20 um short of the stop
    assert np.max(np.abs(p_sep - p_att)) < 1.0      # Pa: the same motion


@pytest.mark.parametrize(("hold", "damping", "least"), [
    (0, "equivalent", 1.0), (5, "equivalent", 1.0), (20, "equivalent", 0.16), (0, 20.0, 0.04), (5, 20.0, 0.04)])
def test_core_mass_that_would_part_the_bodies(hold, damping, least):
    """docs/model.md R35, the margin: with core and spool moving as one body, the contact force on
    the spool is N = F_s - B_c v - m_c a (F_s the solenoid's push on the core); they part when the
    core's inertia outweighs what holds it, m_c a > F_s - B_c v. Over fast releases (100 % -> 30 %,
    or -> 0 % for `hold` ms then 30 %, no rate limit) the smallest core mass that would part them,
    min (F_s - B_c v) / a over the decelerating samples, is >= 1 kg at the paper's damping (the
    assumed core is 0.024 kg, Table 1's whole moving mass 0.04 kg), >= 0.16 kg where the duty
    returns after 20 ms at 0 %, and still above the whole moving mass with the damping cut 15-fold:
    the spool's force changes at the coil's and the pressure's rates (ms), so it never slows
    abruptly enough inside the stroke."""
    p = options(spool__core="attached", spool__viscous_friction_simplified=damping, fluid__temperature="fixed",
                solenoid__coil_temperature="fixed")
    model = ValveModel(p)
    st = at_rest(p, 1.0)
    iv = st.sim.plant.index("state", "valve.spool_velocity")
    put(st, "duty_cycle", 0.0 if hold else 0.3)
    v, f_s = [], []
    for k in range(1000):                           # 100 ms: the release and the pressure's fall
        if hold and k == hold * 10:
            put(st, "duty_cycle", 0.3)
        advance(st, 1)
        v.append(st.sim.x[iv])
        f_s.append(model.solenoid_force(now(st).current, now(st).spool_position))
    vel, force = np.array(v), np.array(f_s)
    acc = np.gradient(vel, st.dt)
    slowing = acc > 1.0                             # m/s^2: the -x motion being braked, or +x driven
    held = force - p.spool.core_damping * vel
    needed = np.min(held[slowing] / acc[slowing])
    assert needed > least
    assert needed > 1.5 * p.spool.core_mass


def test_core_parameters_are_checked():
    with pytest.raises(ParameterError, match="core_mass"):
        options(spool__core_mass=0.05)
    with pytest.raises(ParameterError, match="core_damping"):
        options(spool__core_damping=10.0)


def test_the_option_interface_is_the_kernels():
    """The node's option topics (`OPTION_INTERFACE`) and the device's `OPTION_SIGNALS` are the
    kernel's option inputs and outputs with all options on, by direction, for both models."""
    from pcv_sim.device.valve import OPTION_SIGNALS
    from pcv_sim.io.topics import OPTION_INTERFACE

    for kind in ("simplified", "full"):
        lay = kernel.layout(options(), kind)
        assert lay.inputs[len(kernel.INPUTS):] == tuple(e.name for e in OPTION_INTERFACE if e.direction == "in")
        assert lay.outputs[len(kernel.OUTPUTS):] == tuple(e.name for e in OPTION_INTERFACE if e.direction == "out")
    assert set(OPTION_SIGNALS) == {e.name for e in OPTION_INTERFACE}
