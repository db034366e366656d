"""Running variants inside one worker process: the campaign prepared once, variants run in chunks.

A worker (a local process, the campaign command's own process, or a Dask worker) keeps what it
prepared per campaign (the variant table, the last rig built): imports and compiled kernels are
loaded once per process, and a rig whose parameters the next variant shares is reset, not
rebuilt (a reset rig runs bit for bit as a new one: the tests compare both). A variant whose
model runs away, whose values a loader refuses or whose controller raises is a row with status
`error` and its reason; nothing a variant does stops the campaign.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Iterable
from typing import Any

import numpy as np

from pcv_sim.campaign.spec import Campaign
from pcv_sim.campaign.variants import Variant, Variants
from pcv_sim.errors import PcvSimError
from pcv_sim.rig.assertions import outcome_kind
from pcv_sim.rig.rig import Rig
from pcv_sim.rig.scenario import Outcome, Scenario, ScenarioResult, resolve_controller, run_scenario

__all__ = ["ERROR", "FAILED", "PASSED", "Worker", "margin", "run_chunk", "worker_for"]

PASSED, FAILED, ERROR = "passed", "failed", "error"


def margin(o: Outcome) -> float:
    """How far the found value is inside its limit (> 0, passed) or beyond it (< 0), in the
    assertion's unit: the outcome's own margin, or |limit - value| signed by the outcome."""
    if not math.isnan(o.margin):
        return float(o.margin)
    if math.isnan(o.value) or math.isnan(o.limit):
        return math.nan
    gap = abs(o.limit - o.value)
    return gap if o.passed else -gap


def metrics(result: ScenarioResult, valves: tuple[str, ...]) -> dict[str, float]:
    """The run's figures besides its assertions (deterministic: no wall times)."""
    run = result.run
    out: dict[str, float] = {}
    if run is None:
        return out
    x, sp = run.signal("cylinder.position"), run.setpoint
    finite = np.isfinite(sp)
    out["metric.position_rms_error"] = float(np.sqrt(np.mean((x[finite] - sp[finite]) ** 2))) if finite.any() \
        else math.nan
    out["metric.position_peak"] = float(np.max(np.abs(x)))
    for v in valves:
        out[f"metric.{v}.peak_pressure"] = float(np.max(run.signal(f"{v}.pressure")))
    out["metric.rejected_commands"] = float(len(run.rejected))
    return out


class Worker:
    """A campaign prepared in this process."""

    def __init__(self, campaign: Campaign) -> None:
        self.campaign = campaign
        self.variants = Variants(campaign)
        self._rig: Rig | None = None
        self._rig_key: Any = None

    def scenario(self, v: Variant) -> Scenario:
        return self.campaign.base.scenario_for(v.parameters, v.timeline, v.at)

    def rig(self, scenario: Scenario) -> Rig:
        key = (scenario.rig, scenario.seed)
        if self._rig is None or self._rig_key != key:
            self._rig, self._rig_key = None, None
            self._rig = Rig(scenario.rig, seed=scenario.seed)
            self._rig_key = key
        return self._rig

    def run(self, k: int) -> dict[str, Any]:
        """Variant k's row (and its timing under '_timing')."""
        return self.run_recorded(k)[0]

    def run_recorded(self, k: int) -> tuple[dict[str, Any], ScenarioResult | None, Scenario | None]:
        """Variant k's row, its scenario result (None: it did not run) and its scenario."""
        t0 = time.perf_counter()
        v = self.variants[k]
        row: dict[str, Any] = {"index": k, "status": ERROR, **v.values}
        timing = {"setup_s": math.nan, "run_s": math.nan}
        try:
            scenario = self.scenario(v)
            controller = None
            if scenario.controller is not None:
                controller = resolve_controller(scenario.controller, scenario.controller_params,
                                                scenario.path.parent if scenario.path else None)
            rig = self.rig(scenario)
        except PcvSimError as err:
            row["error"] = f"variant {k} cannot be built: {err}"
            row["_timing"] = timing
            return row, None, None
        t1 = time.perf_counter()
        try:
            result = run_scenario(scenario, controller, rig=rig)
        except Exception as err:       # the user's controller: any exception is its failure, not ours
            self._rig, self._rig_key = None, None
            row["error"] = f"the controller raised {type(err).__name__}: {err}"
            timing.update(setup_s=t1 - t0, run_s=time.perf_counter() - t1)
            row["_timing"] = timing
            return row, None, scenario
        timing.update(setup_s=t1 - t0, run_s=time.perf_counter() - t1)
        if result.error:
            self._rig, self._rig_key = None, None
            row["error"] = result.error
        else:
            row["status"] = PASSED if result.passed else FAILED
            seen: list[str] = []
            kinds: dict[str, str] = {}
            for o in result.outcomes:           # an assertion may check several limits: one outcome each
                name, j = o.name, 2
                while name in seen:
                    name, j = f"{o.name} #{j}", j + 1
                seen.append(name)
                kinds[name] = outcome_kind(o)
                row[f"{name}.passed"] = o.passed
                row[f"{name}.limit"] = o.limit
                row[f"{name}.value"] = o.value
                row[f"{name}.margin"] = margin(o)
            row.update(metrics(result, tuple(s.name for s in scenario.rig.valves)))
            row["_kinds"] = kinds               # the unit kind of each value, limit and margin (not a column)
        row["_timing"] = timing
        return row, result, scenario


_LOCAL = threading.local()             # a Dask worker may run tasks on several threads


def worker_for(campaign: Campaign) -> Worker:
    """This thread's Worker for `campaign` (prepared at the first call)."""
    cache: dict[str, Worker] = getattr(_LOCAL, "workers", None) or {}
    _LOCAL.workers = cache
    w = cache.get(campaign.digest)
    if w is None:
        cache.clear()                  # one campaign at a time per worker: drop the last one's rig
        w = cache[campaign.digest] = Worker(campaign)
    return w


def run_chunk(campaign: Campaign, indices: Iterable[int]) -> list[dict[str, Any]]:
    """Rows of the variants `indices` (the task a local or a Dask worker runs)."""
    w = worker_for(campaign)
    return [w.run(k) for k in indices]
