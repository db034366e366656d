"""Replay reports: text summary, Markdown or HTML with plots (measured vs model per signal).

Rendering only: every number comes from a :class:`~pcv_sim.replay.compare.ReplayResult`.
"""

from __future__ import annotations

import html
import math
from pathlib import Path

from pcv_sim.analysis.metrics import StepMetrics
from pcv_sim.markup import html_table, markdown_table, png_source, relative_link
from pcv_sim.plotting import png, pyplot
from pcv_sim.replay.compare import DISPLAY, ReplayResult, ThresholdFailure

__all__ = ["plot_signals", "render_html", "render_markdown", "render_text"]


def _f(v: float, digits: int = 4) -> str:
    if isinstance(v, float) and math.isnan(v):
        return "n/a"
    if isinstance(v, float) and math.isinf(v):
        return "inf"
    return f"{v:.{digits}g}"


def _summary_rows(r: ReplayResult) -> list[list[str]]:
    rows = []
    for role, sig in r.signals.items():
        d = DISPLAY[role]
        rows.append([d.label, d.unit, str(sig.samples), str(sig.excluded), _f(sig.fit.rmse * d.scale),
                     _f(sig.fit.max_error * d.scale), f"{sig.fit.nrmse_fit_percent:.4f}"])
    return rows


def _gap_summary(r: ReplayResult) -> str:
    if not r.gaps:
        return "none"
    d = [g.duration * 1e3 for g in r.gaps]
    excluded = sum(s.excluded for s in r.signals.values())
    return (f"{len(r.gaps)} ({min(d):.1f}-{max(d):.1f} ms, {sum(d):.1f} ms in all); not compared "
            f"across them: {excluded} samples from each gap until {r.resync_s * 1e3:g} ms after it")


def _gap_rows(r: ReplayResult) -> list[list[str]]:
    return [[str(k), f"{g.start:.4f}", f"{g.end:.4f}", f"{g.duration * 1e3:.1f}", str(g.missing),
             f"{g.end + r.resync_s:.4f}", ", ".join(g.roles)]
            for k, g in enumerate(r.gaps, start=1)]


_GAP_HEAD = ["gap", "last sample before [s]", "first sample after [s]", "duration [ms]", "missing samples",
             "compared again from [s]", "signals"]


def _step_rows(r: ReplayResult, role: str) -> list[list[str]]:
    d = DISPLAY[role]
    rows = []
    for sc in r.steps:
        if role not in sc.measured:
            continue
        m, s, e = sc.measured[role], sc.model[role], sc.errors(role)
        st = sc.step
        ramp = f" ({st.changes} cmds)" if st.changes > 1 else ""
        rows.append([
            str(st.index), f"{st.t_start:.3f}", f"{st.duty_from:g} -> {st.duty_to:g}{ramp}",
            f"{_f(m.rise_time * 1e3)} / {_f(s.rise_time * 1e3)}",
            f"{_f(m.overshoot_percent, 3)} / {_f(s.overshoot_percent, 3)}",
            f"{_f(m.settling_time * 1e3)}{_open(m)} / {_f(s.settling_time * 1e3)}",
            f"{_f(m.final * d.scale, 6)} / {_f(s.final * d.scale, 6)}",
            _f(e["steady_state_error"] * d.scale, 3),
        ])
    return rows


def _open(m: StepMetrics) -> str:
    """' (20..60)': the settling times (ms) the noise leaves open, when it leaves any."""
    if m.settling_early == m.settling_late or math.isnan(m.settling_early):
        return ""
    return f" ({_f(m.settling_early * 1e3)}..{_f(m.settling_late * 1e3)})"


_SUMMARY_HEAD = ["signal", "unit", "samples compared", "not compared (gaps)", "RMSE", "max error", "NRMSE fit %"]
_STEP_HEAD = ["step", "t [s]", "duty", "rise [ms] meas / model", "overshoot [%] meas / model",
              "settling [ms] meas / model", "steady state meas / model", "steady-state error"]


def _header_lines(r: ReplayResult) -> list[tuple[str, str]]:
    return [
        ("bag", r.bag),
        ("model", f"{r.model} ({r.solver})"),
        ("in force", r.in_force.text() if r.in_force is not None else "n/a"),
        ("duration", f"{r.duration_s:.3f} s, {r.input_changes} input changes, {len(r.steps)} steps"),
        ("topics", ", ".join(f"{k}={v}" for k, v in r.topics.items())),
        ("bag closed properly", "yes" if r.closed_cleanly else "NO: the writer did not finish; "
                                                                "the readable part was used"),
        ("gaps in the measured outputs", _gap_summary(r)),
        ("replay speed", f"{r.elapsed_s:.2f} s, {r.real_time_factor:.1f}x real time"),
    ]


