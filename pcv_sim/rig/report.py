"""The review report of a scenario run: one self-contained HTML file (plots inline as PNG).

Engineering units throughout (bar, mm, mm/s, ms, %, N, A; `pcv_sim.units.display`); each
assertion with its value, limit, margin and the time of its worst point; limits and bands drawn
on the plot of their signal, each violation marked there (a red x and line) and named in the
table; with a valve option on (docs/model.md R33-R35) the coil and oil temperatures, the coil
resistance and the core's gap to the spool in panels of their own; every event (the timeline's
duty, force, supply, temperatures, faults and clears, the rig's watchdog and rejected commands)
in a table and as numbered lines on every plot; the measured signal
beside the true one where a sensor fault made them differ; the run's metadata (package version,
seed, the config's hash, date). `render_index` is the page of a folder run.
"""

from __future__ import annotations

import html
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pcv_sim.io.topics import (
    AMBIENT_TEMPERATURE,
    COIL_RESISTANCE,
    COIL_TEMPERATURE,
    CORE_POSITION,
    OIL_TEMPERATURE,
    SPOOL_POSITION,
)
from pcv_sim.markup import png_source
from pcv_sim.rig.assertions import Outcome, outcome_kind, signal_kind
from pcv_sim.rig.lockstep import RigRun
from pcv_sim.rig.rig import TEMPERATURE_INPUTS
from pcv_sim.units import KINDS, display, fmt

__all__ = ["outcome_kind", "plot_run", "render_html", "render_index"]

_VIOLATION = "#d62728"
_BAND = "#2ca02c"


#: Series a report derives from a run's signals: name -> (minuend, subtrahend) per valve.
_GAP = "core_gap"


def _derived(run: RigRun) -> dict[str, np.ndarray]:
    """The core's gap to the spool (spool position - core position, m) of each valve whose core
    is its own body (R35): zero while they move as one."""
    return {f"{v}.{_GAP}": run.signal(f"{v}.{SPOOL_POSITION}") - run.signal(f"{v}.{CORE_POSITION}")
            for v in run.valves if f"{v}.{CORE_POSITION}" in run.signals}


def _panels(run: RigRun, extra: Mapping[str, np.ndarray]) -> list[tuple[str, str, list[str]]]:
    """(title, kind, signals) per plot: the rig's, then those of the valve options that are on."""
    v = list(run.valves)
    present = set(run.signals) | set(extra)
    forces = [n for n in extra if "." not in n]             # the timeline's inputs on the piston
    out = [("piston position", "length", ["cylinder.position", "setpoint"]),
           ("chamber pressures", "pressure", [f"{x}.pressure" for x in v]),
           ("duties", "fraction", [f"{x}.duty" for x in v]),
           ("coil currents", "current", [f"{x}.current" for x in v]),
           ("piston velocity", "velocity", ["cylinder.velocity"]),
           ("forces", "force", ["cylinder.effort", *forces])]
    temperatures = [f"{x}.{n}" for x in v for n in (COIL_TEMPERATURE, AMBIENT_TEMPERATURE, OIL_TEMPERATURE)
                    if f"{x}.{n}" in present]
    if temperatures:
        out.append(("temperatures", "temperature", temperatures))
    if any(f"{x}.{COIL_RESISTANCE}" in present for x in v):
        out.append(("coil resistances [ohm]", "number", [f"{x}.{COIL_RESISTANCE}" for x in v]))
    if any(f"{x}.{_GAP}" in present for x in v):
        out.append(("core gap to the spool", "length", [f"{x}.{_GAP}" for x in v]))
    if run.flags:
        out.append(("controller flags", "number", list(run.flags)))
    return out


def _scale(kind: str) -> tuple[str, float, float]:
    """The unit a panel of `kind` is drawn in, the factor SI -> it and its zero (degC's 273.15)."""
    unit, f = display(kind)
    return unit, f, KINDS[kind].zero(unit)


def _series(run: RigRun, extra: Mapping[str, np.ndarray], name: str, measured: bool = False) -> np.ndarray | None:
    if name in extra:
        return extra[name]
    if name == "setpoint" and not np.any(np.isfinite(run.setpoint)):
        return None
    try:
        return run.signal(name, measured=measured)
    except KeyError:
        return None


