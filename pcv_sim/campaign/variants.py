"""The variants of a campaign: variant k's values, a pure function of (campaign file, k).

The sections present combine as a product, faults outermost and Monte Carlo innermost:
k = (f * n_sweep + s) * n_samples + m. A sweep's grid runs its first key slowest (product) or
all keys together (zip). Monte Carlo draws the whole design from its seed at once: a matrix U of
uniforms in [0, 1) (numpy's PCG64 from `seed`, or a Latin hypercube from scipy.stats.qmc seeded
the same way), one column per independent dimension (each valve of a `valves.` key unless tied),
mapped through each distribution's inverse CDF (a truncated normal through scipy.stats.truncnorm).
Every process that needs variant k computes the same matrix, so no values travel between them.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import stats
from scipy.stats import qmc

from pcv_sim.campaign.sensitivity import design
from pcv_sim.campaign.spec import Campaign, Distribution, _check_value, fault_entries
from pcv_sim.campaign.targets import FAULT_COLUMNS, CampaignError

__all__ = ["Variant", "Variants"]

# A uniform of exactly 0 would map to -inf through a normal's inverse CDF.
_U_EDGE = 1e-15


@dataclass(frozen=True)
class Variant:
    index: int
    values: Mapping[str, Any]              # every varied column -> its value (SI), fault columns included
    timeline: tuple[Mapping[str, Any], ...] = ()     # entries appended to the scenario's timeline
    at: Mapping[tuple[str | int, ...], Any] = field(default_factory=dict)  # scenario paths set to the onset

    @property
    def parameters(self) -> dict[str, Any]:
        """The values written into the files (the fault matrix's columns aside)."""
        return {k: v for k, v in self.values.items() if k not in FAULT_COLUMNS}


def _ppf(d: Distribution, u: np.ndarray) -> np.ndarray:
    if d.kind == "uniform":
        return d.low + u * (d.high - d.low)
    u = np.clip(u, _U_EDGE, 1.0 - _U_EDGE)
    if math.isinf(d.low) and math.isinf(d.high):
        return np.asarray(stats.norm.ppf(u, loc=d.mean, scale=d.sd))
    a, b = (d.low - d.mean) / d.sd, (d.high - d.mean) / d.sd
    return np.clip(stats.truncnorm.ppf(u, a, b, loc=d.mean, scale=d.sd), d.low, d.high)


class Variants:
    """The variants of `campaign`, indexed 0 .. len - 1; `validate` checks the Monte Carlo
    values' extremes with the parameters' own validation (CampaignError naming the key)."""

    def __init__(self, campaign: Campaign, *, validate: bool = False) -> None:
        self.campaign = c = campaign
        self.columns: list[str] = []
        if c.faults is not None:
            self.columns += FAULT_COLUMNS
        if c.sweep is not None:
            self.columns += [col for t, _ in c.sweep.parameters for col in t.columns]
        self.samples: dict[str, np.ndarray] = {}
        if c.sensitivity is not None:
            x = design(c.sensitivity)
            for j, sd in enumerate(c.sensitivity.dimensions):
                for col in sd.columns:
                    self.samples[col] = x[:, j]
                    self.columns.append(col)
        mc = c.monte_carlo
        if mc is not None:
            dims: list[list[tuple[str, Distribution]]] = []
            for t, dists in mc.parameters:
                if dists[0].tied:
                    dims.append(list(zip(t.columns, dists)))
                else:
                    dims += [[(col, d)] for col, d in zip(t.columns, dists)]
            rng = np.random.default_rng(mc.seed)
            if mc.sampling == "latin_hypercube":
                u = qmc.LatinHypercube(d=len(dims), rng=rng).random(mc.samples)
            else:
                u = rng.random((mc.samples, len(dims)))
            for j, dim in enumerate(dims):
                for col, d in dim:
                    self.samples[col] = _ppf(d, u[:, j])
            self.columns += [col for t, _ in mc.parameters for col in t.columns]
            if validate:
                for col, x in self.samples.items():
                    for v in (float(np.min(x)), float(np.max(x))):
                        _check_value(c.base, col, v, f"monte_carlo.parameters ({mc.samples} samples, seed {mc.seed})")

    def __len__(self) -> int:
        return self.campaign.size

    def __getitem__(self, k: int) -> Variant:
        c = self.campaign
        if not 0 <= k < c.size:
            raise CampaignError(f"variant {k}: accepted is 0 .. {c.size - 1}")
        n_mc, n_sw = c.monte_carlo_size, c.sweep_size
        m, s, f = k % n_mc, (k // n_mc) % n_sw, k // (n_mc * n_sw)
        values: dict[str, Any] = {}
        timeline: tuple[Mapping[str, Any], ...] = ()
        at: dict[tuple[str | int, ...], Any] = {}
        if c.faults is not None:
            kind, target, onset = c.faults.cells[f]
            values.update(zip(FAULT_COLUMNS, (kind, target, onset)))
            timeline = tuple(fault_entries(c.faults, kind, target, onset, c.base.scenario.duration))
            at = dict.fromkeys(c.faults.at_onset, onset)
        if c.sweep is not None:
            params = c.sweep.parameters
            if c.sweep.combine == "zip":
                picks = [s] * len(params)
            else:
                picks = []
                rest = s
                for _, vals in reversed(params):
                    picks.append(rest % len(vals))
                    rest //= len(vals)
                picks.reverse()
            for (t, vals), j in zip(params, picks):
                for col in t.columns:
                    values[col] = vals[j]
        for col, x in self.samples.items():
            values[col] = float(x[m])
        return Variant(k, values, timeline, at)
