"""A whole campaign run: validate, run the missing variants where asked, store, summarise, report.

`run_campaign(path_or_campaign, out, workers=0, scheduler=None, resume=False, report=True,
on_row=None) -> CampaignResult` is what `pcv-sim campaign run` and `pcv_sim.testing` call.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pcv_sim.campaign.executors import run_dask, run_local
from pcv_sim.campaign.results import Store, assertion_names, summary
from pcv_sim.campaign.runner import ERROR
from pcv_sim.campaign.spec import Campaign, load_campaign
from pcv_sim.campaign.variants import Variants

__all__ = ["CampaignResult", "run_campaign"]


@dataclass
class CampaignResult:
    summary: dict[str, Any]
    rows: list[dict[str, Any]] = field(repr=False)
    out: Path
    interrupted: bool = False

    @property
    def passed(self) -> bool:
        """The campaign's gate holds."""
        return bool(self.summary["gate"]["holds"])

    @property
    def pass_rate(self) -> float:
        return float(self.summary["pass_rate"])

    def worst_margin(self, assertion: str) -> float:
        """The smallest margin of `assertion` over the variants that ran to the end."""
        m = [float(r.get(f"{assertion}.margin", math.nan)) for r in self.rows if r["status"] != ERROR]
        if assertion not in self.summary["assertions"]:
            raise KeyError(f"no assertion {assertion!r}; assertions: {', '.join(self.summary['assertions'])}")
        return min((x for x in m if not math.isnan(x)), default=math.nan)

    def text(self) -> str:
        from pcv_sim.campaign.results import summary_text

        return summary_text(self.summary)


def run_campaign(campaign: str | Path | Campaign, out: str | Path, *, workers: int = 0, scheduler: str | None = None,
                 resume: bool = False, report: bool = True,
                 on_row: Callable[[dict[str, Any]], None] | None = None,
                 on_start: Callable[[int], None] | None = None, batch: int = 0) -> CampaignResult:
    """Run `campaign` (a file or a loaded Campaign) into the directory `out`: on `workers`
    local processes (0: every core; 1: this process) or on the Dask cluster at `scheduler`.
    `on_start(n)` is told how many variants will run (with `resume`, the missing ones), `on_row`
    each finished row. `batch`: variants run `batch` at a time in one batch (`pcv_sim.rig.batch`;
    the same rows; 1: each alone; 0: two at a time where the batch's compiled code is at hand,
    `pcv_sim.campaign.runner.run_chunk`). A KeyboardInterrupt keeps every finished variant (the
    result says `interrupted`)."""
    c = campaign if isinstance(campaign, Campaign) else load_campaign(campaign)
    variants = Variants(c, validate=True)      # every value checked before any variant runs
    out = Path(out)
    store = Store(out, c, variants.columns, resume=resume)
    todo = store.missing()
    if on_start is not None:
        on_start(len(todo))

    def add(row: dict[str, Any]) -> None:
        store.add(row)
        if on_row is not None:
            on_row(row)

    interrupted = False
    wall0 = time.perf_counter()
    ready: list[float] = []

    def on_ready() -> None:
        ready.append(time.perf_counter())

    try:
        if scheduler is not None:
            run_dask(c, todo, scheduler, add, on_ready, batch=batch)
        else:
            run_local(c, todo, workers or os.cpu_count() or 1, add, on_ready, batch=batch)
    except KeyboardInterrupt:
        interrupted = True
    finally:
        store.close()
    rows = store.ordered()
    names = assertion_names(rows)
    s = summary(c, rows, variants.columns, names, worst=c.worst)
    s["ran"] = len(todo) if not interrupted else sum(1 for r in rows if r["index"] in set(todo))
    end = time.perf_counter()
    s["wall_time_s"] = end - wall0
    # the workers' set-up (warming: imports, kernels) apart from running the variants
    s["setup_time_s"] = (ready[0] if ready else end) - wall0
    s["run_time_s"] = end - (ready[0] if ready else end)
    s["results"] = str(out / "results.csv")
    if report and not interrupted:
        from pcv_sim.campaign.report import write_report

        s["report"] = str(write_report(c, s, rows, variants.columns, names, out))
    return CampaignResult(s, rows, out, interrupted)
