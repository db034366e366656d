"""Replay comparison as a pure function: a recording and a parameter set in, typed metrics out.

:func:`replay` drives the chosen model with the recording's inputs (:mod:`.simulate`) and
compares it with the measured outputs, over the whole run (RMSE, max error, NRMSE fit %) and per
duty step (rise time, overshoot, settling time, steady state; :func:`pcv_sim.analysis.metrics.step_metrics`).
Errors are model minus measured. :func:`check_thresholds` turns limits into failures.

Gaps (:class:`~pcv_sim.replay.recording.Gap`: the measured outputs pause, e.g. an emulator that
skipped steps under load) are reported, and the run is not compared across them: the samples
from a gap's end until :data:`RESYNC_S` after it are left out of RMSE, max error and fit, and a
step whose analysis window touches a gap or that interval is not analysed. Why exclusion and not
segments that each restart the model: a restart needs the device's state at the gap's end, and
a bag holds only pressure, current and position, not the flux linkage, the spool velocity or
the solenoid's hysteresis state, so a restarted model would start wrong too. Across a gap the
device stood still while the model went on (or the samples were lost while both went on); with
the same inputs afterwards both settle to the same trajectory, as fast as the valve forgets its
state. Measured with the emulator's device (``bench/replay_gaps.py``, BENCHMARKS.md): after a
55 ms skip anywhere in the transients of 0.5 -> 0.7 -> 0.4 duty steps, the difference is below
0.05 bar 300 ms after the gap (up to 78 bar at its end, 0.14-6.9 bar 50 ms later).
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Final, Literal

import numpy as np
import numpy.typing as npt

from pcv_sim.analysis.in_force import InForce, in_force
from pcv_sim.analysis.metrics import FitMetrics, StepMetrics, fit_metrics, step_metrics
from pcv_sim.io.topics import CURRENT, OUTPUT_ROLES, PRESSURE, ROLE_UNITS, SPOOL_POSITION
from pcv_sim.params import ValveParams
from pcv_sim.replay.errors import ReplayError
from pcv_sim.replay.recording import Gap, Recording
from pcv_sim.replay.simulate import InputTimeline, Solver, input_timeline, run_model
from pcv_sim.units import MM_PER_M, NS_PER_S, PA_PER_BAR

__all__ = [
    "DISPLAY",
    "RESYNC_S",
    "ReplayResult",
    "SignalResult",
    "Step",
    "StepComparison",
    "ThresholdFailure",
    "check_thresholds",
    "compare_step",
    "detect_steps",
    "replay",
]

#: s after a gap during which samples are not compared: the model and the device re-synchronise
#: (to within 0.05 bar after a 55 ms skip, measured: module docstring).
RESYNC_S: Final = 0.3


@dataclass(frozen=True)
class Display:
    """How a signal is shown: label, unit name in metric keys, scale from SI, settling band (SI)."""

    label: str
    unit: str
    key_unit: str
    scale: float
    band_min: float


#: Display units per output role; metric keys carry them (``pressure_rmse_bar``).
DISPLAY: Mapping[str, Display] = {
    PRESSURE: Display("pressure", "bar", "bar", 1 / PA_PER_BAR, 0.5 * PA_PER_BAR),
    CURRENT: Display("current", "A", "a", 1.0, 0.005),
    SPOOL_POSITION: Display("spool position", "mm", "mm", MM_PER_M, 0.002e-3),
}


@dataclass(frozen=True)
class Step:
    """A duty step found in the command: changes closer than ``min_hold`` in one direction
    (a rate-limited ramp recorded as a staircase) form one step. Times in s from replay start."""

    index: int
    t_start: float
    t_last_change: float
    t_end: float
    duty_from: float
    duty_to: float
    changes: int

    @property
    def amplitude(self) -> float:
        return self.duty_to - self.duty_from


@dataclass(frozen=True)
class StepComparison:
    step: Step
    measured: Mapping[str, StepMetrics]
    model: Mapping[str, StepMetrics]

    def errors(self, role: str) -> dict[str, float]:
        """Model minus measured, in SI (times in s, overshoot in percentage points)."""
        m, s = self.measured[role], self.model[role]
        return {
            "steady_state_error": s.final - m.final,
            "rise_time_error": _diff(s.rise_time, m.rise_time),
            "overshoot_error": s.overshoot_percent - m.overshoot_percent,
            "settling_time_error": _settling_error(s, m),
        }


def _settling_error(model: StepMetrics, measured: StepMetrics) -> float:
    """Model minus measured settling time; for a noisy measurement, the distance from the model's
    to the interval the noise leaves open [settling_early, settling_late] (0 inside it)."""
    s, lo, hi = model.settling_time, measured.settling_early, measured.settling_late
    if math.isnan(s) or math.isnan(lo) or (lo == hi == measured.settling_time):
        return _diff(s, measured.settling_time)
    hi = math.inf if math.isnan(hi) else hi
    return s - min(max(s, lo), hi)


def _diff(a: float, b: float) -> float:
    """a - b, where nan (never reached / never settled) on one side only is infinitely off."""
    if math.isnan(a) and math.isnan(b):
        return 0.0
    if math.isnan(a) or math.isnan(b):
        return math.inf
    return a - b


@dataclass(frozen=True)
class SignalResult:
    role: str
    fit: FitMetrics        # SI units, over the compared samples
    samples: int           # compared
    excluded: int = 0      # left out after gaps (re-synchronisation)


@dataclass(frozen=True)
class ThresholdFailure:
    key: str
    value: float
    limit: float
    kind: Literal["above", "below"]

    def __str__(self) -> str:
        rel = ">" if self.kind == "above" else "<"
        return f"{self.key} = {self.value:.6g} {rel} {self.limit:g}"


@dataclass(frozen=True)
class ReplayResult:
    """Everything a report shows. Arrays in ``traces`` are SI; times in s from replay start."""

    bag: str
    model: str
    solver: str
    duration_s: float
    topics: Mapping[str, str]
    closed_cleanly: bool
    signals: Mapping[str, SignalResult]
    steps: tuple[StepComparison, ...]
    traces: Mapping[str, tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64]]]
    duty: tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]
    input_changes: int
    elapsed_s: float
    warnings: tuple[str, ...] = ()
    notes: tuple[str, ...] = field(default=())
    gaps: tuple[Gap, ...] = ()
    resync_s: float = RESYNC_S

    @property
    def excluded_intervals(self) -> list[tuple[float, float]]:
        """(start, end) in s of each skipped interval: the gap and its re-synchronisation."""
        return [(g.start, g.end + self.resync_s) for g in self.gaps]
    in_force: InForce | None = None    # the damping and calibration the model ran with

    @property
    def real_time_factor(self) -> float:
        return self.duration_s / self.elapsed_s if self.elapsed_s > 0 else math.inf

    def scalar_metrics(self) -> dict[str, float]:
        """Flat metrics in display units, the keys ``--fail-above``/``--fail-below`` accept."""
        out: dict[str, float] = {
            "closed_cleanly": 1.0 if self.closed_cleanly else 0.0,
            "gaps": float(len(self.gaps)),
            "gap_max_ms": max((g.duration for g in self.gaps), default=0.0) * 1e3,
        }
        for role, sig in self.signals.items():
            d = DISPLAY[role]
            out[f"{role}_rmse_{d.key_unit}"] = sig.fit.rmse * d.scale
            out[f"{role}_max_error_{d.key_unit}"] = sig.fit.max_error * d.scale
            out[f"{role}_fit_percent"] = sig.fit.nrmse_fit_percent
            worst = {"steady_state_error": 0.0, "rise_time_error": 0.0, "overshoot_error": 0.0,
                     "settling_time_error": 0.0}
            for sc in self.steps:
                for k, v in sc.errors(role).items():
                    worst[k] = max(worst[k], abs(v))
            out[f"{role}_steady_state_error_{d.key_unit}"] = worst["steady_state_error"] * d.scale
            out[f"{role}_rise_time_error_ms"] = worst["rise_time_error"] * 1e3
            out[f"{role}_overshoot_error_percent"] = worst["overshoot_error"]
            out[f"{role}_settling_time_error_ms"] = worst["settling_time_error"] * 1e3
        return out

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready summary (SI units, times in s; no sample arrays)."""
        return {
            "bag": self.bag,
            "model": self.model,
            "solver": self.solver,
            "duration_s": self.duration_s,
            "elapsed_s": self.elapsed_s,
            "real_time_factor": self.real_time_factor,
            "closed_cleanly": self.closed_cleanly,
            "topics": dict(self.topics),
            "input_changes": self.input_changes,
            "signals": {
                r: {"samples": s.samples, "excluded_samples": s.excluded, **s.fit.as_dict()}
                for r, s in self.signals.items()
            },
            "gaps": [
                {"start_s": g.start, "end_s": g.end, "duration_s": g.duration,
                 "missing_samples": g.missing, "signals": list(g.roles),
                 "not_compared_until_s": g.end + self.resync_s}
                for g in self.gaps
            ],
            "resync_s": self.resync_s,
            "steps": [
                {
                    "index": sc.step.index,
                    "t_start_s": sc.step.t_start,
                    "t_end_s": sc.step.t_end,
                    "duty_from": sc.step.duty_from,
                    "duty_to": sc.step.duty_to,
                    "commands": sc.step.changes,
                    "signals": {
                        r: {"measured": sc.measured[r].as_dict(), "model": sc.model[r].as_dict(),
                            "errors": sc.errors(r)}
                        for r in sc.measured
                    },
                }
                for sc in self.steps
            ],
            "metrics": self.scalar_metrics(),
            "units": {**{role: ROLE_UNITS[role] for role in OUTPUT_ROLES}, "times": "s",
                      "metrics": "as named: bar, a (A), mm, ms, percent"},
            "warnings": list(self.warnings),
            "notes": list(self.notes),
            "in_force": self.in_force.as_dict() if self.in_force is not None else None,
        }


