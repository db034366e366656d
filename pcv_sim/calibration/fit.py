"""Fit named valve parameters to recorded bags: bounded, robust nonlinear least squares.

The model (``run_model``, the same engine as ``replay``) is driven by each recording's inputs.
Each measured output y_m of bag b is compared with the model's y through a sensor with a delay
tau_r and a first-order time constant T_r (per signal, shared by the bags: one rig) and an
offset c_br (per signal and bag):

    y_m(t) = F_T[y](t - tau_r) + c_br + noise,   residual = (F_T[y](t - tau_r) + c_br - y_m(t)) / sigma_br

F_T is the first-order low pass T dy_f/dt = y - y_f (:func:`first_order`; T = 0: none), so a
sensor that lags by a dead time, by a time constant, or both is described.

sigma_br is the noise level of the recording, estimated from its sample-to-sample differences
(:func:`noise_level`; at least 1e-3 of the signal's span, so a noiseless or quantised signal does
not outweigh the others), so every signal counts by what it can tell. The valve parameters theta
(any scalar key of the valve YAML) and the nuisance parameters (tau, c) are found by
``scipy.optimize.least_squares`` (trust region reflective, bounds, the ``soft_l1`` robust loss
with f_scale = 3 sigma, so broken samples and spikes do not pull the fit).

Jacobian: forward differences of the model for theta (one simulation per parameter; the fixed
step makes the outputs smooth in theta), analytic for the nuisance parameters
(d/dtau = -dy/dt, d/dc = 1; d/dT by a forward difference of the filter, which needs no run).

Intervals: cov = s^2 (J^T J)^-1 with s^2 = sum(r^2) / (m - n) of the weighted residuals, inflated
by (1 + rho) / (1 - rho) where rho > 0 is the lag-1 autocorrelation of the residuals (what is left
of model error makes neighbouring samples agree: they then count as fewer independent ones).
Approximate 95 % interval: +-1.96 sqrt(diag(cov)). Parameters whose correlation exceeds
:data:`CORRELATION_LIMIT`, whose interval is wider than the value, or that end on a bound are
reported as not separable by the data; so is a parameter whose Jacobian column does not hold over
a 10x larger step (the outputs are not smooth in it, and the interval, a local slope's, means
nothing: e.g. the core's mass, which acts only through the contact's events, R35).
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
import numpy.typing as npt
from scipy.optimize import least_squares

from pcv_sim.errors import ParameterError, PcvSimError
from pcv_sim.io.topics import CURRENT, OUTPUT_ROLES, PRESSURE, ROLE_UNITS, SPOOL_POSITION
from pcv_sim.params import ValveParams, replace_param
from pcv_sim.replay.compare import DISPLAY
from pcv_sim.replay.errors import ReplayError
from pcv_sim.replay.recording import Recording, Series
from pcv_sim.replay.simulate import InputTimeline, Solver, input_timeline, run_model
from pcv_sim.units import NS_PER_S, PA_PER_BAR

__all__ = [
    "CORRELATION_LIMIT",
    "CalibrationError",
    "CalibrationResult",
    "Estimate",
    "FitParameter",
    "SignalFit",
    "Suggestion",
    "calibrate",
    "first_order",
    "fit_parameter",
    "noise_level",
]

CORRELATION_LIMIT = 0.95
#: Default sensor-delay bounds (s): a sensor cannot answer before the valve does, by more than a sample.
LAG_BOUNDS = (-0.002, 0.05)
#: Default bounds of the sensor's first-order time constant (s).
TIME_CONSTANT_BOUNDS = (0.0, 0.03)
_FD_STEP = 1e-3          # relative forward-difference step of the valve parameters
_ROUGH_STEP = 10.0       # the smoothness check's step, in forward-difference steps
_ROUGH_LIMIT = 0.3       # relative difference of the two Jacobian columns beyond which a parameter's slope is not one
#: A signal whose RMSE after the fit exceeds this many times its noise level (estimated from the
#: recording) is not explained by the model: a right model leaves the noise (about 1x).
NOISE_RATIO_LIMIT = 1.5
#: Sensor offsets larger than these (SI) are more than a sensor's zero error: they likely absorb a
#: model error (a pressure transducer's zero is within ~0.5 % of 200 bar, a current shunt's within
#: tens of mA, a position sensor's within tens of um).
PLAUSIBLE_OFFSET = {PRESSURE: 1.0 * PA_PER_BAR, CURRENT: 0.03, SPOOL_POSITION: 20e-6}
#: A sensor delay plus time constant above this (s) is slower than a valve's pressure, current or
#: position sensor: it likely absorbs a model's slow dynamics.
PLAUSIBLE_LAG = 0.01
#: Parameters checked against what the fit leaves (the ones that differ from valve to valve or with
#: the oil and the circuit); those not fitted whose effect matches the residual are named.
CANDIDATES = ("solenoid.coil_resistance", "solenoid.supply_voltage", "spool.mass", "spool.spring_stiffness",
              "spool.spring_preload", "spool.viscous_friction_simplified", "spool.viscous_friction",
              "orifice.gap_height", "fluid.bulk_modulus", "fluid.kinematic_viscosity", "circuit.load_volume",
              "circuit.supply_pressure", "calibration.net_area", "damping.restrictor_conductance")
#: A candidate is named when adding it alone would explain at least this share of the residual's
#: sum of squares beyond what the fitted parameters and sensors already can.
SUGGEST_SHARE = 0.2
_Z95 = 1.959963984540054


class CalibrationError(PcvSimError, ValueError):
    """A calibration cannot be set up or run as asked (keys, bounds, recordings)."""


@dataclass(frozen=True)
class FitParameter:
    """One valve parameter to fit: its YAML path, start value and bounds (SI, as in the YAML)."""

    key: str
    initial: float
    lower: float
    upper: float
    unit: str

    @property
    def scale(self) -> float:
        """The unit of the fit's internal coordinate: |initial|, or the bound width if 0."""
        return abs(self.initial) if self.initial != 0.0 else (self.upper - self.lower) / 2.0


