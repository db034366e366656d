"""Calibration output: the fitted valve YAML and the report (text, Markdown or HTML with plots).

Rendering only: every number comes from a :class:`~pcv_sim.calibration.fit.CalibrationResult`
and the replays before and after (:class:`~pcv_sim.replay.compare.ReplayResult`).
"""

from __future__ import annotations

import html
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from pcv_sim.analysis.metrics import StepMetrics
from pcv_sim.calibration.fit import CalibrationError, CalibrationResult
from pcv_sim.markup import html_table, markdown_table, png_source, relative_link
from pcv_sim.params import params_from_mapping
from pcv_sim.plotting import png, pyplot
from pcv_sim.replay.compare import DISPLAY, Step, compare_step

__all__ = ["StepFit", "fitted_yaml", "plot_fit", "render_html", "render_markdown", "render_text", "step_fits", "step_rows"]


def _yaml_float(v: float) -> str:
    """A float YAML 1.1 (PyYAML) reads as a float: 6 significant digits, '.' in the mantissa."""
    s = f"{v:.6g}"
    mant, e, exp = s.partition("e")
    if "." not in mant:
        mant += ".0"
    return mant + (e + exp if e else "")


def fitted_yaml(source: str, result: CalibrationResult, origin: Sequence[str],
                overrides: Mapping[str, float | str] | None = None) -> str:
    """The valve YAML ``source`` with each fitted key's value replaced (comments kept), a note
    with the interval beside it, and a header naming the recordings; ``overrides`` (key -> value,
    e.g. the damping the fit ran with) are written too. Checked by loading it."""
    lines = source.splitlines()
    edits = [(e.name, _yaml_float(e.value), f"# fitted by pcv-sim calibrate: +-{e.half_width_95:.2g} (95 %), was "
                                             f"{e.initial:.6g}") for e in result.parameters]
    fitted_keys = {e.name for e in result.parameters}
    edits += [(k, v if isinstance(v, str) else _yaml_float(v), "# set for pcv-sim calibrate")
              for k, v in (overrides or {}).items() if k not in fitted_keys]
    for key, text_value, note in edits:
        section, _, name = key.partition(".")
        start = next((k for k, line in enumerate(lines) if re.match(rf"^{re.escape(section)}:\s*(#.*)?$", line)), None)
        if start is None:
            msg = f"cannot find section {section!r} in the source YAML to write {key}"
            raise CalibrationError(msg)
        found = False
        for k in range(start + 1, len(lines)):
            line = lines[k]
            if line and not line[0].isspace() and not line.startswith("#"):
                break
            m = re.match(rf"^(\s+{re.escape(name)}:\s*)(\S[^#]*?|)(\s*)(#.*)?$", line)
            if m:
                lines[k] = f"{m.group(1)}{text_value}   {note}"
                found = True
                break
        if not found:
            msg = f"cannot find {key} in the source YAML's section {section!r}"
            raise CalibrationError(msg)
    header = [f"# Calibrated with pcv-sim calibrate ({result.model} model) from: {', '.join(origin)}",
              "# " + "; ".join(f"{e.name} = {e.value:.6g} +- {e.half_width_95:.2g} {e.unit}" for e in result.parameters)]
    text = "\n".join(header + lines) + "\n"
    check = params_from_mapping(yaml.safe_load(text), origin="fitted YAML")
    for est in result.parameters:
        section, _, name = est.name.partition(".")
        got = getattr(getattr(check, section), name)
        if not math.isclose(float(got), est.value, rel_tol=1e-5):
            msg = f"the written YAML reads {est.name} = {got!r}, not {est.value:g}"
            raise CalibrationError(msg)
    return text


def _f(v: float, digits: int = 4) -> str:
    if math.isnan(v):
        return "n/a"
    if math.isinf(v):
        return "inf"
    return f"{v:.{digits}g}"