def compare_step(step: Step, role: str, t: npt.NDArray[np.float64], measured: npt.NDArray[np.float64],
                 models: tuple[npt.NDArray[np.float64], ...]) -> tuple[StepMetrics, tuple[StepMetrics, ...]] | None:
    """The step metrics of `role`'s measured response over `step`'s window and of each response
    in `models`, every model judged in the measured band (widened by the sensor's noise), so that
    one gate holds for both; None when the window has fewer than 3 samples or none before the step."""
    inside = (t >= step.t_start) & (t <= step.t_end)
    if np.count_nonzero(inside) < 3 or not np.any(t < step.t_start):
        return None
    band = DISPLAY[role].band_min
    m = step_metrics(t, measured, step.t_start, step.t_end, band_min=band)
    return m, tuple(step_metrics(t, y, step.t_start, step.t_end, band_min=max(band, m.band)) for y in models)


def detect_steps(
    timeline: InputTimeline, end_ns: int, *, min_hold: float = 0.02, min_amplitude: float = 0.005
) -> tuple[list[Step], list[str]]:
    """Duty steps in the command timeline, and notes on changes not taken as steps."""
    t = timeline.t_ns
    d = timeline.duty
    changes = [k for k in range(1, len(t)) if d[k] != d[k - 1]]
    groups: list[list[int]] = []
    hold_ns = round(min_hold * NS_PER_S)
    for k in changes:
        if groups:
            last = groups[-1]
            same_dir = np.sign(d[k] - d[k - 1]) == np.sign(d[last[-1]] - d[last[0] - 1])
            if t[k] - t[last[-1]] < hold_ns and same_dir:
                last.append(k)
                continue
        groups.append([k])
    steps: list[Step] = []
    small = 0
    for n, g in enumerate(groups):
        start = int(t[g[0]])
        end = int(t[groups[n + 1][0]]) if n + 1 < len(groups) else end_ns
        d_from, d_to = float(d[g[0] - 1]), float(d[g[-1]])
        if abs(d_to - d_from) < min_amplitude or end <= start:
            small += 1
            continue
        steps.append(Step(len(steps) + 1, start / NS_PER_S, int(t[g[-1]]) / NS_PER_S, end / NS_PER_S, d_from, d_to, len(g)))
    notes = []
    if small:
        notes.append(
            f"{small} duty change(s) of less than {min_amplitude:g} (or at the very end) are in "
            f"the run's fit but not analysed as steps"
        )
    return steps, notes


