"""Temperatures that vary over a run (docs/model.md R33, R34): the ambient of a lumped coil and the
oil temperature as scenario profiles, fed to the valves' option inputs while the rig runs."""

import math
from pathlib import Path

import numpy as np
import pytest
from offline_valve import advance, at_rest, put

from pcv_sim.device.valve import VALVE
from pcv_sim.errors import CommandError
from pcv_sim.params import load_params
from pcv_sim.rig import Rig, load_rig
from pcv_sim.rig.scenario import ScenarioError, run_scenario, scenario_from_mapping, schedule_timeline
from pcv_sim.units import kelvin

REPO = Path(__file__).resolve().parents[2]
R_TH, C_TH = 1.0, 1.0        # K/W, J/K: a coil with a 1 s thermal time constant, so a test sees it settle


@pytest.fixture(scope="module")
def probe_rig(tmp_path_factory, options_rig_writer):
    """The shipped rig plus a valve `probe` on its own load volume with both temperature inputs
    (test/kernel_warmup.py `write_options_rig`); no watchdog (the runs command a duty once and hold it)."""
    d = tmp_path_factory.mktemp("rig")
    path = options_rig_writer(d, R_TH, C_TH)
    return path, load_rig(path), load_params(d / "probe.yaml")


def _scenario(rig_path, timeline, duration):
    return scenario_from_mapping({"rig": str(rig_path), "duration": duration, "timeline": timeline})


def _run(rig, scenario, outputs, every):
    """The rig through the scenario's timeline without a controller; `outputs` at each `every` steps."""
    rig.reset()
    schedule_timeline(rig, scenario)
    idx = [rig.plant.index("output", o) for o in outputs]
    n = round(scenario.duration / rig.dt)
    rows = []
    for step in range(0, n + 1, every):
        rig.advance_to(step)
        rows.append(rig.sim.outputs()[idx].copy())
    return np.arange(0, n + 1, every) * rig.dt, np.array(rows)


def test_ambient_step_gives_the_coils_first_order_response(probe_rig):
    """A step of the ambient (40 -> 0 degC at 0.2 s) on a coil that carries no current: the coil
    temperature through the rig is the analytic first-order response, T_a + (T_0 - T_a)
    exp(-t / (R_th C_th)), to the integration error of the step."""
    path, params, _ = probe_rig
    rig = Rig(params)
    scenario = _scenario(path, [{"t": 0.2, "ambient_temperature": {"probe": "0 degC"}}], 3.0)
    t, rows = _run(rig, scenario, ["probe.coil_temperature"], 100)
    tau = R_TH * C_TH
    t0 = math.ceil(0.2 / rig.dt - 1e-9) * rig.dt
    expected = np.where(t < t0, kelvin(40.0), kelvin(0.0) + 40.0 * np.exp(-np.maximum(t - t0, 0.0) / tau))
    assert rows[0, 0] == pytest.approx(kelvin(40.0))             # the rest state: the coil at the ambient
    assert np.max(np.abs(rows[:, 0] - expected)) < 1e-3           # K, of a 40 K step
    assert rows[-1, 0] == pytest.approx(kelvin(0.0) + 40.0 * math.exp(-(3.0 - t0) / tau), abs=1e-3)


