"""The campaign's HTML report (`DIR/report.html`, one file, images inline): the summary, the
pass/fail map of a sweep, each assertion's margin against each varied number, histograms of
the margins (limits and margins in engineering units: mm, bar, ms, `pcv_sim.units`), and links
to the worst variants' own scenario reports (`DIR/variants/K.html`), which this renders by
running those variants again (alone, fresh: the same values as in the table)."""

from __future__ import annotations

import html
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pcv_sim.campaign.runner import ERROR, PASSED, Worker
from pcv_sim.campaign.spec import Campaign
from pcv_sim.markup import png_source
from pcv_sim.plotting import png, pyplot
from pcv_sim.units import display, fmt

__all__ = ["write_report"]

_MAX_PARAMETERS = 6


def _png(fig: Any) -> str:
    return f"<img alt='plot' src='{png_source(png(fig, dpi=80, bbox_inches='tight'))}'>"


def _numeric(rows: Sequence[Mapping[str, Any]], columns: Sequence[str]) -> list[str]:
    return [c for c in columns if rows and all(isinstance(r.get(c), (int, float)) and not isinstance(r.get(c), bool)
                                               for r in rows)]


def _plots(campaign: Campaign, rows: Sequence[Mapping[str, Any]], varied: Sequence[str], names: Sequence[str],
           kinds: Mapping[str, str]) -> list[str]:
    plt = pyplot()

    out: list[str] = []
    numeric = [c for c in _numeric(rows, varied)
               if len({r[c] for r in rows}) > 1][:_MAX_PARAMETERS]
    colour = ["tab:green" if r["status"] == PASSED else "tab:red" if r["status"] != ERROR else "black" for r in rows]
    if campaign.sweep is not None:
        sweep_cols = [t.columns[0] for t, _ in campaign.sweep.parameters if t.columns[0] in numeric][:2]
        if sweep_cols:
            fig, ax = plt.subplots(figsize=(5, 4))
            x = [r[sweep_cols[0]] for r in rows]
            y = [r[sweep_cols[1]] for r in rows] if len(sweep_cols) > 1 else [0.0] * len(rows)
            ax.scatter(x, y, c=colour, s=40, marker="s")
            ax.set_xlabel(sweep_cols[0])
            ax.set_ylabel(sweep_cols[1] if len(sweep_cols) > 1 else "")
            ax.set_title("pass (green) / fail (red) / error (black) over the sweep")
            out.append("<h2>Pass/fail map</h2>" + _png(fig))
    ran = [r for r in rows if r["status"] != ERROR]
    # margins in each assertion's engineering unit (mm, bar, ms...), as the tables show them
    unit = {n: display(kinds.get(n, "number")) for n in names}
    if numeric and names and ran:
        fig, axes = plt.subplots(len(names), len(numeric), figsize=(3.2 * len(numeric), 2.6 * len(names)),
                                 squeeze=False)
        for i, n in enumerate(names):
            for j, c in enumerate(numeric):
                ax = axes[i][j]
                ax.scatter([r[c] for r in ran], [r.get(f"{n}.margin", math.nan) * unit[n][1] for r in ran], s=8,
                           c=["tab:green" if r.get(f"{n}.passed") else "tab:red" for r in ran])
                ax.axhline(0.0, color="grey", lw=0.8)
                if i == len(names) - 1:
                    ax.set_xlabel(c, fontsize=8)
                if j == 0:
                    ax.set_ylabel(f"{n}\nmargin [{unit[n][0]}]", fontsize=8)
                ax.tick_params(labelsize=7)
        out.append("<h2>Margin against each varied value</h2>" + _png(fig))
    if names and ran:
        fig, axes = plt.subplots(1, len(names), figsize=(3.5 * len(names), 2.8), squeeze=False)
        for j, n in enumerate(names):
            m = np.array([r.get(f"{n}.margin", math.nan) for r in ran], float) * unit[n][1]
            m = m[np.isfinite(m)]
            ax = axes[0][j]
            if len(m):
                ax.hist(m, bins=min(30, max(5, len(m) // 5)), color="tab:blue")
            ax.axvline(0.0, color="red", lw=0.8)
            ax.set_title(f"{n}: margin [{unit[n][0]}]", fontsize=8)
            ax.tick_params(labelsize=7)
        out.append("<h2>Margins</h2>" + _png(fig))
    return out


def write_report(campaign: Campaign, summary: Mapping[str, Any], rows: Sequence[Mapping[str, Any]],
                 varied: Sequence[str], names: Sequence[str], out: Path) -> Path:
    """DIR/report.html and the worst variants' scenario reports beside it; the report's path."""
    from pcv_sim.rig.report import render_html

    esc = html.escape
    links = []
    worker = Worker(campaign)
    (out / "variants").mkdir(parents=True, exist_ok=True)
    for w in summary["worst"]:
        k = int(w["index"])
        _, result, _ = worker.run_recorded(k)
        if result is not None:
            (out / "variants" / f"{k}.html").write_text(render_html(result), encoding="utf-8")
            links.append(f"<li><a href='variants/{k}.html'>variant {k}</a>: {esc(w['status'])}, relative margin "
                         f"{w['relative_margin']:.4g}</li>")
        else:
            links.append(f"<li>variant {k}: {esc(str(w.get('error')))}</li>")
    lo, hi = summary["pass_rate_ci95"]
    gate = summary["gate"]
    per = "".join(f"<tr><td>{esc(n)}</td><td>{a['pass_rate']:.4f}</td><td>{esc(fmt(a['limit'], a['kind']))}</td>"
                  f"<td>{esc(fmt(a['worst_margin'], a['kind']))}</td><td>{a['worst_variant']}</td></tr>"
                  for n, a in summary["assertions"].items())
    corr_rows = "".join(
        f"<tr><td>{esc(c)}</td>" + "".join(f"<td>{by.get(n, math.nan):+.2f}</td>" for n in names) + "</tr>"
        for c, by in summary["rank_correlation"].items())
    parts = [
        f"<!doctype html><html><head><meta charset='utf-8'><title>campaign {esc(campaign.name)}</title></head><body>",
        f"<h1>Campaign {esc(campaign.name)}: gate {'holds' if gate['holds'] else 'DOES NOT HOLD'}</h1>",
        f"<p>{summary['done']} of {summary['variants']} variants: {summary['passed']} passed, {summary['failed']} "
        f"failed, {summary['errors']} errors. Pass rate {summary['pass_rate']:.4f} (95 % CI {lo:.4f} .. {hi:.4f}); "
        f"gate pass_rate &gt;= {gate['pass_rate']:g}.</p>",
        "<h2>Assertions</h2><table border='1' cellpadding='4'><tr><th>assertion</th><th>pass rate</th><th>limit</th>"
        f"<th>worst margin</th><th>worst variant</th></tr>{per}</table>",
        "<h2>Worst variants</h2><ul>" + ("".join(links) or "<li>none</li>") + "</ul>",
    ]
    if corr_rows:
        parts.append("<h2>Rank correlation (Spearman) of each varied value with each margin</h2>"
                     "<table border='1' cellpadding='4'><tr><th></th>"
                     + "".join(f"<th>{esc(n)}</th>" for n in names) + f"</tr>{corr_rows}</table>")
    sens = summary.get("sensitivity")
    if sens is not None:
        key = "ST" if sens["method"] == "sobol" else "mu_star"
        idx = sens["indices"]
        if isinstance(idx.get("error"), str):
            parts.append(f"<h2>Sensitivity ({esc(sens['method'])})</h2><p>{esc(idx['error'])}</p>")
        else:
            dims = [d.name for d in campaign.sensitivity.dimensions] if campaign.sensitivity else []
            body = "".join(
                f"<tr><td>{esc(n)}</td>" + ("".join(f"<td>{by[d][key]:.3g}</td>" for d in dims) if "error" not in by
                                             else f"<td colspan='{len(dims)}'>{esc(by['error'])}</td>") + "</tr>"
                for n, by in idx.items())
            parts.append(f"<h2>Sensitivity ({esc(sens['method'])}: {key} of each margin)</h2>"
                         "<table border='1' cellpadding='4'><tr><th></th>"
                         + "".join(f"<th>{esc(d)}</th>" for d in dims) + f"</tr>{body}</table>")
    parts += _plots(campaign, rows, varied, names, {n: a["kind"] for n, a in summary["assertions"].items()})
    parts.append("</body></html>")
    path = out / "report.html"
    path.write_text("\n".join(parts), encoding="utf-8")
    return path
