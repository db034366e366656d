"""Rig-style recordings made with the model itself, to check calibration against a known truth.

A DAQ logs every sample: time (not starting at 0), duty in %, pressure in bar, current in A,
position in mm, each output seen through a sensor with a lag, white noise and an offset, and a
few broken rows. :func:`write_rig_csv` writes such a CSV from any parameter set (e.g. one with a
perturbed parameter); ``import-csv --skip-bad-rows`` turns it into a bag for ``calibrate``.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Literal

import numpy as np

from pcv_sim.calibration.fit import first_order
from pcv_sim.params import ValveParams
from pcv_sim.replay.compare import DISPLAY
from pcv_sim.replay.simulate import InputTimeline, run_model
from pcv_sim.units import M3S_PER_LPM, NS_PER_S

__all__ = ["RIG_HEADER", "write_rig_csv"]

RIG_HEADER = "time[s],duty[%],pressure[bar],current[A],position[mm]"
_DISPLAY = {role: d.scale for role, d in DISPLAY.items()}   # SI -> bar, A, mm


def write_rig_csv(
    path: str | os.PathLike[str],
    params: ValveParams,
    duties: Sequence[float],
    *,
    hold_s: float = 0.5,
    rate_hz: float = 1000.0,
    lag_s: Mapping[str, float] | None = None,
    noise: Mapping[str, float] | None = None,
    offset: Mapping[str, float] | None = None,
    time_origin_s: float = 12.5,
    broken_rows: int = 3,
    seed: int = 0,
    model: Literal["full", "simplified"] = "simplified",
    load_flows_lpm: Sequence[float] | None = None,
    time_constant_s: Mapping[str, float] | None = None,
) -> Path:
    """Write a CSV of the model driven by ``duties`` (each held ``hold_s``), as a rig logs it.

    ``lag_s``, ``noise`` (standard deviation) and ``offset`` per output role, SI units: the
    logged value at t is F[y](t - lag) + offset + noise, F a first-order sensor of
    ``time_constant_s`` (per role, default none). ``load_flows_lpm`` (one per duty, L/min)
    adds a load-flow column: static pressure-flow points where the inputs hold. Returns the path.
    """
    lag_s = dict(lag_s or {})
    noise = dict(noise or {})
    offset = dict(offset or {})
    rng = np.random.default_rng(seed)
    n = round(len(duties) * hold_s * rate_hz)
    period_ns = round(NS_PER_S / rate_hz)
    t_ns = np.arange(n, dtype=np.int64) * period_ns
    hold_ns = round(hold_s * NS_PER_S)
    change_ns = np.arange(len(duties), dtype=np.int64) * hold_ns
    flows = np.zeros(len(duties)) if load_flows_lpm is None else np.asarray(load_flows_lpm, float) * M3S_PER_LPM
    tl = InputTimeline(change_ns, np.asarray(duties, float), flows,
                       np.full(len(duties), params.circuit.supply_pressure))
    # The model at every sample time and at every lagged one (before 0 it rests).
    tcs = dict(time_constant_s or {})
    lag_ns = {r: round(lag_s.get(r, 0.0) * NS_PER_S) for r in _DISPLAY}
    times = [np.clip(t_ns - lag_ns[r], 0, None) for r in _DISPLAY]
    if tcs:  # the filter integrates the model exactly only between close samples: a 0.1 ms grid
        times.append(np.arange(0, int(t_ns[-1]) + 1, 100_000, dtype=np.int64))
    want = np.unique(np.concatenate(times))
    run = run_model(params, model, tl, want)
    segment = np.searchsorted(change_ns, t_ns, side="right") - 1
    cols = [t_ns / NS_PER_S + time_origin_s, np.asarray(duties, float)[segment] * 100.0]
    for role, scale in _DISPLAY.items():
        sensed = first_order(want / NS_PER_S, run.outputs[role], tcs.get(role, 0.0))   # 0.1 ms grid when filtered
        y = sensed[np.searchsorted(want, np.clip(t_ns - lag_ns[role], 0, None))]
        y = y + offset.get(role, 0.0) + rng.normal(0.0, noise.get(role, 0.0), n)
        cols.append(y * scale)
    header = RIG_HEADER
    if load_flows_lpm is not None:
        cols.append(flows[segment] / M3S_PER_LPM)
        header += ",load_flow[l/min]"
    rows = [",".join(f"{v:.9g}" for v in row) for row in np.column_stack(cols)]
    # A few broken rows, as a DAQ writes them: a dropped field, a text glitch, an empty value.
    glitches = ["{t},{d}", "{t},{d},ERR,,", "{t},{d},,1.0,0.0"]
    for k, at in enumerate(sorted(rng.choice(np.arange(10, n - 10), size=min(broken_rows, max(n - 20, 0)), replace=False))):
        t_text, d_text = rows[at].split(",")[:2]
        rows[at] = glitches[k % len(glitches)].format(t=t_text, d=d_text)
    out = Path(path)
    out.write_text(header + "\n" + "\n".join(rows) + "\n", encoding="utf-8")
    return out
