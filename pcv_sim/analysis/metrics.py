"""Step-response metrics and fit statistics, as pure functions of arrays."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
from scipy.signal import savgol_coeffs, savgol_filter

__all__ = ["NOISE_BAND_SIGMAS", "NOISE_FRACTION", "SETTLING_SIGMAS", "SETTLING_SMOOTH_SAMPLES", "SMOOTH_SAMPLES",
           "FitMetrics", "StepMetrics", "fit_metrics", "step_metrics"]


@dataclass(frozen=True)
class StepMetrics:
    """One step response. Times in s from the step instant; values in the signal's unit."""

    initial: float
    final: float                 # steady state: mean over the last `tail` of the window, or as given
    rise_time: float             # 10 % -> 90 % of the change (nan if never reached)
    overshoot_percent: float     # peak beyond final, % of the change (0 if none or within the noise)
    settling_time: float         # last exit from the band final +- band (nan if never settled)
    peak: float
    band: float = math.nan       # the settling band used (half-width, signal unit)
    noise: float = 0.0           # the noise level found (standard deviation, signal unit)
    # What the noise leaves open (noisy data; else both = settling_time): the settling time of the
    # noise-free response lies between these (nan: not settled for sure within the window).
    settling_early: float = math.nan
    settling_late: float = math.nan

    def as_dict(self) -> dict[str, float]:
        return asdict(self)


#: Noise above this fraction of the change switches step_metrics to its noise-robust reading.
NOISE_FRACTION = 1e-3
#: The settling band is at least this many standard deviations of the smoothed noise: white noise
#: leaves a 4 sigma band with probability 6e-5 per sample (one stray sample in ~16000), so it does
#: not set the settling time.
NOISE_BAND_SIGMAS = 4.0
#: Samples of the centred moving average that rise time and peak are read from on noisy data.
SMOOTH_SAMPLES = 5
#: Samples of the local quadratic fit the settling interval of noisy data is read from, and the
#: multiple of its noise that makes a sample surely outside / inside the band (synthetic noise of
#: 0.2-0.8 bar on the model's steps at 1 kHz: the clean settling time inside in every case).
SETTLING_SMOOTH_SAMPLES = 21
SETTLING_SIGMAS = 3.0


def _noise(y: np.ndarray) -> float:
    """White-noise standard deviation from sample-to-sample differences: 1.4826 MAD(diff)/sqrt 2."""
    d = np.diff(y)
    if d.size < 2:
        return 0.0
    return float(1.4826 * np.median(np.abs(d - np.median(d))) / math.sqrt(2.0))


