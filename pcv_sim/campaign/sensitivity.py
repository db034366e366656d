"""Global sensitivity of each assertion's margin to chosen parameters, through SALib.

    sensitivity:
      method: sobol                  # sobol (Saltelli/Sobol' sampling, first and total order
                                     # indices) or morris (elementary effects: mu*, sigma)
      samples: 64                    # N: sobol N (D + 2) variants (N a power of 2), morris N (D + 1)
      seed: 1
      levels: 4                      # morris grid levels
      parameters:                    # uniform over [low, high] (SI) or nominal +- tolerance (SI or N%)
        valves.spool.spring_preload: {tolerance: 5%}          # each valve its own dimension unless tied
        cylinder.mass: {low: 40.0, high: 60.0}

The design (SALib's sampler, seeded) gives the variants; once they have all run, SALib's analyser
gives the indices per assertion margin. Which tolerance matters for which requirement.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["METHODS", "Dimension", "Sensitivity", "analyze", "design", "size"]

METHODS = ("sobol", "morris")


@dataclass(frozen=True)
class Dimension:
    name: str
    columns: tuple[str, ...]               # the columns it sets (every valve of a tied key)
    low: float
    high: float


@dataclass(frozen=True)
class Sensitivity:
    method: str
    samples: int
    seed: int
    levels: int
    dimensions: tuple[Dimension, ...]


def _problem(s: Sensitivity) -> dict[str, Any]:
    return {"num_vars": len(s.dimensions), "names": [d.name for d in s.dimensions],
            "bounds": [[d.low, d.high] for d in s.dimensions]}


def size(s: Sensitivity) -> int:
    d = len(s.dimensions)
    return s.samples * (d + 2) if s.method == "sobol" else s.samples * (d + 1)


def design(s: Sensitivity) -> np.ndarray:
    """The variants' values, one row per variant, one column per dimension."""
    if s.method == "sobol":
        from SALib.sample import sobol

        x = sobol.sample(_problem(s), s.samples, calc_second_order=False, seed=s.seed)
    else:
        from SALib.sample import morris

        x = morris.sample(_problem(s), s.samples, num_levels=s.levels, seed=s.seed)
    return np.asarray(x, float)


def analyze(s: Sensitivity, rows: Sequence[Mapping[str, Any]], names: Sequence[str]) -> dict[str, Any]:
    """Per assertion: per dimension the indices (sobol: S1, ST and their 95 % confidence
    half-widths; morris: mu_star, sigma, mu_star_conf), or why they could not be computed."""
    out: dict[str, Any] = {}
    if len(rows) != size(s):
        return {"error": f"{len(rows)} of {size(s)} variants ran; the indices need them all"}
    x = design(s)
    for n in names:
        y = np.array([float(r.get(f"{n}.margin", math.nan)) for r in rows])
        if not np.all(np.isfinite(y)):
            out[n] = {"error": f"{int(np.sum(~np.isfinite(y)))} variants without a finite margin (errors, or a "
                               "flag never raised)"}
            continue
        if np.ptp(y) == 0:
            out[n] = {d.name: dict.fromkeys(("S1", "ST") if s.method == "sobol" else ("mu_star", "sigma"), 0.0)
                      for d in s.dimensions}
            continue
        if s.method == "sobol":
            from SALib.analyze import sobol as sobol_analyze

            r = sobol_analyze.analyze(_problem(s), y, calc_second_order=False, seed=s.seed)
            keys: tuple[str, ...] = ("S1", "S1_conf", "ST", "ST_conf")
        else:
            from SALib.analyze import morris as morris_analyze

            r = morris_analyze.analyze(_problem(s), x, y, num_levels=s.levels, seed=s.seed)
            keys = ("mu_star", "mu_star_conf", "sigma")
        out[n] = {d.name: {k: float(r[k][j]) for k in keys} for j, d in enumerate(s.dimensions)}
    return out
