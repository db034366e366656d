"""A campaign's results: the store in its output directory, the table and the summary.

    DIR/campaign.json   what ran: the campaign's name, digest (of everything a variant depends
                        on), number of variants, columns
    DIR/variants.jsonl  one line per finished variant, appended as it arrives (what --resume reads)
    DIR/results.csv     one row per variant in index order: index, status, every varied value (SI),
                        each assertion's passed / value / margin, the run's metrics, the error
                        (deterministic: the same campaign gives the same file, byte for byte)
    DIR/timings.csv     per variant: set-up and run wall time (s), which vary from run to run

The summary: pass rate with its 95 % Wilson score interval, each assertion's pass rate and
worst margin (SI in the tables and --json, with its kind; the text and the report show it in
engineering units, `pcv_sim.units.fmt`), the worst variants (an error first, then by the smallest margin relative to its
limit), each varied number's Spearman rank correlation with each assertion's margin, the gate.
"""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

from pcv_sim.campaign.runner import ERROR, PASSED
from pcv_sim.campaign.sensitivity import analyze
from pcv_sim.campaign.spec import Campaign
from pcv_sim.errors import UsageError
from pcv_sim.units import fmt

__all__ = ["Store", "assertion_names", "columns", "summary", "summary_text", "wilson"]

_Z95 = 1.959963984540054


def wilson(passed: int, n: int, z: float = _Z95) -> tuple[float, float]:
    """The Wilson score interval of a binomial proportion (95 % by default)."""
    if n == 0:
        return (0.0, 1.0)
    p = passed / n
    d = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / d
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / d
    return (max(0.0, centre - half), min(1.0, centre + half))


def assertion_names(rows: Iterable[Mapping[str, Any]]) -> list[str]:
    """The outcomes' names in the rows, in the order they first appear (rows in index order)."""
    out: list[str] = []
    for r in rows:
        for k in r:
            if k.endswith(".passed") and k[:-7] not in out:
                out.append(k[:-7])
    return out


def columns(campaign: Campaign, varied: list[str], names: list[str]) -> list[str]:
    valves = [v.name for v in campaign.base.scenario.rig.valves]
    out = ["index", "status", *varied]
    for n in names:
        out += [f"{n}.passed", f"{n}.value", f"{n}.limit", f"{n}.margin"]
    out += ["metric.position_rms_error", "metric.position_peak", *(f"metric.{v}.peak_pressure" for v in valves),
            "metric.rejected_commands", "error"]
    return out


def _cell(v: Any) -> str:
    if v is None:
        return ""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return repr(v)               # every bit: the table compares exactly
    return str(v)


class Store:
    """The output directory of a campaign (see the module docstring)."""

    def __init__(self, out: Path, campaign: Campaign, varied: list[str], *, resume: bool) -> None:
        self.out, self.campaign, self.varied = out, campaign, varied
        meta = {"name": campaign.name, "digest": campaign.digest, "variants": campaign.size, "varied": varied}
        self.rows: dict[int, dict[str, Any]] = {}
        jsonl = out / "variants.jsonl"
        if resume and (out / "campaign.json").is_file():
            old = json.loads((out / "campaign.json").read_text(encoding="utf-8"))
            if old.get("digest") != campaign.digest:
                raise UsageError(f"--resume: {out} holds campaign {old.get('name')!r} ({old.get('digest')}), not this "
                                 f"one ({campaign.digest}: its file or the files it names changed); accepted is the "
                                 "same campaign, or a new --out")
            if jsonl.is_file():
                for line in jsonl.read_text(encoding="utf-8").splitlines():
                    try:
                        row = json.loads(line)
                    except json.JSONDecodeError:
                        continue             # a line cut short by the interrupt
                    self.rows[int(row["index"])] = row
                # rewritten whole: a line an interrupt cut short must not run into the next one
                jsonl.write_text("".join(json.dumps(r) + "\n" for r in self.ordered()), encoding="utf-8")
        elif not resume and jsonl.exists():
            raise UsageError(f"--out {out}: holds a campaign's results; accepted is --resume (run what is missing) "
                             "or a new directory")
        out.mkdir(parents=True, exist_ok=True)
        (out / "campaign.json").write_text(json.dumps(meta, indent=1), encoding="utf-8")
        self._file = jsonl.open("a", encoding="utf-8")

    def missing(self) -> list[int]:
        return [k for k in range(self.campaign.size) if k not in self.rows]

    def add(self, row: dict[str, Any]) -> None:
        self.rows[int(row["index"])] = row
        self._file.write(json.dumps(row) + "\n")
        self._file.flush()

    def close(self) -> None:
        self._file.close()
        self.write_tables()

    def ordered(self) -> list[dict[str, Any]]:
        return [self.rows[k] for k in sorted(self.rows)]

    @property
    def columns(self) -> list[str]:
        return columns(self.campaign, self.varied, assertion_names(self.ordered()))

    def write_tables(self) -> None:
        rows = self.ordered()
        cols = self.columns
        with (self.out / "results.csv").open("w", newline="", encoding="utf-8") as f:
            w = csv.writer(f)
            w.writerow(cols)
            for r in rows:
                w.writerow([_cell(r.get(c)) for c in cols])
        with (self.out / "timings.csv").open("w", newline="", encoding="utf-8") as f:
            w = csv.writer(f)
            w.writerow(["index", "setup_s", "run_s"])
            for r in rows:
                t = r.get("_timing", {})
                w.writerow([r["index"], _cell(t.get("setup_s")), _cell(t.get("run_s"))])