def step_metrics(
    t: np.ndarray, y: np.ndarray, t_step: float, t_end: float | None = None, *,
    band_fraction: float = 0.02, band_min: float = 0.0, tail: float = 0.1, final: float | None = None,
    robust: bool = True,
) -> StepMetrics:
    """Metrics of the response y(t) to a step at t_step, within [t_step, t_end].

    The settling band is max(band_fraction * |change|, band_min), so a tiny step is not judged
    by noise. `initial` is the last sample before the step. `final` (e.g. the static solution)
    replaces the window's tail mean as the steady state.

    Noise (``robust``): the noise level sigma is read from the window's sample-to-sample
    differences. When it exceeds NOISE_FRACTION of the change (measured data; a model's trace
    has none), rise time, peak and settling are read from a centred moving average of
    SMOOTH_SAMPLES samples (noise sigma / sqrt(5)), the band widens to at least
    NOISE_BAND_SIGMAS of that sigma, an overshoot within it is noise and reported as 0, and
    `initial` is the mean of the last 20 samples before the step. Settling is then known only
    within [settling_early, settling_late]: the last exits of a local quadratic fit beyond
    band +- SETTLING_SIGMAS of its noise (a comparison with a clean response takes the distance).
    """
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    t_end = float(t[-1]) if t_end is None else t_end
    before = t < t_step
    win = (t >= t_step) & (t <= t_end)
    tw, yw = t[win] - t_step, y[win]
    n_tail = max(1, round(tail * len(yw)))
    final = float(np.mean(yw[-n_tail:])) if final is None else float(final)
    initial = float(y[before][-1]) if before.any() else float(y[0])
    sigma = _noise(yw) if robust else 0.0
    noisy = sigma > NOISE_FRACTION * abs(final - initial)
    if noisy and before.any():
        initial = float(np.mean(y[before][-20:]))
    change = final - initial
    sign = 1.0 if change >= 0 else -1.0
    sigma_smooth = sigma / math.sqrt(SMOOTH_SAMPLES)
    band = max(band_fraction * abs(change), band_min, NOISE_BAND_SIGMAS * sigma_smooth if noisy else 0.0)
    if abs(change) == 0.0:
        return StepMetrics(initial, final, math.nan, 0.0, 0.0, float(yw.max()), band, sigma, 0.0, 0.0)
    ys = yw
    if noisy and len(yw) >= SMOOTH_SAMPLES:
        k = SMOOTH_SAMPLES // 2
        padded = np.concatenate([np.full(k, yw[0]), yw, np.full(k, yw[-1])])
        ys = np.convolve(padded, np.ones(SMOOTH_SAMPLES) / SMOOTH_SAMPLES, mode="valid")
    rel = (ys - initial) / change

    def first_cross(level: float) -> float:
        idx = np.nonzero(rel >= level)[0]
        if not idx.size:
            return math.nan
        k = int(idx[0])
        if k == 0:
            return float(tw[0])
        # Linear interpolation between the samples around the crossing.
        r0, r1 = rel[k - 1], rel[k]
        return float(tw[k - 1] + (level - r0) / (r1 - r0) * (tw[k] - tw[k - 1]))

    rise = first_cross(0.9) - first_cross(0.1)
    peak = float(ys.max() if sign > 0 else ys.min())
    excess = (peak - final) * sign
    if noisy and excess <= NOISE_BAND_SIGMAS * sigma_smooth:
        excess = 0.0
    overshoot = max(0.0, excess / abs(change) * 100.0)
    dev = np.abs(ys - final)
    settling = _last_exit(tw, dev, band)
    early = late = settling
    if noisy and len(yw) > SETTLING_SMOOTH_SAMPLES:
        # Where the response is within the noise of the band's edge, the data cannot say whether
        # the clean one is in or out (a peak grazing the edge moves the last exit by tens of ms).
        # Read from a local quadratic fit over SETTLING_SMOOTH_SAMPLES (Savitzky-Golay): surely
        # outside beyond band + SETTLING_SIGMAS of its noise, surely inside within band - that.
        coeffs = savgol_coeffs(SETTLING_SMOOTH_SAMPLES, 2)
        margin = SETTLING_SIGMAS * sigma * math.sqrt(float(coeffs @ coeffs))
        fitted = np.abs(savgol_filter(yw, SETTLING_SMOOTH_SAMPLES, 2, mode="interp") - final)
        early = _last_exit(tw, fitted, band + margin)
        late = _last_exit(tw, fitted, band - margin) if band > margin else math.nan
    return StepMetrics(initial, final, rise, overshoot, settling, peak, band, sigma, early, late)


def _last_exit(tw: np.ndarray, dev: np.ndarray, level: float) -> float:
    """The first time after the last sample with dev > level (0 if none, nan if it is the last)."""
    outside = np.nonzero(dev > level)[0]
    if not outside.size:
        return 0.0
    if outside[-1] == len(dev) - 1:
        return math.nan
    return float(tw[outside[-1] + 1])


@dataclass(frozen=True)
class FitMetrics:
    rmse: float
    max_error: float
    nrmse_fit_percent: float     # 100 (1 - ||y - y_hat|| / ||y - mean(y)||), as MATLAB's compare()

    def as_dict(self) -> dict[str, float]:
        return asdict(self)


def fit_metrics(measured: np.ndarray, model: np.ndarray) -> FitMetrics:
    measured = np.asarray(measured, dtype=float)
    model = np.asarray(model, dtype=float)
    err = model - measured
    rmse = float(np.sqrt(np.mean(err**2)))
    spread = float(np.linalg.norm(measured - measured.mean()))
    fit = 100.0 * (1.0 - float(np.linalg.norm(err)) / spread) if spread > 0 else (100.0 if rmse == 0 else -math.inf)
    return FitMetrics(rmse, float(np.max(np.abs(err))), fit)