def _param_rows(r: CalibrationResult) -> list[list[str]]:
    rows = []
    for e in r.parameters:
        rows.append([e.name, e.unit, _f(e.initial, 6), _f(e.value, 6), f"+-{_f(e.half_width_95, 2)}",
                     f"{_f(e.value - e.half_width_95, 5)} .. {_f(e.value + e.half_width_95, 5)}",
                     "at bound" if e.at_bound else ""])
    return rows


def _nuisance_rows(r: CalibrationResult) -> list[list[str]]:
    rows = []
    for e in r.lags:
        rows.append([f"sensor lag, {e.name[4:]}", "ms", _f(e.value * 1e3, 4), f"+-{_f(e.half_width_95 * 1e3, 2)}"])
    for e in r.time_constants:
        rows.append([f"sensor time constant, {e.name[14:]}", "ms", _f(e.value * 1e3, 4),
                     f"+-{_f(e.half_width_95 * 1e3, 2)}"])
    for e in r.offsets:
        role = e.name.split(".")[1].split("[")[0]
        d = DISPLAY.get(role)
        scale, unit = (d.scale, d.unit) if d else (1.0, e.unit)
        rows.append([f"offset, {e.name[7:]}", unit, _f(e.value * scale, 4), f"+-{_f(e.half_width_95 * scale, 2)}"])
    return rows


def _signal_rows(r: CalibrationResult) -> list[list[str]]:
    rows = []
    for s in r.signals:
        d = DISPLAY[s.role]
        rows.append([Path(s.bag).name, d.label, _f(s.noise_sigma * d.scale, 3) + " " + d.unit,
                     f"{s.fit_before_percent:.2f}", f"{s.fit_after_percent:.2f}",
                     _f(s.rmse_before * d.scale, 4), _f(s.rmse_after * d.scale, 4)])
    return rows


@dataclass(frozen=True)
class StepFit:
    """One step of one signal: step metrics of the measurement and of the model before and
    after the fit (the fitted sensor applied), all read in the measured band. SI units."""

    step: Step
    role: str
    measured: StepMetrics
    before: StepMetrics
    after: StepMetrics

    def as_dict(self) -> dict[str, Any]:
        return {"index": self.step.index, "t_start_s": self.step.t_start, "duty_from": self.step.duty_from,
                "duty_to": self.step.duty_to, "signal": self.role, "measured": self.measured.as_dict(),
                "before": self.before.as_dict(), "after": self.after.as_dict(),
                "steady_state_error_before": self.before.final - self.measured.final,
                "steady_state_error_after": self.after.final - self.measured.final}


def step_fits(r: CalibrationResult, bag: int, steps: Sequence[Step]) -> list[StepFit]:
    """Per step and signal of bag ``bag``: step metrics measured / model before / model after
    (the fitted sensor applied: what the fit compared), all in the measured band."""
    out = []
    for st in steps:
        for role in DISPLAY:
            if (bag, role) not in r.traces:
                continue
            t, meas, before, after = r.traces[(bag, role)]
            compared = compare_step(st, role, t, meas, (before, after))
            if compared is not None:
                m, (b, a) = compared
                out.append(StepFit(st, role, m, b, a))
    return out


def step_rows(fits: Sequence[StepFit]) -> list[list[str]]:
    """The step fits as table rows in display units (bar, A, mm; ms)."""
    rows = []
    for f in fits:
        d = DISPLAY[f.role]
        m, b, a = f.measured, f.before, f.after
        rows.append([
            str(f.step.index), f"{f.step.duty_from:g} -> {f.step.duty_to:g}", d.label,
            f"{_f(m.final * d.scale, 5)} / {_f(b.final * d.scale, 5)} / {_f(a.final * d.scale, 5)}",
            f"{_f((b.final - m.final) * d.scale, 3)} -> {_f((a.final - m.final) * d.scale, 3)}",
            f"{_f(m.rise_time * 1e3, 3)} / {_f(b.rise_time * 1e3, 3)} / {_f(a.rise_time * 1e3, 3)}",
            f"{_f(m.settling_time * 1e3, 3)} / {_f(b.settling_time * 1e3, 3)} / {_f(a.settling_time * 1e3, 3)}",
        ])
    return rows