def plot_run(run: RigRun, *, outcomes: Sequence[Outcome] = (), events: Sequence[tuple[float, str]] = (),
             extra: Mapping[str, np.ndarray] | None = None, title: str = "") -> bytes:
    """A PNG of the run in engineering units with the assertions' limits, bands and violations and
    the numbered events drawn (see the module docstring)."""
    from pcv_sim.plotting import png, pyplot

    plt = pyplot()
    extra = {**_derived(run), **(extra or {})}
    panels = _panels(run, extra)
    fig, axes = plt.subplots(len(panels), 1, figsize=(10, 2.3 * len(panels) + 0.6), sharex=True)
    t = run.times
    where: dict[str, Any] = {}
    for ax, (label, kind, names) in zip(axes, panels):
        unit, f, z = _scale(kind)
        for name in names:
            y = _series(run, extra, name)
            if y is None:
                continue
            # inputs dashed: the setpoint, the oil's and the ambient's temperatures
            style = "--" if name == "setpoint" or name.rpartition(".")[2] in TEMPERATURE_INPUTS else "-"
            (line,) = ax.plot(t, y * f - z, style, lw=1.2,
                              label=name.replace("cylinder.", "").replace("controller.", "").replace("_", " "))
            where[name] = (ax, f, z)
            m = _series(run, extra, name, measured=True)
            if m is not None and name in run.signals and not np.array_equal(m, y, equal_nan=True):
                ax.plot(t, m * f - z, ":", lw=1.2, color=line.get_color(), label=f"{name} measured")
        ax.set_ylabel(f"{label}\n[{unit}]" if unit != "-" else label, fontsize=8)
        ax.grid(True, alpha=0.3)
    for o in outcomes:
        d = o.draw
        sig = d.get("signal", o.signal)
        if sig not in where:
            continue
        ax, f, z = where[sig]
        t0, t1 = d.get("t0", t[0]), d.get("t1", t[-1])
        if "tolerance" in d:
            ref = d.get("reference")
            tt = t[(t >= t0 - 1e-12) & (t <= t1 + 1e-12)]
            r = (np.full(len(tt), float(ref)) if isinstance(ref, (int, float)) else
                 np.interp(tt, t, run.signal(str(ref))))
            ax.fill_between(tt, (r - d["tolerance"]) * f - z, (r + d["tolerance"]) * f - z, color=_BAND, alpha=0.18,
                            lw=0, label=f"band: {o.name}")
        for key in ("hi", "lo"):
            if key in d:
                ax.hlines(d[key] * f - z, t0, t1, colors=_BAND if o.passed else _VIOLATION, linestyles="--", lw=1.2,
                          label=f"limit: {o.name}")
        if "deadline" in d:
            ax.axvline(d["deadline"], color=_BAND if o.passed else _VIOLATION, ls="--", lw=1.0,
                       label=f"deadline: {o.name}")
        if "baseline" in d:
            tb, yb = d["baseline"]
            ax.plot(tb, np.asarray(yb) * f - z, color="0.4", lw=1.0, ls="-.", label="baseline")
        if not o.passed and o.time is not None and math.isfinite(o.time):
            y = _series(run, extra, sig)
            if y is not None:
                k = int(np.argmin(np.abs(t - o.time)))
                ax.plot([o.time], [y[k] * f - z], "x", color=_VIOLATION, ms=11, mew=2.5,
                        label=f"violation {o.time:.3f} s")
            ax.axvline(o.time, color=_VIOLATION, lw=1.0)
    for n, (te, _text) in enumerate(events, start=1):
        for ax in axes:
            ax.axvline(te, color="0.45", lw=0.8, ls=":")
        axes[0].annotate(f"E{n}", (te, 1.0), xycoords=("data", "axes fraction"), fontsize=7, color="0.3",
                         ha="left", va="bottom")
    for ax in axes:
        if ax.get_legend_handles_labels()[0]:
            ax.legend(loc="center left", bbox_to_anchor=(1.0, 0.5), fontsize=7, frameon=False)
    axes[-1].set_xlabel("time [s]")
    if title:
        fig.suptitle(title, y=1.0)
    fig.tight_layout()
    return png(fig, dpi=90, bbox_inches="tight")


_CSS = """body{font-family:sans-serif;margin:1.5em;max-width:1200px}table{border-collapse:collapse;margin:.5em 0}
td,th{border:1px solid #bbb;padding:3px 8px;font-size:13px;text-align:left}th{background:#eee}
.pass{color:#1a7f37;font-weight:bold}.fail{color:#d62728;font-weight:bold}.num{text-align:right;font-family:monospace}
.meta td{border:none;padding:1px 8px}h1{font-size:22px}h2{font-size:17px;margin-top:1.2em}"""


def _head(title: str) -> str:
    return (f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title>"
            f"<style>{_CSS}</style></head><body>")


def _drawn(o: Outcome) -> str:
    """What the plot shows for an outcome, in words (the figure's caption)."""
    d, k = o.draw, signal_kind(o.signal) if o.signal else "number"
    parts = []
    span = f" over {d['t0']:.3f}-{d['t1']:.3f} s" if "t0" in d and "t1" in d else ""
    if "tolerance" in d:
        ref = d.get("reference")
        ref_s = fmt(float(ref), k) if isinstance(ref, (int, float)) else str(ref)
        parts.append(f"<span class='band'>band {ref_s} &plusmn; {fmt(d['tolerance'], k)}{span}</span>")
    for key, word in (("hi", "upper"), ("lo", "lower")):
        if key in d:
            parts.append(f"<span class='limit'>{word} limit {fmt(d[key], k)}{span}</span>")
    if "deadline" in d:
        parts.append(f"<span class='limit'>deadline {d['deadline']:.3f} s</span>")
    return "; ".join(parts)


