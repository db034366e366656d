"""Step-response metrics and fit statistics, as pure functions of arrays."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

__all__ = ["StepMetrics", "step_metrics", "FitMetrics", "fit_metrics"]


@dataclass(frozen=True)
class StepMetrics:
    """One step response. Times in s from the step instant; values in the signal's unit."""

    initial: float
    final: float                 # steady state: mean over the last `tail` of the window
    rise_time: float             # 10 % -> 90 % of the change (nan if never reached)
    overshoot_percent: float     # peak beyond final, % of the change (0 if none)
    settling_time: float         # last exit from the band final +- band (nan if never settled)
    peak: float

    def as_dict(self) -> dict[str, float]:
        return asdict(self)


def step_metrics(
    t: np.ndarray, y: np.ndarray, t_step: float, t_end: float | None = None, *,
    band_fraction: float = 0.02, band_min: float = 0.0, tail: float = 0.1,
) -> StepMetrics:
    """Metrics of the response y(t) to a step at t_step, within [t_step, t_end].

    The settling band is max(band_fraction * |change|, band_min), so a tiny step is not
    judged by noise. `initial` is the last sample before the step.
    """
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    t_end = float(t[-1]) if t_end is None else t_end
    before = t < t_step
    initial = float(y[before][-1]) if before.any() else float(y[0])
    win = (t >= t_step) & (t <= t_end)
    tw, yw = t[win] - t_step, y[win]
    n_tail = max(1, int(round(tail * len(yw))))
    final = float(np.mean(yw[-n_tail:]))
    change = final - initial
    sign = 1.0 if change >= 0 else -1.0
    if abs(change) == 0.0:
        return StepMetrics(initial, final, math.nan, 0.0, 0.0, float(yw.max()))
    rel = (yw - initial) / change
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
    peak = float(yw.max() if sign > 0 else yw.min())
    overshoot = max(0.0, (peak - final) * sign / abs(change) * 100.0)
    band = max(band_fraction * abs(change), band_min)
    outside = np.nonzero(np.abs(yw - final) > band)[0]
    if not outside.size:
        settling = 0.0
    elif outside[-1] == len(yw) - 1:
        settling = math.nan
    else:
        settling = float(tw[outside[-1] + 1])
    return StepMetrics(initial, final, rise, overshoot, settling, peak)


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