_PARAM_HEAD = ["parameter", "unit", "start", "fitted", "95 % interval", "range", ""]
_NUIS_HEAD = ["nuisance", "unit", "fitted", "95 % interval"]
_SIG_HEAD = ["bag", "signal", "noise sigma", "fit % before", "fit % after", "RMSE before", "RMSE after"]
_STEP_HEAD = ["step", "duty", "signal", "steady state meas / before / after", "steady-state error before -> after",
              "rise [ms] meas / before / after", "settling [ms] meas / before / after"]


def _corr_rows(r: CalibrationResult) -> list[list[str]]:
    names = [e.name for e in r.parameters]
    return [[names[i]] + [f"{r.correlation[i, j]:+.3f}" for j in range(len(names))] for i in range(len(names))]


def render_text(r: CalibrationResult) -> str:
    lines = [f"Calibration ({r.model} model, {r.solver}): {r.evaluations} evaluations, {r.simulations} "
             f"simulations, {r.elapsed_s:.1f} s; {r.status}"]
    lines.append(f"  {'parameter':40s} {'start':>12s} {'fitted':>12s} {'95 % interval':>14s}  unit")
    for e in r.parameters:
        flag = "  (at bound)" if e.at_bound else ""
        lines.append(f"  {e.name:40s} {e.initial:12.6g} {e.value:12.6g} {'+-' + _f(e.half_width_95, 2):>14s}  {e.unit}{flag}")
    for row in _nuisance_rows(r):
        lines.append(f"  {row[0]:40s} {'':>12s} {row[2]:>12s} {row[3]:>14s}  {row[1]}")
    if len(r.parameters) > 1:
        lines.append("  correlations: " + ", ".join(
            f"{r.parameters[i].name} ~ {r.parameters[j].name}: {r.correlation[i, j]:+.3f}"
            for i in range(len(r.parameters)) for j in range(i + 1, len(r.parameters))))
    lines.append(f"  {'bag':24s} {'signal':16s} {'fit % before':>12s} {'after':>8s}")
    for s in r.signals:
        lines.append(f"  {Path(s.bag).name[:24]:24s} {DISPLAY[s.role].label:16s} {s.fit_before_percent:12.2f} "
                     f"{s.fit_after_percent:8.2f}")
    for w in r.warnings:
        lines.append(f"  warning: {w}")
    return "\n".join(lines)


def _intro(r: CalibrationResult, damping: str) -> list[str]:
    return [
        f"Model: {r.model} ({r.solver}); {damping}.",
        f"Cost (robust, 1/2 sum of weighted residuals^2): {r.cost_before:.6g} -> {r.cost_after:.6g}; "
        f"{r.evaluations} evaluations, {r.simulations} simulations, {r.elapsed_s:.1f} s; {r.status}",
        f"Residual lag-1 autocorrelation {r.autocorrelation:.3f}: intervals inflated by "
        f"{(1 + r.autocorrelation) / (1 - r.autocorrelation):.2f} in variance.",
        "Fit % = NRMSE fit, 100 (1 - ||y_model - y|| / ||y - mean y||). 'after' is the fitted model seen "
        "through the fitted sensor (delay, time constant, offset), as the fit compared it; 'before' the "
        "starting model without a sensor model, as replay compares it.",
    ]


