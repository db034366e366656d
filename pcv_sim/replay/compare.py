"""Replay comparison as a pure function: a recording and a parameter set in, typed metrics out.

:func:`replay` drives the chosen model with the recording's inputs (:mod:`.simulate`) and
compares it with the measured outputs, over the whole run (RMSE, max error, NRMSE fit %) and per
duty step (rise time, overshoot, settling time, steady state; :func:`pcv_sim.analysis.metrics.step_metrics`).
Errors are model minus measured. :func:`check_thresholds` turns limits into failures.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
import numpy.typing as npt

from pcv_sim.analysis.in_force import InForce, in_force
from pcv_sim.analysis.metrics import FitMetrics, StepMetrics, fit_metrics, step_metrics
from pcv_sim.io.topics import CURRENT, OUTPUT_ROLES, PRESSURE, SPOOL_POSITION
from pcv_sim.params import ValveParams
from pcv_sim.replay.errors import ReplayError
from pcv_sim.replay.recording import Recording
from pcv_sim.replay.simulate import InputTimeline, Solver, input_timeline, run_model

__all__ = [
    "DISPLAY",
    "ReplayResult",
    "SignalResult",
    "Step",
    "StepComparison",
    "ThresholdFailure",
    "check_thresholds",
    "detect_steps",
    "replay",
]

_NS = 1_000_000_000


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
    PRESSURE: Display("pressure", "bar", "bar", 1e-5, 0.5e5),
    CURRENT: Display("current", "A", "a", 1.0, 0.005),
    SPOOL_POSITION: Display("spool position", "mm", "mm", 1e3, 0.002e-3),
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
            "settling_time_error": _diff(s.settling_time, m.settling_time),
        }


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
    fit: FitMetrics        # SI units
    samples: int


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
    in_force: InForce | None = None    # the damping and calibration the model ran with

    @property
    def real_time_factor(self) -> float:
        return self.duration_s / self.elapsed_s if self.elapsed_s > 0 else math.inf

    def scalar_metrics(self) -> dict[str, float]:
        """Flat metrics in display units, the keys ``--fail-above``/``--fail-below`` accept."""
        out: dict[str, float] = {}
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
                r: {"samples": s.samples, **s.fit.as_dict()} for r, s in self.signals.items()
            },
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
            "units": {"pressure": "Pa", "current": "A", "spool_position": "m", "times": "s",
                      "metrics": "as named: bar, a (A), mm, ms, percent"},
            "warnings": list(self.warnings),
            "notes": list(self.notes),
            "in_force": self.in_force.as_dict() if self.in_force is not None else None,
        }


def detect_steps(
    timeline: InputTimeline, end_ns: int, *, min_hold: float = 0.02, min_amplitude: float = 0.005
) -> tuple[list[Step], list[str]]:
    """Duty steps in the command timeline, and notes on changes not taken as steps."""
    t = timeline.t_ns
    d = timeline.duty
    changes = [k for k in range(1, len(t)) if d[k] != d[k - 1]]
    groups: list[list[int]] = []
    hold_ns = int(round(min_hold * _NS))
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
        steps.append(Step(len(steps) + 1, start / _NS, int(t[g[-1]]) / _NS, end / _NS, d_from, d_to, len(g)))
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
) -> ReplayResult:
    """Drive ``model`` with the recording's inputs and compare it with the measured outputs."""
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
    for role in OUTPUT_ROLES:
        if role not in recording.measured:
            continue
        s = recording.measured[role]
        idx = np.searchsorted(sample_ns, s.t_ns)
        model_values = run.outputs[role][idx]
        signals[role] = SignalResult(role, fit_metrics(s.value, model_values), len(s))
        traces[role] = (s.t, s.value, model_values)
    steps, step_notes = detect_steps(timeline, end_ns, min_hold=min_hold)
    comparisons = []
    for st in steps:
        meas: dict[str, StepMetrics] = {}
        mod: dict[str, StepMetrics] = {}
        for role, (t, y_meas, y_mod) in traces.items():
            inside = (t >= st.t_start) & (t <= st.t_end)
            if np.count_nonzero(inside) < 3 or not np.any(t < st.t_start):
                continue
            band = DISPLAY[role].band_min
            meas[role] = step_metrics(t, y_meas, st.t_start, st.t_end, band_min=band)
            # The model is judged in the measured band (widened by the sensor's noise): same gate.
            mod[role] = step_metrics(t, y_mod, st.t_start, st.t_end, band_min=max(band, meas[role].band))
        if meas:
            comparisons.append(StepComparison(st, meas, mod))
        else:
            step_notes.append(f"step {st.index} at {st.t_start:.3f} s has too few samples to analyse")
    duty_t = timeline.t_ns.astype(np.float64) / _NS
    return ReplayResult(
        bag=str(recording.path),
        model=model,
        solver=run.solver,
        duration_s=end_ns / _NS,
        topics=recording.topics,
        closed_cleanly=recording.closed_cleanly,
        signals=signals,
        steps=tuple(comparisons),
        traces=traces,
        duty=(duty_t, timeline.duty.copy()),
        input_changes=len(timeline),
        elapsed_s=elapsed,
        warnings=recording.warnings,
        notes=recording.notes + tuple(tl_notes) + run.notes + tuple(step_notes),
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