def _scalar_fields(params: ValveParams) -> dict[str, dataclasses.Field[Any]]:
    out = {}
    for section in dataclasses.fields(params):
        for f in dataclasses.fields(getattr(params, section.name)):
            if f.metadata.get("kind") in ("float", "float_or_null", "float_or_equivalent"):
                out[f"{section.name}.{f.name}"] = f
    return out


def fit_parameter(params: ValveParams, spec: str) -> FitParameter:
    """Parse ``section.key`` or ``section.key=LOW:HIGH`` into a FitParameter.

    The start is the value in force (``equivalent`` damping and a ``null`` net area as their
    numbers). Default bounds: initial / 4 .. initial * 4 for a positive quantity, initial +- 3
    max(|initial|, 1) for a signed one, 0..1 for a fraction. Refuses vectors, text, unknown keys.
    """
    key, _, bounds = spec.strip().partition("=")
    key = key.strip()
    fields = _scalar_fields(params)
    if key not in fields:
        section = key.partition(".")[0]
        near = [k for k in fields if k.startswith(section + ".")] or sorted(fields)
        msg = (f"--fit {key!r}: not a scalar parameter of the valve YAML; accepted are scalar keys "
               f"named by their path, e.g. spool.spring_preload; in {section!r}: {', '.join(near)}")
        raise CalibrationError(msg)
    f = fields[key]
    section, _, name = key.partition(".")
    value = getattr(getattr(params, section), name)
    if key == "calibration.net_area" and value is None:
        value = params.net_area
    elif key == "spool.viscous_friction_simplified" and value == "equivalent":
        value = params.equivalent_damping
    elif value is None:
        msg = f"--fit {key}: the config has null (off) here; give it a start value in the YAML first"
        raise CalibrationError(msg)
    x0 = float(value)
    check_name = getattr(f.metadata["check"], "__name__", "")
    if bounds:
        lo_text, sep, hi_text = bounds.partition(":")
        try:
            lo, hi = float(lo_text), float(hi_text)
        except ValueError:
            lo = hi = math.nan
        if not sep or not (math.isfinite(lo) and math.isfinite(hi)) or not lo < hi:
            msg = f"--fit {spec!r}: bounds are KEY=LOW:HIGH with finite LOW < HIGH, e.g. {key}={x0 / 2:g}:{x0 * 2:g}"
            raise CalibrationError(msg)
        for name_, bound in (("LOW", lo), ("HIGH", hi)):   # a bound is a value the fit may try
            problem = f.metadata["check"](bound)
            if problem is not None:
                msg = f"--fit {spec!r}: {name_} = {bound:g} {f.metadata['unit']} is not a value of {key}; accepted is {problem}"
                raise CalibrationError(msg)
        if not lo <= x0 <= hi:
            msg = f"--fit {spec!r}: the start value {x0:g} (from the config) lies outside {lo:g}..{hi:g}"
            raise CalibrationError(msg)
    elif hasattr(f.metadata["check"], "lo"):        # a plausible physical range: stay inside it
        r_lo, r_hi = f.metadata["check"].lo, f.metadata["check"].hi
        lo, hi = (x0 / 4.0, x0 * 4.0) if x0 > 0 and r_lo >= 0 else (x0 - 3.0 * max(abs(x0), 1.0), x0 + 3.0 * max(abs(x0), 1.0))
        lo, hi = max(lo, r_lo), min(hi, r_hi)
    elif check_name in ("_positive", "_non_negative") and x0 > 0:
        lo, hi = x0 / 4.0, x0 * 4.0
    elif check_name == "_fraction":
        lo, hi = 0.0, 1.0
    else:
        width = 3.0 * max(abs(x0), 1.0)
        lo, hi = x0 - width, x0 + width
    if key == "calibration.net_area":  # 0 < net area < A_c (ValveParams)
        hi = min(hi, params.spool.pressure_area * (1 - 1e-9))
    return FitParameter(key, x0, lo, hi, f.metadata["unit"])


