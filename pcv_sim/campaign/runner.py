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
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

from pcv_sim.campaign.spec import Campaign
from pcv_sim.campaign.variants import Variant, Variants
from pcv_sim.errors import PcvSimError
from pcv_sim.rig.assertions import outcome_kind
from pcv_sim.rig.batch import batchable, run_lockstep_batch
from pcv_sim.rig.lockstep import Controller, RigRun
from pcv_sim.rig.rig import Rig
from pcv_sim.rig.scenario import (
    RUN_STOPS,
    Outcome,
    Scenario,
    ScenarioResult,
    resolve_controller,
    run_scenario,
    scenario_result,
    scenario_stopped,
    schedule_timeline,
)

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
        #: the rigs last built, per place in a batch (0: a variant alone), with their keys
        self._rigs: dict[int, tuple[Any, Rig]] = {}

    def scenario(self, v: Variant) -> Scenario:
        return self.campaign.base.scenario_for(v.parameters, v.timeline, v.at)

    def rig(self, scenario: Scenario, place: int = 0) -> Rig:
        """A rig for `scenario`: the one last built at `place` when its parameters are the same."""
        key = (scenario.rig, scenario.seed)
        kept = self._rigs.get(place)
        if kept is not None and kept[0] == key:
            return kept[1]
        self._rigs.pop(place, None)
        rig = Rig(scenario.rig, seed=scenario.seed)
        self._rigs[place] = (key, rig)
        return rig

    def run(self, k: int) -> dict[str, Any]:
        """Variant k's row (and its timing under '_timing')."""
        return self.run_recorded(k)[0]

    def _build(self, k: int, place: int) -> tuple[dict[str, Any], dict[str, float],
                                                   tuple[Scenario, Controller | None, Rig] | None]:
        """Variant k's row so far, its timing, and its scenario, controller and rig (None: the
        variant cannot be built; the row says why)."""
        v = self.variants[k]
        row: dict[str, Any] = {"index": k, "status": ERROR, **v.values}
        timing = {"setup_s": math.nan, "run_s": math.nan}
        try:
            scenario = self.scenario(v)
            controller = None
            if scenario.controller is not None:
                controller = resolve_controller(scenario.controller, scenario.controller_params,
                                                scenario.path.parent if scenario.path else None)
            rig = self.rig(scenario, place)
        except PcvSimError as err:
            row["error"] = f"variant {k} cannot be built: {err}"
            row["_timing"] = timing
            return row, timing, None
        return row, timing, (scenario, controller, rig)

    def _finish(self, row: dict[str, Any], timing: dict[str, float], scenario: Scenario,
                result: ScenarioResult | Exception, place: int) -> tuple[dict[str, Any], ScenarioResult | None]:
        """The row of a variant that ran: its outcomes and metrics, or its error."""
        row["_timing"] = timing
        if isinstance(result, Exception):      # the user's controller: any exception is its failure, not ours
            self._rigs.pop(place, None)
            row["error"] = f"the controller raised {type(result).__name__}: {result}"
            return row, None
        if result.error:
            self._rigs.pop(place, None)
            row["error"] = result.error
            return row, result
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
        return row, result

    def run_recorded(self, k: int) -> tuple[dict[str, Any], ScenarioResult | None, Scenario | None]:
        """Variant k's row, its scenario result (None: it did not run) and its scenario."""
        t0 = time.perf_counter()
        row, timing, built = self._build(k, 0)
        if built is None:
            return row, None, None
        scenario, controller, rig = built
        t1 = time.perf_counter()
        result: ScenarioResult | Exception
        try:
            result = run_scenario(scenario, controller, rig=rig)
        except Exception as err:       # the user's controller: any exception is its failure, not ours
            result = err
        timing.update(setup_s=t1 - t0, run_s=time.perf_counter() - t1)
        row, res = self._finish(row, timing, scenario, result, 0)
        return row, res, scenario

    def run_batch(self, indices: Sequence[int]) -> list[dict[str, Any]]:
        """The rows of the variants `indices` run as one batch (`pcv_sim.rig.batch`: their rigs
        stepped in one compiled call per control period): the same rows as `run` of each, bit for
        bit. Variants that cannot share a batch (not built, another rig structure, a controller
        without the lockstep's array form) run alone."""
        t0 = time.perf_counter()
        built = [self._build(k, place) for place, k in enumerate(indices)]
        members = [j for j, (_, _, b) in enumerate(built) if b is not None and _array_form(b[1])]
        rows: dict[int, dict[str, Any]] = {j: built[j][0] for j, (_, _, b) in enumerate(built) if b is None}
        rigs: list[Rig] = []
        for j in members:
            parts = built[j][2]
            assert parts is not None
            scenario, _, rig = parts
            rig.reset()
            schedule_timeline(rig, scenario)
            rigs.append(rig)
        if len(members) > 1 and batchable(rigs) is None and len({built[j][2][0].duration for j in members}) == 1:
            t1 = time.perf_counter()
            parts_of = [built[j][2] for j in members]
            runs = run_lockstep_batch(rigs, [p[1] for p in parts_of], parts_of[0][0].duration,
                                      setpoints=[p[0].setpoint_function() for p in parts_of])
            run_s = (time.perf_counter() - t1) / len(members)
            for j, parts, run, rig in zip(members, parts_of, runs, rigs, strict=True):
                scenario = parts[0]
                result: ScenarioResult | Exception
                if isinstance(run, RigRun):
                    result = scenario_result(scenario, run)
                elif isinstance(run, RUN_STOPS):
                    result = scenario_stopped(scenario, rig, run, run_s)
                elif isinstance(run, Exception):
                    result = run
                else:
                    raise run
                row, timing, _ = built[j]
                timing.update(setup_s=(t1 - t0) / len(indices), run_s=run_s)
                rows[j] = self._finish(row, timing, scenario, result, j)[0]
        for j in range(len(indices)):           # what did not run in the batch runs alone
            if j not in rows:
                rows[j] = self.run(indices[j]) if j == 0 else self._alone(indices[j], j)
        return [rows[j] for j in range(len(indices))]

    def _alone(self, k: int, place: int) -> dict[str, Any]:
        """Variant k alone on the rig kept at `place` (as `run`, which uses place 0)."""
        t0 = time.perf_counter()
        row, timing, built = self._build(k, place)
        if built is None:
            return row
        scenario, controller, rig = built
        t1 = time.perf_counter()
        result: ScenarioResult | Exception
        try:
            result = run_scenario(scenario, controller, rig=rig)
        except Exception as err:       # the user's controller: any exception is its failure, not ours
            result = err
        timing.update(setup_s=t1 - t0, run_s=time.perf_counter() - t1)
        return self._finish(row, timing, scenario, result, place)[0]


def _array_form(controller: Controller | None) -> bool:
    """Whether the controller offers the lockstep's array form (what a batch calls)."""
    return controller is not None and callable(getattr(controller, "lockstep_arrays", None))


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


def run_chunk(campaign: Campaign, indices: Iterable[int], batch: int = 1) -> list[dict[str, Any]]:
    """Rows of the variants `indices` (the task a local or a Dask worker runs), `batch` at a time
    in one batch (`Worker.run_batch`; 1: each alone). The same rows either way."""
    w = worker_for(campaign)
    todo = list(indices)
    if batch <= 1:
        return [w.run(k) for k in todo]
    rows: list[dict[str, Any]] = []
    for i in range(0, len(todo), batch):
        group = todo[i:i + batch]
        rows += w.run_batch(group) if len(group) > 1 else [w.run(group[0])]
    return rows