def render_text(r: ReplayResult, failures: list[ThresholdFailure] | None = None) -> str:
    lines = [f"Replay of {r.bag}: {r.model} model ({r.solver}), {r.duration_s:.3f} s, "
             f"{len(r.steps)} steps, {r.real_time_factor:.1f}x real time"]
    if r.in_force is not None:
        lines.append(f"  {r.in_force.text()}")
    if not r.closed_cleanly:
        lines.append("  the bag was NOT closed properly: only its readable part was replayed")
    if r.gaps:
        lines.append(f"  gaps in the measured outputs: {_gap_summary(r)}")
        lines += [f"    gap {row[0]}: {row[1]} -> {row[2]} s ({row[3]} ms, ~{row[4]} samples missing), "
                  f"compared again from {row[5]} s" for row in _gap_rows(r)[:20]]
        if len(r.gaps) > 20:
            lines.append(f"    ... {len(r.gaps) - 20} more (--json or --report list them all)")
    lines.append(f"  {'signal':16s} {'unit':5s} {'RMSE':>10s} {'max error':>10s} {'fit %':>10s}")
    for row in _summary_rows(r):
        lines.append(f"  {row[0]:16s} {row[1]:5s} {row[4]:>10s} {row[5]:>10s} {row[6]:>10s}")
    for w in r.warnings:
        lines.append(f"  warning: {w}")
    for n in r.notes:
        lines.append(f"  note: {n}")
    for f in failures or []:
        lines.append(f"  FAILED: {f}")
    return "\n".join(lines)


def render_markdown(r: ReplayResult, plots: dict[str, Path], failures: list[ThresholdFailure],
                    base: Path) -> str:
    """Markdown; ``plots`` (role -> PNG) are linked relative to ``base`` (the report's folder)."""
    out = [f"# Replay: {Path(r.bag).name}", ""]
    out += [f"- **{k}**: {v}" for k, v in _header_lines(r)]
    out.append("")
    if failures:
        out += ["## Thresholds FAILED", ""] + [f"- {f}" for f in failures] + [""]
    if r.warnings:
        out += ["## Warnings from the bag reader", ""] + [f"- {w}" for w in r.warnings] + [""]
    if r.gaps:
        out += ["## Gaps (skipped intervals, not compared)", "",
                f"The measured outputs pause {len(r.gaps)} time(s); samples from each gap until "
                f"{r.resync_s * 1e3:g} ms after it are left out of the metrics (the model and the "
                f"device re-synchronise), and steps touching them are not analysed.", "",
                markdown_table(_GAP_HEAD, _gap_rows(r)), ""]
    out += ["## Whole run (model minus measured)", "", markdown_table(_SUMMARY_HEAD, _summary_rows(r)), ""]
    for role in r.signals:
        d = DISPLAY[role]
        out += [f"## Steps: {d.label} [{d.unit}]", ""]
        rows = _step_rows(r, role)
        out += [markdown_table(_STEP_HEAD, rows) if rows else "No step could be analysed.", ""]
        if role in plots:
            rel = relative_link(plots[role], base)
            out += [f"![{d.label}: measured vs model]({rel})", ""]
    if "duty" in plots:
        out += ["## Input", "", f"![duty command]({relative_link(plots['duty'], base)})", ""]
    if r.notes:
        out += ["## Notes", ""] + [f"- {n}" for n in r.notes] + [""]
    return "\n".join(out)