def test_coil_heating_under_a_varying_ambient_follows_its_heat_balance(probe_rig):
    """At 80 % duty with the ambient ramping 40 -> -10 degC: the rig's coil temperature solves the
    heat balance C_th dT/dt = (D V)^2 / R(T) - (T - T_a(t)) / R_th (the current settles in ~10 ms,
    quasi-static against tau = 1 s), and the current is D V / R(T) with copper's R(T) = R_20 (1 +
    alpha (T - 20 degC)) at every sample: the colder coil draws more current."""
    from scipy.integrate import solve_ivp

    path, params, valve = probe_rig
    s = valve.solenoid
    rig = Rig(params)
    scenario = _scenario(path, [{"t": 0.0, "duty": {"probe": 0.8}},
                                {"t": 0.5, "ambient_temperature": {"ramp": {"to": "-10 degC", "duration": "1 s"}}}],
                         3.0)
    t, rows = _run(rig, scenario, ["probe.coil_temperature", "probe.current"], 100)

    def r_of(temp):
        return s.coil_resistance * (1.0 + s.coil_temperature_coefficient * (temp - kelvin(s.coil_reference_temperature_c)))

    def ambient(tt):
        return kelvin(40.0) if tt < 0.5 else kelvin(40.0 - 50.0 * min(1.0, (tt - 0.5) / 1.0))

    v = 0.8 * s.supply_voltage
    # From 0.1 s on, after the current's own transient: the rig's state then is the start.
    settled = t >= 0.1 - 1e-12
    ref = solve_ivp(lambda tt, y: [(v * v / r_of(y[0]) - (y[0] - ambient(tt)) / R_TH) / C_TH], (t[settled][0], 3.0),
                    [rows[settled][0, 0]], t_eval=t[settled], rtol=1e-9, atol=1e-9, max_step=1e-3)
    assert np.max(np.abs(rows[settled, 0] - ref.y[0])) < 0.05     # K, over a ~34 K swing
    assert np.ptp(rows[:, 0]) > 25.0
    # The current D V / R(T), lagging the resistance's drift (~2 %/s) by the coil's L / R (~10 ms).
    late = t >= 0.3 - 1e-12
    current = v / r_of(rows[late, 0])
    assert np.max(np.abs(rows[late, 1] - current) / current) < 1e-3
    assert rows[-1, 1] > 1.1 * rows[np.searchsorted(t, 0.5), 1]      # cold copper: more current


def test_oil_profile_in_the_rig_is_the_valve_fed_the_same_oil(probe_rig):
    """A cold start (oil -20 degC warming to 40 degC over 0.4 s, duty 30 -> 70 %) on the rig's
    probe valve gives the pressure of the valve run alone (the emulator's device) with the same oil
    temperature set at the same control instants: the rig feeds the input and the spool's pole
    (the exponential step's rate) as the emulator's device does."""
    path, params, valve = probe_rig
    rig = Rig(params)
    scenario = _scenario(path, [{"t": 0.0, "oil_temperature": "-20 degC"},
                                {"t": 0.05, "duty": {"probe": 0.3}},
                                {"t": 0.1, "oil_temperature": {"ramp": {"to": "40 degC", "duration": "0.4 s"}}},
                                {"t": 0.3, "duty": {"probe": 0.7}}], 0.6)
    t, rows = _run(rig, scenario, ["probe.pressure", "probe.coil_temperature"], 10)
    st = at_rest(valve, 0.0)
    period = round(params.timing.control_period / rig.dt)
    p = [float(st.sim.x[3])]
    for step in range(1, round(0.6 / rig.dt) + 1):
        k = step - 1
        if k % period == 0:
            tk = k * rig.dt
            oil = -20.0 if tk < 0.1 - 1e-12 else -20.0 + 60.0 * min(1.0, (tk - 0.1) / 0.4)
            st.set_temperature(VALVE, "oil_temperature", kelvin(oil))
            if k == round(0.05 / rig.dt):
                put(st, "duty_cycle", 0.3)
            if k == round(0.3 / rig.dt):
                put(st, "duty_cycle", 0.7)
        advance(st, 1)
        if step % 10 == 0:
            p.append(float(st.sim.x[3]))
    alone = np.array(p)
    assert np.max(np.abs(rows[:, 0] - alone)) < 1e-3 * np.ptp(alone)
    cold_at = rows[np.searchsorted(t, 0.05 + 0.02), 0]     # 20 ms after the step, in oil at -20 degC
    warm = at_rest(valve, 0.0)               # the same step in oil at the YAML's 40 degC
    put(warm, "duty_cycle", 0.3)
    advance(warm, round(0.02 / rig.dt))
    assert abs(cold_at - float(warm.sim.x[3])) > 0.05 * float(warm.sim.x[3])    # the cold oil shows: a slower valve