def render_html(result: Any) -> str:
    """The report of a `ScenarioResult` (see the module docstring)."""
    esc = html.escape
    verdict = "passed" if result.passed else "FAILED"
    parts = [_head(f"{result.name}: {verdict}"),
             f"<h1>Scenario {esc(result.name)}: <span class='{'pass' if result.passed else 'fail'}'>{verdict}"
             "</span></h1>"]
    meta = dict(result.meta or {})
    rows = [("file", result.path), ("pcv_sim", meta.get("pcv_sim", "")), ("seed", meta.get("seed", "")),
            ("config hash", meta.get("config_hash", "")), ("date", meta.get("date", "")),
            ("duration", f"{meta['duration_s']:g} s" if "duration_s" in meta else ""),
            ("real-time factor", f"{result.real_time_factor:.1f}x ({result.wall_time:.3f} s wall)")]
    parts.append("<table class='meta'>" + "".join(f"<tr><td>{esc(k)}</td><td>{esc(str(v))}</td></tr>"
                                                  for k, v in rows) + "</table>")
    if result.error:
        parts.append(f"<p class='fail'>{esc(result.error)}</p>")
    for n in result.notes:
        parts.append(f"<p class='note'>note: {esc(n)}</p>")
    trs = []
    for o in result.outcomes:
        k = outcome_kind(o)
        worst = "" if o.time is None or not math.isfinite(o.time) else f"{o.time:.4f} s"
        mark = (f"<span class='violation' data-t='{o.time:.6g}'>violated at {worst}</span>"
                if not o.passed and worst else worst)
        trs.append(f"<tr><td>{esc(o.name)}</td><td class='{'pass' if o.passed else 'fail'}'>"
                   f"{'pass' if o.passed else 'FAIL'}</td><td class='num'>{esc(fmt(o.value, k))}</td>"
                   f"<td class='num'>{esc(fmt(o.limit, k))}</td><td class='num'>{esc(fmt(o.margin, k))}</td>"
                   f"<td class='num'>{mark}</td><td>{_drawn(o)}</td><td>{esc(o.detail)}</td></tr>")
    parts.append("<h2>Assertions</h2><table><tr><th>assertion</th><th>result</th><th>value</th><th>limit</th>"
                 "<th>margin</th><th>worst point</th><th>drawn</th><th>detail (SI)</th></tr>"
                 f"{''.join(trs) or '<tr><td colspan=8>none</td></tr>'}</table>")
    run = result.run
    events = sorted([(t, "timeline", text) for t, text in result.events] +
                    ([(t, "rig", text) for t, text in run.log if not text.startswith(("fault ", "cleared "))] +
                     [(t, "rig", f"rejected: {text}") for t, text in run.rejected] if run is not None else []),
                    key=lambda e: e[0])
    ev_rows = "".join(f"<tr class='event'><td>E{n}</td><td class='num'>{t:.4f} s</td><td>{src}</td>"
                      f"<td>{esc(text)}</td></tr>" for n, (t, src, text) in enumerate(events, start=1))
    parts.append("<h2>Events</h2><table><tr><th>#</th><th>time</th><th>source</th><th>event</th></tr>"
                 f"{ev_rows or '<tr><td colspan=4>none</td></tr>'}</table>")
    if run is not None:
        image = png_source(plot_run(run, outcomes=result.outcomes, events=[(t, x) for t, _, x in events],
                                    extra=getattr(result, "inputs", {}), title=result.name))
        caption = "; ".join(f"{esc(o.name)}: {_drawn(o)}" for o in result.outcomes if _drawn(o))
        parts.append(f"<h2>Run</h2><figure><img alt='the run: signals, limits, bands, violations and events' "
                     f"src='{image}'><figcaption>Drawn: {caption or 'no limits'}; events as "
                     "numbered dotted lines; violations as red x.</figcaption></figure>")
    parts.append("</body></html>")
    return "\n".join(parts)


def render_index(results: Sequence[Mapping[str, Any]], *, title: str, base: Path | None = None) -> str:
    """The page of a folder run: one row per scenario, linked to its report."""
    esc = html.escape
    rows = []
    for r in results:
        status = {0: ("pass", "passed"), 1: ("fail", "FAILED"), 2: ("fail", "BAD FILE")}[int(r["status"])]
        link = r.get("report")
        if link and base is not None:
            link = str(Path(link).relative_to(base)) if Path(link).is_relative_to(base) else link
        name = f"<a href='{esc(str(link))}'>{esc(r['name'])}</a>" if link else esc(r["name"])
        failed = [a["name"] for a in r.get("assertions", []) if not a["passed"]]
        why = r.get("error") or ", ".join(failed)
        rows.append(f"<tr><td>{name}</td><td class='{status[0]}'>{status[1]}</td>"
                    f"<td class='num'>{len(r.get('assertions', []))}</td><td>{esc(why or '')}</td></tr>")
    n = len(results)
    ok = sum(int(r["status"]) == 0 for r in results)
    return (_head(f"scenarios {title}") + f"<h1>Scenarios in {esc(title)}: {ok} of {n} passed</h1>"
            "<table><tr><th>scenario</th><th>result</th><th>assertions</th><th>failed</th></tr>"
            + "".join(rows) + "</table></body></html>")
