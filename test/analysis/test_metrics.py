"""pcv_sim.analysis.metrics on responses whose metrics are known in closed form."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pcv_sim.analysis.metrics import fit_metrics, step_metrics

DT = 1e-5   # s, sampling of the synthetic responses; tolerances below are a few samples


def first_order(tau: float, t_step: float, t_end: float, gain: float = 1.0, offset: float = 0.0):
    t = np.arange(0.0, t_end, DT)
    y = offset + gain * np.where(t >= t_step, 1.0 - np.exp(-(t - t_step) / tau), 0.0)
    return t, y


def test_first_order_rise_and_settling() -> None:
    tau, t_step = 0.01, 0.02
    t, y = first_order(tau, t_step, t_step + 30 * tau, gain=50e5, offset=70e5)
    m = step_metrics(t, y, t_step)
    assert m.initial == 70e5
    assert m.final == pytest.approx(120e5, rel=1e-9)            # exp(-27) of the change in the tail
    # 10 % at tau ln(10/9), 90 % at tau ln 10: rise = tau ln 9 (interpolated: error << DT).
    assert m.rise_time == pytest.approx(tau * math.log(9.0), abs=DT / 10)
    # No overshoot: only the tail mean's exp(-27) shortfall shows (~1e-10 %).
    assert m.overshoot_percent == pytest.approx(0.0, abs=1e-6)
    # |y - final| = change * exp(-t/tau) <= 2 % from t = tau ln 50: the settling time is the first
    # sample inside the band, so within one sample after tau ln 50 (not before it).
    assert tau * math.log(50.0) - 1e-9 <= m.settling_time <= tau * math.log(50.0) + DT
    assert m.peak == pytest.approx(120e5, rel=1e-9)


def test_first_order_step_down() -> None:
    tau, t_step = 0.004, 0.01
    t, y = first_order(tau, t_step, t_step + 30 * tau, gain=-2.0, offset=3.0)
    m = step_metrics(t, y, t_step)
    assert (m.initial, m.final) == (3.0, pytest.approx(1.0, rel=1e-9))
    assert m.rise_time == pytest.approx(tau * math.log(9.0), abs=DT / 10)
    assert m.overshoot_percent == pytest.approx(0.0, abs=1e-6)
    assert tau * math.log(50.0) - 1e-9 <= m.settling_time <= tau * math.log(50.0) + DT
    assert m.peak == pytest.approx(1.0, rel=1e-9)               # the minimum for a step down


@pytest.mark.parametrize("zeta", [0.1, 0.3, 0.6])
@pytest.mark.parametrize("direction", [1.0, -1.0])
def test_second_order_overshoot(zeta: float, direction: float) -> None:
    """y = 1 - exp(-zeta wn t) / sqrt(1 - zeta^2) sin(wd t + acos zeta): peak overshoot
    100 exp(-zeta pi / sqrt(1 - zeta^2)) % at t_p = pi / wd."""
    wn, t_step = 2 * math.pi * 50.0, 0.005
    wd = wn * math.sqrt(1 - zeta**2)
    t = np.arange(0.0, t_step + 60.0 / (zeta * wn), DT)
    tau = np.clip(t - t_step, 0.0, None)
    unit = 1.0 - np.exp(-zeta * wn * tau) / math.sqrt(1 - zeta**2) * np.sin(wd * tau + math.acos(zeta))
    y = 10.0 + direction * 4.0 * unit
    m = step_metrics(t, y, t_step)
    expected = 100.0 * math.exp(-zeta * math.pi / math.sqrt(1 - zeta**2))
    # Sampling at DT can miss the true peak by (wd DT)^2/2 of the oscillation: < 0.01 %-points here.
    assert m.overshoot_percent == pytest.approx(expected, abs=0.01)
    assert m.peak == pytest.approx(10.0 + direction * 4.0 * (1 + expected / 100), abs=1e-3)
    # Settling: the envelope exp(-zeta wn t)/sqrt(1-zeta^2) bounds it from above.
    assert m.settling_time <= math.log(50.0 / math.sqrt(1 - zeta**2)) / (zeta * wn) + DT


def test_no_change_and_never_settled() -> None:
    t = np.arange(0.0, 1.0, 1e-3)
    flat = step_metrics(t, np.full_like(t, 5.0), 0.1)
    assert math.isnan(flat.rise_time) and flat.overshoot_percent == 0.0 and flat.settling_time == 0.0
    # Settled except the last sample, which leaves the band: "never settled" is nan.
    y = np.where(t >= 0.1, 1.0, 0.0)
    y[-1] = 1.5
    m = step_metrics(t, y, 0.1)
    assert math.isnan(m.settling_time)
    # An ideal step: already inside the band at the step instant.
    y[-1] = 1.0
    ideal = step_metrics(t, y, 0.1)
    assert ideal.settling_time == 0.0 and ideal.rise_time == 0.0 and ideal.overshoot_percent == 0.0


def test_band_min_ignores_small_noise() -> None:
    t, y = first_order(0.002, 0.01, 0.2, gain=1e-3)
    noisy = y + np.where(t > 0.1, 5e-5 * np.sin(2 * np.pi * 300 * t), 0.0)   # 5 % of the change
    # The 2 % band (2e-5) is narrower than the noise (5e-5): "settled" only after the last noise
    # excursion, late in the window (the noise starts at 0.1 s, 0.09 s after the step).
    assert step_metrics(t, noisy, 0.01).settling_time > 0.09
    # A 1e-4 floor on the band ignores it: settled where the clean response enters 1e-4 of 1e-3,
    # tau ln 10 = 4.6 ms after the step.
    loose = step_metrics(t, noisy, 0.01, band_min=1e-4)
    assert loose.settling_time == pytest.approx(0.002 * math.log(10.0), abs=0.1e-3)


def test_fit_metrics() -> None:
    measured = np.array([0.0, 1.0, 2.0, 3.0])
    perfect = fit_metrics(measured, measured)
    assert (perfect.rmse, perfect.max_error, perfect.nrmse_fit_percent) == (0.0, 0.0, 100.0)
    mean = fit_metrics(measured, np.full(4, measured.mean()))
    assert mean.nrmse_fit_percent == pytest.approx(0.0, abs=1e-12)
    # Offset by 0.5: rmse 0.5, max 0.5, fit 100 (1 - ||0.5||/||m - 1.5||) = 100 (1 - 1/sqrt(5)) = 55.28 %.
    off = fit_metrics(measured, measured + 0.5)
    assert off.rmse == pytest.approx(0.5, rel=1e-12)
    assert off.max_error == pytest.approx(0.5, rel=1e-12)
    assert off.nrmse_fit_percent == pytest.approx(100 * (1 - 1 / math.sqrt(5)), rel=1e-12)
    # A constant measurement: 100 % only if matched, else -inf (no spread to normalise by).
    assert fit_metrics(np.ones(3), np.ones(3)).nrmse_fit_percent == 100.0
    assert fit_metrics(np.ones(3), np.ones(3) * 1.1).nrmse_fit_percent == -math.inf
    assert set(off.as_dict()) == {"rmse", "max_error", "nrmse_fit_percent"}


def test_noise_does_not_set_the_settling_time() -> None:
    """A first-order 70 -> 120 bar step (tau = 19.7 ms: 2 % settling at tau ln 50 = 77 ms) seen by a
    1 kHz sensor with 1 bar of white noise: read naively, noise keeps leaving the 1 bar (2 %) band
    until late in the window. The robust reading smooths over 5 samples (sigma 0.45 bar), widens
    the band to 4 of that sigma (1.8 bar) and settles where the noiseless response enters it,
    tau ln(50 bar / band), plus the time the smoothed noise needs to stop crossing the band's
    edge (while the response is within ~2.5 of its sigma of it)."""
    rng = np.random.default_rng(7)
    tau, t_step = 0.0197, 0.05
    t = np.arange(0.0, 0.55, 1e-3)
    clean = 70e5 + 50e5 * np.where(t >= t_step, 1.0 - np.exp(-(t - t_step) / tau), 0.0)
    noisy = clean + rng.normal(0.0, 1e5, t.size)
    naive = step_metrics(t, noisy, t_step, robust=False)
    m = step_metrics(t, noisy, t_step)
    assert m.noise == pytest.approx(1e5, rel=0.15)
    sigma_smooth = m.noise / math.sqrt(5)
    assert m.band == pytest.approx(4.0 * sigma_smooth, rel=1e-12)
    expected = tau * math.log(50e5 / m.band)
    late = tau * math.log(m.band / (m.band - 2.5 * sigma_smooth))
    assert expected - 0.002 <= m.settling_time <= expected + late
    assert naive.settling_time > 0.15 or math.isnan(naive.settling_time)
    # No overshoot in a first-order response: the noisy peak is not taken for one.
    assert naive.overshoot_percent > 1.0
    assert m.overshoot_percent == 0.0
    # The 10-90 % rise time (tau ln 9 = 43 ms) from the smoothed trace, within 3 samples.
    assert m.rise_time == pytest.approx(tau * math.log(9.0), abs=3e-3)
    assert m.initial == pytest.approx(70e5, abs=0.6e5)


def test_noise_keeps_a_real_overshoot() -> None:
    # An underdamped response (zeta 0.3: 37 % overshoot) with noise at 1 % of the change.
    rng = np.random.default_rng(3)
    zeta, wn, t_step = 0.3, 200.0, 0.02
    t = np.arange(0.0, 0.4, 1e-3)
    s = np.clip(t - t_step, 0.0, None)
    wd = wn * math.sqrt(1 - zeta**2)
    clean = 1.0 - np.exp(-zeta * wn * s) * (np.cos(wd * s) + zeta / math.sqrt(1 - zeta**2) * np.sin(wd * s))
    m = step_metrics(t, clean + rng.normal(0.0, 0.01, t.size), t_step)
    truth = 100.0 * math.exp(-zeta * math.pi / math.sqrt(1 - zeta**2))
    assert m.overshoot_percent == pytest.approx(truth, abs=3.0)   # the 5-sample average trims the peak a little


def test_given_final_replaces_the_window_end() -> None:
    # A window that ends before the response settles: the tail mean is short of the steady state.
    t, y = first_order(0.05, 0.0, 0.13, gain=1.0)
    short = step_metrics(t, y, 0.0)
    given = step_metrics(t, y, 0.0, final=1.0)
    assert short.final < 0.95 and given.final == 1.0
    assert math.isnan(given.settling_time) and given.rise_time == pytest.approx(0.05 * math.log(9.0), abs=DT)