def replay(
    recording: Recording,
    params: ValveParams,
    *,
    model: Literal["full", "simplified"] = "full",
    solver: Solver = "auto",
    fast_step: float = 5e-4,
    min_hold: float = 0.02,
    resync: float = RESYNC_S,
) -> ReplayResult:
    """Drive ``model`` with the recording's inputs and compare it with the measured outputs.

    ``resync``: s after each gap of the recording whose samples are not compared (module
    docstring)."""
    if not (isinstance(resync, (int, float)) and math.isfinite(resync) and resync >= 0):
        msg = f"resync {resync!r} s: accepted is a finite number >= 0"
        raise ReplayError(msg)
    skipped_ns = [(g.start_ns, g.end_ns + round(resync * NS_PER_S)) for g in recording.gaps]
    timeline, tl_notes = input_timeline(
        recording.inputs, 0.0, params.circuit.supply_pressure
    )
    sample_ns = np.unique(np.concatenate([s.t_ns for s in recording.measured.values()]))
    t0 = time.perf_counter()
    run = run_model(params, model, timeline, sample_ns, solver=solver, fast_step=fast_step)
    elapsed = time.perf_counter() - t0
    end_ns = recording.end_ns
    signals: dict[str, SignalResult] = {}
    traces = {}
    gap_notes: list[str] = []
    for role in OUTPUT_ROLES:
        if role not in recording.measured:
            continue
        s = recording.measured[role]
        idx = np.searchsorted(sample_ns, s.t_ns)
        model_values = run.outputs[role][idx]
        keep = np.ones(len(s), dtype=bool)
        for a, b in skipped_ns:
            keep &= ~((s.t_ns > a) & (s.t_ns <= b))
        kept = int(np.count_nonzero(keep))
        if kept:
            fit = fit_metrics(s.value[keep], model_values[keep])
        else:
            fit = FitMetrics(math.nan, math.nan, math.nan)
            gap_notes.append(f"{role}: every sample lies in a gap's re-synchronisation; nothing compared")
        signals[role] = SignalResult(role, fit, kept, len(s) - kept)
        traces[role] = (s.t, s.value, model_values)
    steps, step_notes = detect_steps(timeline, end_ns, min_hold=min_hold)
    comparisons = []
    skipped_s = [(a / NS_PER_S, b / NS_PER_S) for a, b in skipped_ns]
    for st in steps:
        if any(a < st.t_end and st.t_start - min_hold < b for a, b in skipped_s):
            step_notes.append(
                f"step {st.index} at {st.t_start:.3f} s is not analysed: a gap or its "
                f"re-synchronisation ({resync * 1e3:g} ms) falls in its window"
            )
            continue
        meas: dict[str, StepMetrics] = {}
        mod: dict[str, StepMetrics] = {}
        for role, (t, y_meas, y_mod) in traces.items():
            compared = compare_step(st, role, t, y_meas, (y_mod,))
            if compared is not None:
                meas[role], (mod[role],) = compared
        if meas:
            comparisons.append(StepComparison(st, meas, mod))
        else:
            step_notes.append(f"step {st.index} at {st.t_start:.3f} s has too few samples to analyse")
    duty_t = timeline.t_ns.astype(np.float64) / NS_PER_S
    return ReplayResult(
        bag=str(recording.path),
        model=model,
        solver=run.solver,
        duration_s=end_ns / NS_PER_S,
        topics=recording.topics,
        closed_cleanly=recording.closed_cleanly,
        signals=signals,
        steps=tuple(comparisons),
        traces=traces,
        duty=(duty_t, timeline.duty.copy()),
        input_changes=len(timeline),
        elapsed_s=elapsed,
        warnings=recording.warnings,
        notes=recording.notes + tuple(tl_notes) + run.notes + tuple(gap_notes) + tuple(step_notes),
        gaps=recording.gaps,
        resync_s=float(resync),
        in_force=in_force(params, model),
    )


def check_thresholds(
    result: ReplayResult, above: Mapping[str, float], below: Mapping[str, float] | None = None
) -> list[ThresholdFailure]:
    """Failures of ``metric > limit`` (``above``) and ``metric < limit`` (``below``).

    Raises ReplayError for a key the result does not have (listing the keys it has).
    """
    metrics = result.scalar_metrics()
    failures = []
    for kind, limits in (("above", above), ("below", below or {})):
        for key, limit in limits.items():
            if key not in metrics:
                msg = (
                    f"unknown metric {key!r} for --fail-{kind}; this bag has: "
                    f"{', '.join(sorted(metrics))}"
                )
                raise ReplayError(msg)
            v = metrics[key]
            bad = (v > limit or math.isnan(v)) if kind == "above" else (v < limit or math.isnan(v))
            if bad:
                failures.append(ThresholdFailure(key, v, limit, kind))  # type: ignore[arg-type]
    return failures