def render_html(r: ReplayResult, pngs: dict[str, bytes], failures: list[ThresholdFailure]) -> str:
    """A self-contained HTML page (plots embedded as PNG data URIs)."""
    e = html.escape
    parts = [
        "<!DOCTYPE html><html><head><meta charset='utf-8'>",
        f"<title>Replay: {e(Path(r.bag).name)}</title>",
        "<style>body{font-family:sans-serif;max-width:1100px;margin:2em auto}"
        "table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #bbb;padding:3px 8px;"
        "text-align:right}th{background:#eee}.bad{color:#b00;font-weight:bold}</style></head><body>",
        f"<h1>Replay: {e(Path(r.bag).name)}</h1><ul>",
    ]
    parts += [f"<li><b>{e(k)}</b>: {e(v)}</li>" for k, v in _header_lines(r)]
    parts.append("</ul>")
    if failures:
        parts.append("<h2 class='bad'>Thresholds FAILED</h2><ul>")
        parts += [f"<li class='bad'>{e(str(f))}</li>" for f in failures]
        parts.append("</ul>")
    if r.warnings:
        parts.append("<h2>Warnings from the bag reader</h2><ul>")
        parts += [f"<li>{e(w)}</li>" for w in r.warnings]
        parts.append("</ul>")
    if r.gaps:
        parts += ["<h2>Gaps (skipped intervals, not compared)</h2>",
                  f"<p>The measured outputs pause {len(r.gaps)} time(s); samples from each gap until "
                  f"{r.resync_s * 1e3:g} ms after it are left out of the metrics (the model and the device "
                  f"re-synchronise), and steps touching them are not analysed.</p>",
                  html_table(_GAP_HEAD, _gap_rows(r))]
    parts += ["<h2>Whole run (model minus measured)</h2>", html_table(_SUMMARY_HEAD, _summary_rows(r))]
    for role in r.signals:
        d = DISPLAY[role]
        parts.append(f"<h2>Steps: {e(d.label)} [{e(d.unit)}]</h2>")
        parts.append(html_table(_STEP_HEAD, _step_rows(r, role)))
        if role in pngs:
            parts.append(f"<img alt='{e(d.label)}' src='{png_source(pngs[role])}' style='max-width:100%'>")
    if "duty" in pngs:
        parts.append(f"<h2>Input</h2><img alt='duty' src='{png_source(pngs['duty'])}' style='max-width:100%'>")
    if r.notes:
        parts.append("<h2>Notes</h2><ul>")
        parts += [f"<li>{e(n)}</li>" for n in r.notes]
        parts.append("</ul>")
    parts.append("</body></html>")
    return "\n".join(parts)


def plot_signals(r: ReplayResult) -> dict[str, bytes]:
    """PNG bytes per output role (measured vs model, and the error below) and for the duty."""
    plt = pyplot()

    out: dict[str, bytes] = {}
    for role, (t, meas, mod) in r.traces.items():
        d = DISPLAY[role]
        fig, (ax, ax_err) = plt.subplots(2, 1, figsize=(10, 5.5), sharex=True,
                                         gridspec_kw={"height_ratios": [3, 1]})
        ax.plot(t, meas * d.scale, "-", lw=1.4, label="measured (bag)")
        ax.plot(t, mod * d.scale, "--", lw=1.1, label=f"model ({r.model})")
        for k, sc in enumerate(r.steps):  # the settling band of the measured response (noise-aware)
            if role in sc.measured:
                m = sc.measured[role]
                ax.fill_between([sc.step.t_start, sc.step.t_end], (m.final - m.band) * d.scale,
                                (m.final + m.band) * d.scale, color="C2", alpha=0.15, lw=0,
                                label="settling band (measured)" if k == 0 else None)
        ax.set_ylabel(f"{d.label} [{d.unit}]")
        ax.grid(True, alpha=0.3)
        ax.set_title(f"{Path(r.bag).name}: {d.label}, measured vs {r.model} model")
        ax_err.plot(t, (mod - meas) * d.scale, lw=0.9, color="C3")
        for k, (a, b) in enumerate(r.excluded_intervals):   # gaps + re-synchronisation: not compared
            for axis in (ax, ax_err):
                axis.axvspan(a, b, color="0.85", zorder=0, label="not compared (gap)" if k == 0 and axis is ax else None)
        ax.legend(loc="best")
        ax_err.set_ylabel(f"error [{d.unit}]")
        ax_err.set_xlabel("time since first duty command [s]")
        ax_err.grid(True, alpha=0.3)
        fig.tight_layout()
        out[role] = png(fig, dpi=100)
    t_d, duty = r.duty
    t_end = max(r.duration_s, float(t_d[-1]))
    fig, ax = plt.subplots(figsize=(10, 2.5))
    ax.step([*list(t_d), t_end], [*list(duty), duty[-1]], where="post")
    ax.set_ylabel("duty [-]")
    ax.set_xlabel("time since first duty command [s]")
    ax.grid(True, alpha=0.3)
    fig.tight_layout()
    out["duty"] = png(fig, dpi=100)
    return out