def _relative(row: Mapping[str, Any], names: list[str], limits: Mapping[str, float]) -> float:
    """The variant's smallest margin relative to its limit (-inf: it did not run to the end)."""
    if row["status"] == ERROR:
        return -math.inf
    out = math.inf
    for n in names:
        m = row.get(f"{n}.margin")
        if m is None or (isinstance(m, float) and math.isnan(m)):
            continue
        lim = abs(limits.get(n, 0.0))
        if lim == 0.0 and m >= 0.0:
            continue            # a limit of 0 gives no scale: only its violation (m < 0) ranks a variant
        out = min(out, m / lim if lim > 0 and math.isfinite(lim) else m)
    return out


def summary(campaign: Campaign, rows: Iterable[Mapping[str, Any]], varied: list[str], names: list[str],
            *, worst: int = 5) -> dict[str, Any]:
    rows = list(rows)
    n = len(rows)
    passed = sum(r["status"] == PASSED for r in rows)
    errors = sum(r["status"] == ERROR for r in rows)
    limits: dict[str, float] = {}
    for name in names:
        lim = next((r[f"{name}.limit"] for r in rows if f"{name}.limit" in r), math.nan)
        limits[name] = float(lim)
    per: dict[str, Any] = {}
    for name in names:
        ran = [r for r in rows if r["status"] != ERROR]
        m = np.array([r.get(f"{name}.margin", math.nan) for r in ran], float)
        ok = sum(bool(r.get(f"{name}.passed")) for r in ran)
        finite = np.isfinite(m) | np.isneginf(m)
        k = int(np.argmin(np.where(finite, m, np.inf))) if finite.any() else None
        kind = next((r["_kinds"][name] for r in ran if name in r.get("_kinds", {})), "number")
        per[name] = {"pass_rate": ok / len(ran) if ran else math.nan, "worst_margin": float(m[k]) if k is not None
                     else math.nan, "worst_variant": int(ran[k]["index"]) if k is not None else None,
                     "limit": limits[name], "kind": kind}
    order = sorted(rows, key=lambda r: (_relative(r, names, limits), r["index"]))
    worst_rows = [{"index": r["index"], "status": r["status"], "relative_margin": _relative(r, names, limits),
                   "error": r.get("error")} for r in order[:worst]]
    numeric = [c for c in varied if all(isinstance(r.get(c), (int, float)) and not isinstance(r.get(c), bool)
                                        for r in rows)]
    corr: dict[str, dict[str, float]] = {}
    for c in numeric:
        corr[c] = {}
        for name in names:
            pairs = [(float(r[c]), float(r[f"{name}.margin"])) for r in rows
                     if r["status"] != ERROR and math.isfinite(float(r.get(f"{name}.margin", math.nan)))]
            x = np.array([p[0] for p in pairs])
            y = np.array([p[1] for p in pairs])
            rho = math.nan
            if len(pairs) >= 3 and np.ptp(x) > 0 and np.ptp(y) > 0:
                rho = float(stats.spearmanr(x, y).statistic)
            corr[c][name] = rho
    rate = passed / n if n else math.nan
    lo, hi = wilson(passed, n)
    sens = analyze(campaign.sensitivity, rows, names) if campaign.sensitivity is not None else None
    return {"name": campaign.name, "variants": campaign.size, "done": n, "passed": passed,
            "failed": n - passed - errors, "errors": errors, "pass_rate": rate, "pass_rate_ci95": [lo, hi],
            "gate": {"pass_rate": campaign.pass_rate, "holds": n == campaign.size and rate >= campaign.pass_rate},
            "assertions": per, "worst": worst_rows, "rank_correlation": corr,
            **({"sensitivity": {"method": campaign.sensitivity.method, "indices": sens}}
               if campaign.sensitivity is not None else {})}


def summary_text(s: Mapping[str, Any]) -> str:
    lo, hi = s["pass_rate_ci95"]
    lines = [f"campaign {s['name']}: {s['done']} of {s['variants']} variants run: {s['passed']} passed, "
             f"{s['failed']} failed, {s['errors']} errors",
             f"pass rate {s['pass_rate']:.4f} (95 % CI {lo:.4f} .. {hi:.4f}); gate pass_rate >= "
             f"{s['gate']['pass_rate']:g}: {'holds' if s['gate']['holds'] else 'DOES NOT HOLD'}"]
    for name, a in s["assertions"].items():
        kind = a.get("kind", "number")
        lines.append(f"  {name}: pass rate {a['pass_rate']:.4f}, worst margin {fmt(a['worst_margin'], kind)} "
                     f"(variant {a['worst_variant']}; limit {fmt(a['limit'], kind)})")
    if s["worst"]:
        lines.append("worst variants: " + ", ".join(
            f"{w['index']} ({w['status']}{', ' + str(w['error'])[:80] if w.get('error') else ''})"
            for w in s["worst"]))
    if "sensitivity" in s:
        method = s["sensitivity"]["method"]
        key = "ST" if method == "sobol" else "mu_star"
        indices = s["sensitivity"]["indices"]
        if isinstance(indices.get("error"), str):
            lines.append(f"  sensitivity: {indices['error']}")
            indices = {}
        for name, by in indices.items():
            if "error" in by:
                lines.append(f"  sensitivity of {name}: {by['error']}")
                continue
            ranked = sorted(by.items(), key=lambda kv: -kv[1].get(key, 0.0))
            lines.append(f"  {method} {key} of {name}: " + ", ".join(f"{p} {v.get(key, 0.0):.3g}" for p, v in ranked))
    for c, by in s["rank_correlation"].items():
        figures = ", ".join(f"{n} {r:+.2f}" for n, r in by.items() if math.isfinite(r))
        if figures:
            lines.append(f"  rank correlation of {c} with the margins: {figures}")
    return "\n".join(lines)