def render_markdown(r: CalibrationResult, steps: Sequence[tuple[str, list[list[str]]]], plots: Mapping[str, Path],
                    base: Path, damping: str) -> str:
    out = ["# Calibration", ""] + [f"- {x}" for x in _intro(r, damping)] + [""]
    if r.warnings:
        out += ["## Warnings", ""] + [f"- {w}" for w in r.warnings] + [""]
    out += ["## Parameters", "", markdown_table(_PARAM_HEAD, _param_rows(r)), ""]
    out += ["## Correlations", "", markdown_table(["", *[e.name for e in r.parameters]], _corr_rows(r)), ""]
    out += ["## Sensor lag and offset (nuisance)", "", markdown_table(_NUIS_HEAD, _nuisance_rows(r)), ""]
    out += ["## Fit per signal", "", markdown_table(_SIG_HEAD, _signal_rows(r)), ""]
    for bag, rows in steps:
        out += [f"## Steps: {bag}", "", markdown_table(_STEP_HEAD, rows) if rows else "No step could be analysed.", ""]
    for name, path in plots.items():
        out += [f"![{name}]({relative_link(path, base)})", ""]
    return "\n".join(out)


def render_html(r: CalibrationResult, steps: Sequence[tuple[str, list[list[str]]]], pngs: Mapping[str, bytes],
                damping: str) -> str:
    e = html.escape
    parts = ["<!DOCTYPE html><html><head><meta charset='utf-8'><title>pcv-sim calibration</title>",
             "<style>body{font-family:sans-serif;max-width:1100px;margin:auto}table{border-collapse:collapse}"
             "td,th{border:1px solid #bbb;padding:3px 7px;text-align:right}.warn{color:#a40}</style></head><body>",
             "<h1>Calibration</h1><ul>" + "".join(f"<li>{e(x)}</li>" for x in _intro(r, damping)) + "</ul>"]
    if r.warnings:
        parts.append("<h2>Warnings</h2><ul>" + "".join(f"<li class='warn'>{e(w)}</li>" for w in r.warnings) + "</ul>")
    parts += ["<h2>Parameters</h2>", html_table(_PARAM_HEAD, _param_rows(r)),
              "<h2>Correlations</h2>", html_table(["", *[x.name for x in r.parameters]], _corr_rows(r)),
              "<h2>Sensor lag and offset (nuisance)</h2>", html_table(_NUIS_HEAD, _nuisance_rows(r)),
              "<h2>Fit per signal</h2>", html_table(_SIG_HEAD, _signal_rows(r))]
    for bag, rows in steps:
        parts += [f"<h2>Steps: {e(bag)}</h2>", html_table(_STEP_HEAD, rows) if rows else "<p>No step analysed.</p>"]
    for name, image in pngs.items():
        parts.append(f"<h3>{e(name)}</h3><img alt='{e(name)}' src='{png_source(image)}'>")
    parts.append("</body></html>")
    return "\n".join(parts)


def plot_fit(r: CalibrationResult, bags: Sequence[str]) -> dict[str, bytes]:
    """PNG per bag and signal: measured, model before and after (with lag and offset), errors."""
    plt = pyplot()

    out: dict[str, bytes] = {}
    for (b, role), (t, meas, before, after) in r.traces.items():
        d = DISPLAY[role]
        fig, (ax, ax_err) = plt.subplots(2, 1, figsize=(10, 5.5), sharex=True, gridspec_kw={"height_ratios": [3, 1]})
        ax.plot(t, meas * d.scale, "-", lw=1.0, color="0.5", label="measured")
        ax.plot(t, before * d.scale, "--", lw=1.0, label="model before")
        ax.plot(t, after * d.scale, "-", lw=1.1, label="model after (with sensor lag, offset)")
        ax.set_ylabel(f"{d.label} [{d.unit}]")
        ax.grid(True, alpha=0.3)
        ax.legend(loc="best", fontsize=8)
        ax.set_title(f"{Path(bags[b]).name}: {d.label}")
        ax_err.plot(t, (before - meas) * d.scale, lw=0.7, label="before")
        ax_err.plot(t, (after - meas) * d.scale, lw=0.7, label="after")
        ax_err.set_ylabel(f"error [{d.unit}]")
        ax_err.set_xlabel("time since first duty command [s]")
        ax_err.grid(True, alpha=0.3)
        ax_err.legend(loc="best", fontsize=8)
        fig.tight_layout()
        out[f"{Path(bags[b]).name}_{role}"] = png(fig, dpi=90)
    return out