def first_order(t: npt.NDArray[np.float64], u: npt.NDArray[np.float64], tau: float) -> npt.NDArray[np.float64]:
    """A first-order sensor, T dy/dt = u - y, started at rest (y(t0) = u(t0)), exact for u
    piecewise linear between the samples t (s, increasing, any spacing): with a = exp(-h/T) and
    s the slope over h, y_k = u_k - s T + (y_{k-1} - u_{k-1} + s T) a. T <= 0 returns u."""
    if tau <= 0.0 or len(u) < 2:
        return np.asarray(u, dtype=float)
    h = np.diff(t)
    a = np.exp(-h / tau)
    b = np.diff(u) / h * tau * (a - 1.0)     # w_k = y_k - u_k obeys w_k = a w_{k-1} + b
    w = np.empty(len(u))
    w[0] = 0.0
    acc = 0.0
    for k in range(1, len(u)):
        acc = a[k - 1] * acc + b[k - 1]
        w[k] = acc
    return np.asarray(u, dtype=float) + w


def noise_level(values: npt.NDArray[np.float64]) -> float:
    """The white-noise standard deviation of a sampled signal, from its sample-to-sample
    differences: 1.4826 MAD(diff y) / sqrt(2) (robust: steps and slopes barely move it)."""
    d = np.diff(np.asarray(values, dtype=float))
    if d.size < 2:
        return 0.0
    return float(1.4826 * np.median(np.abs(d - np.median(d))) / math.sqrt(2.0))


@dataclass(frozen=True)
class Estimate:
    """A fitted value with its approximate 95 % interval half-width (SI)."""

    name: str
    value: float
    initial: float
    half_width_95: float
    unit: str
    lower: float = -math.inf
    upper: float = math.inf

    @property
    def at_bound(self) -> bool:
        span = self.upper - self.lower
        return math.isfinite(span) and min(self.value - self.lower, self.upper - self.value) < 1e-6 * span

    def as_dict(self) -> dict[str, Any]:
        return {"name": self.name, "value": self.value, "initial": self.initial,
                "interval_95": [self.value - self.half_width_95, self.value + self.half_width_95],
                "half_width_95": self.half_width_95, "unit": self.unit, "bounds": [self.lower, self.upper],
                "at_bound": self.at_bound}


@dataclass(frozen=True)
class SignalFit:
    """One signal of one bag: noise level and the fit before and after (NRMSE fit %, RMSE in SI)."""

    bag: str
    role: str
    samples: int
    noise_sigma: float
    fit_before_percent: float
    fit_after_percent: float
    rmse_before: float
    rmse_after: float


@dataclass(frozen=True)
class Suggestion:
    """A parameter not fitted whose effect matches what the fit left: adding it alone (linearised
    at the fitted values) would explain ``share`` of the residual's sum of squares, with the value
    moved by ``relative_change`` (e.g. +0.15: 15 % up)."""

    key: str
    share: float
    value: float
    relative_change: float
    unit: str

    def as_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class CalibrationResult:
    """What ``calibrate`` found. ``params`` is the fitted parameter set (nuisance excluded)."""

    params: ValveParams
    initial_params: ValveParams
    parameters: tuple[Estimate, ...]
    lags: tuple[Estimate, ...]               # sensor delays
    time_constants: tuple[Estimate, ...]     # sensors' first-order time constants
    offsets: tuple[Estimate, ...]
    correlation: npt.NDArray[np.float64]     # among the fitted valve parameters
    signals: tuple[SignalFit, ...]
    model: str
    solver: str
    evaluations: int
    simulations: int
    elapsed_s: float
    cost_before: float
    cost_after: float
    autocorrelation: float                   # rho of the residuals (interval inflation (1+rho)/(1-rho))
    status: str
    status_code: int                         # least_squares' status: > 0 converged, 0 out of evaluations
    warnings: tuple[str, ...] = ()
    traces: Mapping[tuple[int, str], tuple[npt.NDArray[np.float64], ...]] = field(default_factory=dict, repr=False)
    suggestions: tuple[Suggestion, ...] = ()  # parameters whose effect matches the residual, best first

    def scalar_metrics(self) -> dict[str, float]:
        """After the fit, per signal over the bags: the worst NRMSE fit % and RMSE, in display
        units, keyed as replay's metrics (``pressure_fit_percent``, ``pressure_rmse_bar``, ...)."""
        units = {role: (d.key_unit, d.scale) for role, d in DISPLAY.items()}
        out: dict[str, float] = {}
        for s in self.signals:
            unit, scale = units[s.role]
            fit_key, rmse_key = f"{s.role}_fit_percent", f"{s.role}_rmse_{unit}"
            out[fit_key] = min(out.get(fit_key, math.inf), s.fit_after_percent)
            out[rmse_key] = max(out.get(rmse_key, -math.inf), s.rmse_after * scale)
        return out

    def as_dict(self) -> dict[str, Any]:
        return {
            "metrics_after": self.scalar_metrics(),
            "model": self.model, "solver": self.solver, "status": self.status, "status_code": self.status_code,
            "evaluations": self.evaluations, "simulations": self.simulations, "elapsed_s": self.elapsed_s,
            "cost_before": self.cost_before, "cost_after": self.cost_after,
            "residual_autocorrelation": self.autocorrelation,
            "parameters": [e.as_dict() for e in self.parameters],
            "sensor_lags_s": [e.as_dict() for e in self.lags],
            "sensor_time_constants_s": [e.as_dict() for e in self.time_constants],
            "sensor_offsets": [e.as_dict() for e in self.offsets],
            "correlation": {"keys": [e.name for e in self.parameters], "matrix": self.correlation.tolist()},
            "signals": [dataclasses.asdict(s) for s in self.signals],
            "warnings": list(self.warnings),
            "suggestions": [x.as_dict() for x in self.suggestions],
            "units": "SI: Pa, A, m, s; parameters in the unit of their YAML key",
        }