def test_temperature_entries_are_checked(probe_rig):
    path, params, _ = probe_rig
    with pytest.raises(ScenarioError, match=r"valve left has no oil temperature input; .*fluid.temperature: input"):
        _scenario(path, [{"t": 0.0, "oil_temperature": {"left": "0 degC"}}], 1.0)
    with pytest.raises(ScenarioError, match="did you mean 40 degC"):
        _scenario(path, [{"t": 0.0, "ambient_temperature": 40}], 1.0)
    with pytest.raises(ScenarioError, match=r"ambient temperature .* in 213.15 .. 473.15"):
        _scenario(path, [{"t": 0.0, "ambient_temperature": "-100 degC"}], 1.0)
    with pytest.raises(ScenarioError, match="accepted for a temperature are K, degC"):
        _scenario(path, [{"t": 0.0, "ambient_temperature": "20 C"}], 1.0)
    rig = Rig(params)
    with pytest.raises(CommandError, match=r"no ambient temperature input; the valve YAML.s solenoid\.coil_temperature"):
        rig.set_temperature("left", "ambient_temperature", 300.0)
    with pytest.raises(CommandError, match="unit is K, not degC"):
        rig.set_temperature("probe", "oil_temperature", 20.0)
    # A profile for every valve with the input: only the probe has it, so one channel.
    sc = _scenario(path, [{"t": 0.0, "oil_temperature": {"sine": {"amplitude": "5 degC", "frequency": 1.0,
                                                                   "offset": "30 degC"}}}], 1.0)
    seg = sc.timeline[0]["oil_temperature"]["probe"]
    assert seg.amplitude == pytest.approx(5.0) and seg.value == pytest.approx(kelvin(30.0))   # a difference: no offset
    assert set(sc.timeline[0]["oil_temperature"]) == {"probe"}


def test_a_reset_restores_the_configured_temperatures(probe_rig):
    """A run that cooled the oil and the ambient leaves nothing behind: after a reset the inputs
    and the spool's pole are the YAML's again (a fault re-applied meanwhile keeps the cold pole)."""
    from pcv_sim.device.faults import Fault
    from pcv_sim.model import kernel

    _, params, _ = probe_rig
    rig = Rig(params)
    k = rig.valve_names.index("probe")
    off = rig.plant.offsets("p")[k]
    warm_rate = float(rig.sim.P[off + kernel.V_RATE])
    rig.set_temperature("probe", "oil_temperature", kelvin(-20.0))
    cold_rate = float(rig.sim.P[off + kernel.V_RATE])
    assert cold_rate > 50.0 * warm_rate
    rig.inject(Fault("contamination", "probe", {"area_factor": 0.5}))
    assert rig.sim.P[off + kernel.V_RATE] == cold_rate
    rig.set_temperature("probe", "ambient_temperature", kelvin(0.0))
    rig.reset()
    assert rig.sim.P[off + kernel.V_RATE] == warm_rate
    assert rig.temperature("probe", "oil_temperature") == pytest.approx(kelvin(40.0))
    assert rig.temperature("probe", "ambient_temperature") == pytest.approx(kelvin(40.0))


def test_scenario_with_a_cold_start_runs_and_reports_it(probe_rig):
    """`run_scenario` with temperature profiles: it runs (no error) and the events name them."""
    path, _, _ = probe_rig
    sc = _scenario(path, [{"t": 0.0, "oil_temperature": "-20 degC"},
                          {"t": 0.1, "oil_temperature": {"ramp": {"to": "40 degC", "duration": "0.2 s"}}},
                          {"t": 0.1, "ambient_temperature": "10 degC"}], 0.3)
    result = run_scenario(sc)
    assert result.error is None, result.summary()
    words = [w for _, w in result.events]
    assert any(w.startswith("oil temperature probe:") for w in words)
    assert any(w.startswith("ambient temperature probe:") for w in words)
