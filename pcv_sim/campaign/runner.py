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
from pcv_sim.rig.batch import batchable, compiled_before, run_lockstep_batch
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

__all__ = ["AUTO_BATCH", "ERROR", "FAILED", "PASSED", "Worker", "batch_size", "margin", "run_chunk", "worker_for"]

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

    def run_recorded(self, k: int, place: int = 0) -> tuple[dict[str, Any], ScenarioResult | None, Scenario | None]:
        """Variant k's row, its scenario result (None: it did not run) and its scenario (on the
        rig kept at `place`)."""
        t0 = time.perf_counter()
        row, timing, built = self._build(k, place)
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
        row, res = self._finish(row, timing, scenario, result, place)
        return row, res, scenario

    def run_batch(self, indices: Sequence[int], *, compiled_only: bool = False) -> list[dict[str, Any]]:
        """The rows of the variants `indices` run as one batch (`pcv_sim.rig.batch`: their rigs
        stepped in one compiled call per control period): the same rows as `run` of each, bit for
        bit. Variants that cannot share a batch (not built, another rig structure, a controller
        without the lockstep's array form) run alone; with `compiled_only` all run alone unless
        the batch's compiled code is at hand (`compiled_before`)."""
        t0 = time.perf_counter()
        built = [self._build(k, place) for place, k in enumerate(indices)]
        rows: dict[int, dict[str, Any]] = {j: row for j, (row, _, parts) in enumerate(built) if parts is None}
        members: list[int] = []
        ready: list[tuple[Scenario, Controller | None, Rig]] = []
        for j, (_, _, parts) in enumerate(built):
            if parts is not None and _array_form(parts[1]):
                members.append(j)
                ready.append(parts)
        rigs = [rig for _, _, rig in ready]
        for scenario, _, rig in ready:
            rig.reset()
            schedule_timeline(rig, scenario)
        if len(members) > 1 and len({scenario.duration for scenario, _, _ in ready}) == 1 \
                and batchable(rigs) is None and (not compiled_only or compiled_before(rigs[0], len(rigs))):
            t1 = time.perf_counter()
            runs = run_lockstep_batch(rigs, [controller for _, controller, _ in ready], ready[0][0].duration,
                                      setpoints=[scenario.setpoint_function() for scenario, _, _ in ready])
            run_s = (time.perf_counter() - t1) / len(members)
            for j, (scenario, _, rig), run in zip(members, ready, runs, strict=True):
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
        for j, k in enumerate(indices):           # what did not run in the batch runs alone
            if j not in rows:
                rows[j] = self.run_recorded(k, j)[0]
        return [rows[j] for j in range(len(indices))]

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


#: The batch `batch=0` (auto) runs, when its compiled code is at hand (`compiled_before`): two
#: variants in one call cost 0.6x each in the compiled part (BENCHMARKS.md, "A batch axis").
AUTO_BATCH = 2


def batch_size(batch: int) -> int:
    """How many variants one batch holds for a `batch` setting (0: auto, `AUTO_BATCH`)."""
    if batch < 0:
        raise ValueError(f"batch {batch}: accepted is 0 (auto), 1 (each variant alone) or more")
    return AUTO_BATCH if batch == 0 else batch


def run_chunk(campaign: Campaign, indices: Iterable[int], batch: int = 1) -> list[dict[str, Any]]:
    """Rows of the variants `indices` (the task a local or a Dask worker runs), `batch` at a time
    in one batch (`Worker.run_batch`; 1: each alone; 0: `AUTO_BATCH` when this process has its
    compiled code at hand (loaded or in the kernel cache), else each alone: a first compile costs
    minutes, more than a batch saves in most campaigns). The same rows in every case."""
    w = worker_for(campaign)
    todo = list(indices)
    size = batch_size(batch)
    if size <= 1:
        return [w.run(k) for k in todo]
    rows: list[dict[str, Any]] = []
    for i in range(0, len(todo), size):
        group = todo[i:i + size]
        rows += w.run_batch(group, compiled_only=batch == 0) if len(group) > 1 else [w.run(group[0])]
    return rows