@dataclass(frozen=True)
class _Data:
    """A measured signal of bag number `bag` to fit, weighed by its noise `sigma` (SI)."""

    bag: int
    series: Series
    sigma: float


def _timeline(rec: Recording, params: ValveParams) -> InputTimeline:
    tl, _ = input_timeline(rec.inputs, 0.0, params.circuit.supply_pressure)
    return tl


def calibrate(
    recordings: Sequence[Recording],
    params: ValveParams,
    fit: Sequence[FitParameter],
    *,
    model: Literal["full", "simplified"] = "simplified",
    solver: Solver = "auto",
    roles: Sequence[str] | None = None,
    lag_bounds: tuple[float, float] | None = LAG_BOUNDS,
    time_constant_bounds: tuple[float, float] | None = TIME_CONSTANT_BOUNDS,
    fit_offsets: bool = True,
    max_evaluations: int = 100,
    grid_step: float = 1e-4,
    progress: Callable[[int, float, float], None] | None = None,
) -> CalibrationResult:
    """Fit ``fit`` (and each signal's sensor lag and offset) to ``recordings``; see the module doc.

    An empty ``fit`` estimates the sensors only: how well the valve as configured explains the
    recordings once the rig's lag and offset are taken out (a pass/fail check of a valve).

    ``roles``: the outputs to fit (default: every output the bags have). ``lag_bounds=None``
    fixes the delays at 0, ``time_constant_bounds=None`` the sensors' time constants,
    ``fit_offsets=False`` the offsets. ``grid_step`` (s): the model is also sampled on this grid
    from 0.5 ms before to 1.5 ms after each duty step, for the lagged comparison.
    ``progress(evaluation, cost, elapsed_s)`` is called after each model evaluation.

    Raises:
        CalibrationError: no recording or signal, nothing to fit, a key named twice, or the
            model refusing a trial value (narrow that parameter's bounds).
    """
    if not recordings:
        raise CalibrationError("no recording to calibrate against")
    keys = [p.key for p in fit]
    if len(set(keys)) != len(keys):
        raise CalibrationError(f"--fit names a parameter twice: {keys}")
    wanted = tuple(roles) if roles else OUTPUT_ROLES
    for rec in recordings if roles else ():   # a signal asked for by name is never dropped in silence
        missing = [r for r in wanted if r not in rec.measured or len(rec.measured[r]) < 3]
        if missing:
            has = [r for r in OUTPUT_ROLES if r in rec.measured and len(rec.measured[r]) >= 3]
            msg = (f"--signals {','.join(missing)}: {rec.path} does not record {', '.join(missing)} (it has "
                   f"{', '.join(has) or 'no output'}); accepted are the signals every bag records"
                   f"{' (' + ','.join(has) + ')' if has else ''}, or --topic ROLE=/TOPIC where it is under another name")
            raise CalibrationError(msg)
    data: list[_Data] = []
    for b, rec in enumerate(recordings):
        for role in wanted:
            if role in rec.measured and len(rec.measured[role]) >= 3:
                s = rec.measured[role]
                span = float(np.ptp(s.value))
                sigma = max(noise_level(s.value), 1e-3 * span, 1e-12)
                data.append(_Data(b, s, sigma))
    if not data:
        raise CalibrationError(f"the recordings hold none of the signals to fit ({', '.join(wanted)})")
    # The model at every sample, and on a grid of grid_step around each input change: y(t - lag)
    # is interpolated from these, so a lag between two samples of the current's jump at a duty
    # step (R27) is not smeared; elsewhere the response is smooth at the sample spacing.
    step_ns = round(grid_step * NS_PER_S)
    around = np.arange(-5, 16, dtype=np.int64) * step_ns
    sample_ns = []
    for b, rec in enumerate(recordings):
        times = [d.series.t_ns for d in data if d.bag == b]
        if not times:
            sample_ns.append(np.zeros(0, np.int64))
            continue
        end = int(max(int(t[-1]) for t in times))
        tl = _timeline(rec, params)
        jumps = tl.t_ns[1:][np.abs(np.diff(tl.duty)) >= 0.005][:1000]   # steps, not a noisy command's jitter
        dense = (jumps[:, None] + around[None, :]).ravel()
        dense = dense[(dense >= 0) & (dense <= end)]
        sample_ns.append(np.unique(np.concatenate([*times, dense])))
    all_roles = sorted({d.series.role for d in data}, key=OUTPUT_ROLES.index)
    lag_roles = all_roles if lag_bounds is not None else []
    tc_roles = all_roles if time_constant_bounds is not None else []
    n_theta, n_lag, n_tc = len(fit), len(lag_roles), len(tc_roles)
    n_off = len(data) if fit_offsets else 0
    n_sensor = n_lag + n_tc
    if not fit and not n_sensor + n_off:
        raise CalibrationError("nothing to fit: name a parameter with --fit, or estimate the sensors (lag, offset)")
    # Internal coordinates: theta / scale, delay and time constant in ms, offset in sigma.
    lb, tb = lag_bounds or (0.0, 0.0), time_constant_bounds or (0.0, 0.0)
    # The time constants start inside their bounds (0.5 ms): from a start on the bound, the
    # reflective trust region shrinks every step to the distance to that bound and stops at once.
    z0 = np.concatenate([[p.initial / p.scale for p in fit], np.zeros(n_lag),
                         np.full(n_tc, min(0.5, 0.5 * (tb[0] + tb[1]) * 1e3)), np.zeros(n_off)])
    lo = np.concatenate([[p.lower / p.scale for p in fit], np.full(n_lag, lb[0] * 1e3),
                         np.full(n_tc, tb[0] * 1e3), np.full(n_off, -np.inf)])
    hi = np.concatenate([[p.upper / p.scale for p in fit], np.full(n_lag, lb[1] * 1e3),
                         np.full(n_tc, tb[1] * 1e3), np.full(n_off, np.inf)])
    z0 = np.clip(z0, lo, hi)
    counts: dict[str, Any] = {"evaluations": 0, "simulations": 0}
    start = time.perf_counter()

    def valve(z: npt.NDArray[np.float64]) -> ValveParams:
        p = params
        for k, fp in enumerate(fit):
            try:
                p = replace_param(p, fp.key, float(z[k] * fp.scale))
            except ParameterError as exc:
                msg = f"{fp.key} = {z[k] * fp.scale:g} is refused by the valve's rules ({exc}); narrow its bounds"
                raise CalibrationError(msg) from exc
        return p

    def simulate(p: ValveParams) -> list[dict[str, npt.NDArray[np.float64]]]:
        counts["simulations"] += 1
        outs: list[dict[str, npt.NDArray[np.float64]]] = []
        for b, rec in enumerate(recordings):
            if not sample_ns[b].size:
                outs.append({})
                continue
            try:
                run = run_model(p, model, _timeline(rec, p), sample_ns[b], solver=solver)
            except ReplayError as exc:
                msg = f"{rec.path}: the model cannot run with {', '.join(keys)} = " \
                      f"{', '.join(f'{_get(p, k):g}' for k in keys)}: {exc}"
                raise CalibrationError(msg) from exc
            outs.append(dict(run.outputs))
            counts["solver"] = run.solver   # what ran (auto is the stepper for either model)
        return outs

    grids = [ns.astype(np.float64) / NS_PER_S for ns in sample_ns]

    def sensed(runs: list[dict[str, npt.NDArray[np.float64]]], d: _Data, lag: float,
               tc: float) -> npt.NDArray[np.float64]:
        """The model as the sensor reports it at the measured times (before the offset)."""
        y = first_order(grids[d.bag], runs[d.bag][d.series.role], tc)
        return np.interp(d.series.t_ns / NS_PER_S - lag, grids[d.bag], y)

    def parts(z: npt.NDArray[np.float64]) -> tuple[dict[str, float], dict[str, float], list[float]]:
        lags = {r: float(z[n_theta + k]) * 1e-3 for k, r in enumerate(lag_roles)}
        tcs = {r: float(z[n_theta + n_lag + k]) * 1e-3 for k, r in enumerate(tc_roles)}
        offs = [float(z[n_theta + n_sensor + k]) * d.sigma if fit_offsets else 0.0 for k, d in enumerate(data)]
        return lags, tcs, offs

    def residuals(z: npt.NDArray[np.float64], runs: list[dict[str, npt.NDArray[np.float64]]]) -> npt.NDArray[np.float64]:
        lags, tcs, offs = parts(z)
        return np.concatenate([(sensed(runs, d, lags.get(d.series.role, 0.0), tcs.get(d.series.role, 0.0)) + offs[k]
                                - d.series.value) / d.sigma for k, d in enumerate(data)])

    cache: dict[str, Any] = {}

    def runs_at(z: npt.NDArray[np.float64]) -> list[dict[str, npt.NDArray[np.float64]]]:
        theta = tuple(z[:n_theta].tolist())
        if cache.get("theta") != theta:
            cache["theta"], cache["runs"] = theta, simulate(valve(z))
        runs: list[dict[str, npt.NDArray[np.float64]]] = cache["runs"]
        return runs

    def fun(z: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        r = residuals(z, runs_at(z))
        counts["evaluations"] += 1
        if progress is not None:
            progress(counts["evaluations"], 0.5 * float(r @ r), time.perf_counter() - start)
        return r

    def jac(z: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        base_runs = runs_at(z)
        r0 = residuals(z, base_runs)
        cols = []
        for k in range(n_theta):
            h = _FD_STEP * max(abs(z[k]), 1e-3)
            if z[k] + h > hi[k]:
                h = -h
            zk = z.copy()
            zk[k] += h
            cols.append((residuals(zk, simulate(valve(zk))) - r0) / h)
        lags, tcs, _ = parts(z)
        for role in lag_roles:
            col = np.zeros_like(r0)
            pos = 0
            for d in data:
                n = len(d.series.t_ns)
                if d.series.role == role:
                    grid = grids[d.bag]
                    slope = np.gradient(first_order(grid, base_runs[d.bag][d.series.role], tcs.get(role, 0.0)), grid)
                    col[pos:pos + n] = -np.interp(d.series.t_ns / NS_PER_S - lags[role], grid, slope) * 1e-3 / d.sigma
                pos += n
            cols.append(col)
        for role in tc_roles:
            col = np.zeros_like(r0)
            pos = 0
            h_ms = 1e-2   # forward step of the time constant, ms
            for d in data:
                n = len(d.series.t_ns)
                if d.series.role == role:
                    lag, tc = lags.get(role, 0.0), tcs[role]
                    col[pos:pos + n] = (sensed(base_runs, d, lag, tc + h_ms * 1e-3)
                                        - sensed(base_runs, d, lag, tc)) / h_ms / d.sigma
                pos += n
            cols.append(col)
        if fit_offsets:
            pos = 0
            for d in data:
                col = np.zeros_like(r0)
                col[pos:pos + len(d.series.t_ns)] = 1.0
                cols.append(col)
                pos += len(d.series.t_ns)
        return np.column_stack(cols)

    r_start = fun(z0)
    cost_before = 0.5 * float(r_start @ r_start)
    sol = least_squares(fun, z0, jac=jac, bounds=(lo, hi), loss="soft_l1", f_scale=3.0, x_scale=1.0,
                        max_nfev=max_evaluations, xtol=1e-6, ftol=1e-6, gtol=1e-8)
    z = sol.x
    fitted = valve(z)
    runs = runs_at(z)
    r = residuals(z, runs)
    J = jac(z)
    rough = _rough_parameters(J[:, :n_theta], z[:n_theta], lo[:n_theta], hi[:n_theta],
                              lambda zk: residuals(zk, simulate(valve(zk))), z, r)
    m, n = J.shape
    s2 = float(r @ r) / max(m - n, 1)
    rho = _autocorrelation(r, [len(d.series.t_ns) for d in data])
    inflation = (1.0 + rho) / (1.0 - rho) if rho > 0 else 1.0
    cov_z = s2 * inflation * np.linalg.pinv(J.T @ J)
    sd_z = np.sqrt(np.clip(np.diag(cov_z), 0.0, None))
    scales = np.concatenate([[p.scale for p in fit], np.full(n_sensor, 1e-3), [d.sigma for d in data][:n_off]])
    sd = sd_z * scales
    estimates = tuple(Estimate(p.key, float(z[k] * p.scale), p.initial, _Z95 * float(sd[k]), p.unit, p.lower, p.upper)
                      for k, p in enumerate(fit))
    lag_est = tuple(Estimate(f"lag.{role}", float(z[n_theta + k]) * 1e-3, 0.0, _Z95 * float(sd[n_theta + k]), "s",
                             lag_bounds[0] if lag_bounds else 0.0, lag_bounds[1] if lag_bounds else 0.0)
                    for k, role in enumerate(lag_roles))
    tc_est = tuple(Estimate(f"time_constant.{role}", float(z[n_theta + n_lag + k]) * 1e-3, 0.0,
                            _Z95 * float(sd[n_theta + n_lag + k]), "s", tb[0], tb[1])
                   for k, role in enumerate(tc_roles))
    units = ROLE_UNITS
    off_est = tuple(Estimate(f"offset.{d.series.role}[{d.bag}]", float(z[n_theta + n_sensor + k]) * d.sigma, 0.0,
                             _Z95 * float(sd[n_theta + n_sensor + k]), units.get(d.series.role, "SI"))
                    for k, d in enumerate(data)) if fit_offsets else ()
    with np.errstate(invalid="ignore", divide="ignore"):
        corr_all = np.nan_to_num(cov_z / np.outer(sd_z, sd_z), nan=0.0)
    corr = corr_all[:n_theta, :n_theta]
    nuisance_names = ([f"the sensor delay of {r}" for r in lag_roles] + [f"the sensor time constant of {r}" for r in tc_roles]
                      + [f"the {d.series.role} offset of bag {d.bag}" for d in data][:n_off])

    runs_before = simulate(params)
    signals = []
    traces: dict[tuple[int, str], tuple[npt.NDArray[np.float64], ...]] = {}
    lags, tcs, offs = parts(z)
    for k, d in enumerate(data):
        before = sensed(runs_before, d, 0.0, 0.0)
        after = sensed(runs, d, lags.get(d.series.role, 0.0), tcs.get(d.series.role, 0.0)) + offs[k]
        fb, fa = _fit(d.series.value, before), _fit(d.series.value, after)
        signals.append(SignalFit(str(recordings[d.bag].path), d.series.role, len(d.series.t_ns), d.sigma,
                                 fb[0], fa[0], fb[1], fa[1]))
        traces[(d.bag, d.series.role)] = (d.series.t_ns / NS_PER_S, d.series.value, before, after)

    warnings = _warnings(estimates, corr, lag_est)
    for k, ratio in rough:
        warnings.append(f"{estimates[k].name} is not determined by the data: the recordings do not respond smoothly "
                        f"to it (its sensitivity over a {_FD_STEP:g} and a {_ROUGH_STEP * _FD_STEP:g} relative step "
                        f"differ by {ratio:.0%}: the outputs move by a jump at a step of the fixed-step model, as an "
                        f"impact's, or by nothing), so its interval +-{estimates[k].half_width_95:.3g} "
                        f"{estimates[k].unit} is not to be trusted")
    for i, e in enumerate(estimates):
        for j, name in enumerate(nuisance_names):
            c = corr_all[i, n_theta + j]
            if abs(c) > CORRELATION_LIMIT:
                warnings.append(f"{e.name} is correlated with {name} (r = {c:+.3f}): the recordings tell them "
                                f"apart only through the other signals and the dynamics, and its interval is "
                                f"mostly that trade; if the sensor is known (e.g. zeroed), fix it (--no-offset, "
                                f"--sensor) to narrow it")
    # What the fit leaves: a signal well above its noise, a sensor that had to be implausibly
    # off or slow, and the parameters not fitted whose effect matches the residual.
    unexplained = []
    for sf, d in zip(signals, data):
        scale, unit = DISPLAY[sf.role].scale, DISPLAY[sf.role].unit
        if sf.rmse_after > NOISE_RATIO_LIMIT * sf.noise_sigma:
            unexplained.append(sf.role)
            spread = float(np.linalg.norm(d.series.value - d.series.value.mean()))
            floor = 100.0 * (1.0 - sf.noise_sigma * math.sqrt(len(d.series.value)) / spread) if spread > 0 else math.nan
            warnings.append(
                f"the model does not explain the {sf.role} of {sf.bag}: after the fit its RMSE is "
                f"{sf.rmse_after * scale:.3g} {unit}, {sf.rmse_after / sf.noise_sigma:.1f}x the recording's noise "
                f"level ({sf.noise_sigma * scale:.3g} {unit}, from its sample-to-sample differences); fit "
                f"{sf.fit_after_percent:.2f} % where the noise allows {floor:.2f} %: a parameter that differs is "
                f"not in --fit (see the suggestions) or the values found are biased by it")
    for e, d in zip(off_est, data):
        limit = PLAUSIBLE_OFFSET.get(d.series.role, math.inf)
        if abs(e.value) > limit:
            scale, unit = DISPLAY[d.series.role].scale, DISPLAY[d.series.role].unit
            span = float(np.ptp(d.series.value))
            warnings.append(
                f"the {d.series.role} offset of {recordings[d.bag].path} is {e.value * scale:+.3g} {unit} "
                f"({abs(e.value) / span * 100 if span > 0 else math.nan:.1f} % of the signal's span), more than a "
                f"{d.series.role} sensor's zero error (~{limit * scale:g} {unit}): it likely absorbs a model error; "
                f"if the sensor was zeroed, --no-offset keeps it out")
    for role in all_roles:
        total = lags.get(role, 0.0) + tcs.get(role, 0.0)
        if total > PLAUSIBLE_LAG:
            warnings.append(
                f"the {role} sensor lags by {total * 1e3:.1f} ms (delay {lags.get(role, 0.0) * 1e3:.1f} ms + time "
                f"constant {tcs.get(role, 0.0) * 1e3:.1f} ms), slower than a {role} sensor "
                f"(~{PLAUSIBLE_LAG * 1e3:g} ms): it likely absorbs the model's slow dynamics")
    suggestions: list[Suggestion] = []
    if unexplained:
        # Each candidate's sensitivity (one run at the fitted values), the part of it the fitted
        # parameters and sensors cannot already produce, projected on the residual.
        u_j, sv_j, _ = np.linalg.svd(J, full_matrices=False)
        q = u_j[:, sv_j > sv_j[0] * 1e-10] if sv_j.size else u_j
        rr = float(r @ r)
        effects: dict[str, npt.NDArray[np.float64]] = {}
        for key in CANDIDATES:
            if key in keys:
                continue
            try:
                cand = fit_parameter(fitted, key)
                h = 0.01 * cand.initial if cand.initial != 0.0 else 0.01 * cand.scale
                probe = replace_param(fitted, key, cand.initial + h)
                col = (residuals(z, simulate(probe)) - r) / 0.01   # per unit of relative change (of scale at 0)
            except (CalibrationError, ParameterError):
                continue            # not a number in this config, or refused by the model: not a candidate
            perp = col - q @ (q.T @ col)
            norm2 = float(perp @ perp)
            if norm2 <= 0.0 or rr <= 0.0:
                continue
            share = float(perp @ r) ** 2 / norm2 / rr
            step = -float(perp @ r) / norm2       # the least-squares change, relative to the value
            rel = step if cand.initial != 0.0 else math.nan
            if share >= SUGGEST_SHARE:
                suggestions.append(Suggestion(key, share, cand.initial, rel, cand.unit))
                effects[key] = perp / math.sqrt(norm2)
        suggestions.sort(key=lambda x: -x.share)
        if suggestions:
            def alike(x: Suggestion) -> str:
                """Names an earlier suggestion with the same effect here (e.g. V and beta: only V/beta acts)."""
                for y in suggestions:
                    if y is x:
                        return ""
                    if abs(float(effects[x.key] @ effects[y.key])) > CORRELATION_LIMIT:
                        return f", the same effect as {y.key} here"
                return ""

            listing = "; ".join(f"{x.key} (explains {x.share * 100:.0f} % of it, at about "
                                f"{x.relative_change * 100:+.0f} % = {x.value * (1 + x.relative_change):.4g} {x.unit}"
                                f"{alike(x)})" for x in suggestions[:4])
            warnings.append(f"what the fit leaves in {', '.join(dict.fromkeys(unexplained))} matches the effect of: "
                            f"{listing}; add the first to --fit (--fit {','.join([*keys, suggestions[0].key])})")
        else:
            warnings.append(f"what the fit leaves in {', '.join(dict.fromkeys(unexplained))} matches none of "
                            f"{', '.join(k for k in CANDIDATES if k not in keys)} alone: a model error "
                            f"beyond one parameter, or a recording the model does not describe")
    return CalibrationResult(
        params=fitted, initial_params=params, parameters=estimates, lags=lag_est, time_constants=tc_est,
        offsets=off_est,
        correlation=corr, signals=tuple(signals), model=model,
        solver=str(counts.get("solver", solver)),
        evaluations=counts["evaluations"], simulations=counts["simulations"],
        elapsed_s=time.perf_counter() - start, cost_before=cost_before, cost_after=0.5 * float(r @ r),
        autocorrelation=rho, status=sol.message, status_code=int(sol.status), warnings=tuple(warnings), traces=traces,
        suggestions=tuple(suggestions),
    )


def _get(p: ValveParams, key: str) -> float:
    section, _, name = key.partition(".")
    v = getattr(getattr(p, section), name)
    return float(v) if isinstance(v, (int, float)) else math.nan


def _fit(measured: npt.NDArray[np.float64], model: npt.NDArray[np.float64]) -> tuple[float, float]:
    err = model - measured
    spread = float(np.linalg.norm(measured - measured.mean()))
    fit = 100.0 * (1.0 - float(np.linalg.norm(err)) / spread) if spread > 0 else math.nan
    return fit, float(np.sqrt(np.mean(err**2)))


def _autocorrelation(r: npt.NDArray[np.float64], lengths: Sequence[int]) -> float:
    """Lag-1 autocorrelation of the residuals, pooled over the signals (0 if none)."""
    num = den = 0.0
    pos = 0
    for n in lengths:
        seg = r[pos:pos + n] - np.mean(r[pos:pos + n])
        num += float(seg[1:] @ seg[:-1])
        den += float(seg @ seg)
        pos += n
    return min(max(num / den, 0.0), 0.99) if den > 0 else 0.0


def _rough_parameters(j_theta: npt.NDArray[np.float64], theta: npt.NDArray[np.float64], lo: npt.NDArray[np.float64],
                      hi: npt.NDArray[np.float64], residuals_at: Any, z: npt.NDArray[np.float64],
                      r: npt.NDArray[np.float64]) -> list[tuple[int, float]]:
    """The valve parameters whose Jacobian column (a forward difference) does not hold over a
    step _ROUGH_STEP times larger: (index, relative difference of the two columns). The
    intervals assume outputs smooth in theta; a parameter that acts only through events (the
    core's contact, R35) moves them by jumps on the step's grid, and a difference over a tiny step
    then reads as a steep, well-determined slope. One more simulation per parameter."""
    out = []
    for k in range(len(theta)):
        h = _ROUGH_STEP * _FD_STEP * max(abs(theta[k]), 1e-3)
        if theta[k] + h > hi[k]:
            h = -h
        if not lo[k] <= theta[k] + h <= hi[k]:
            continue
        zk = z.copy()
        zk[k] += h
        col = (residuals_at(zk) - r) / h
        scale = max(float(np.linalg.norm(col)), float(np.linalg.norm(j_theta[:, k])))
        if scale > 0.0:
            ratio = float(np.linalg.norm(col - j_theta[:, k])) / scale
            if ratio > _ROUGH_LIMIT:
                out.append((k, ratio))
    return out


def _warnings(est: Sequence[Estimate], corr: npt.NDArray[np.float64], lags: Sequence[Estimate]) -> list[str]:
    out = []
    for i in range(len(est)):
        for j in range(i + 1, len(est)):
            if abs(corr[i, j]) > CORRELATION_LIMIT:
                out.append(
                    f"{est[i].name} and {est[j].name} are correlated (r = {corr[i, j]:+.3f}): the data cannot "
                    f"separate them; fit one of them, or add recordings that move them differently"
                )
    for e in est:
        if e.at_bound:
            out.append(f"{e.name} ended on its bound ({e.value:g} {e.unit}; bounds {e.lower:g}..{e.upper:g}): "
                       f"widen it (--fit {e.name}=LOW:HIGH) or fix the parameter")
        elif not e.half_width_95 < abs(e.value):
            out.append(f"{e.name} is not determined by the data: its 95 % interval +-{e.half_width_95:.3g} "
                       f"{e.unit} is wider than its value {e.value:.4g}")
    for e in lags:
        if e.at_bound:
            out.append(f"the sensor lag of {e.name[4:]} ended on its bound ({e.value * 1e3:g} ms)")
    return out
