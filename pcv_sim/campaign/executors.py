"""Where a campaign's variants run: this process, local worker processes, or a Dask cluster.

Every executor hands chunks of variant indices to `pcv_sim.campaign.runner.run_chunk` and passes
each finished row to `on_row` as it arrives (the caller stores it at once, so an interrupted
campaign keeps every finished variant). The rows do not depend on the executor, the number of
workers or the chunking: a variant's values are a function of (campaign, index) alone.

- `run_inline`: in this process (one worker; no start-up cost).
- `run_local`: `workers` processes forked from this one after it prepared the campaign and ran
  its first variant once (imports, compiled kernels, the controller's module: the children
  inherit them); Ctrl-C terminates the workers and keeps what finished.
- `run_dask`: a Dask distributed cluster (`dask scheduler` + `dask worker`s, on any machines
  with this package installed and the scenario's files at the same paths): every worker imports
  the package and is warmed by one task pinned to it (the first variant run once: its kernels
  loaded), then the chunks are Dask tasks, each carrying the campaign. Dask does the scheduling.

`on_ready()`, when given, is called once the workers are warm, before the first chunk: the
caller counts the set-up apart from the run.
"""

from __future__ import annotations

import importlib
import multiprocessing
import signal
import time
from collections.abc import Callable, Sequence
from typing import Any

from pcv_sim.campaign.runner import batch_size, run_chunk, worker_for
from pcv_sim.campaign.spec import Campaign
from pcv_sim.errors import UsageError

__all__ = ["chunks", "run_dask", "run_inline", "run_local", "warm"]

Row = dict[str, Any]
OnRow = Callable[[Row], None]
OnReady = Callable[[], None] | None


def chunks(indices: Sequence[int], workers: int, *, most: int = 8, least: int = 1) -> list[list[int]]:
    """`indices` in chunks of falling size, each half of what is left per worker (at most `most`,
    at least `least`, a batch; "factoring"): large while much is left, so a task's overhead stays
    small, and single variants (batches) at the end, so that no worker waits for another's last
    chunk longer than a variant (a batch) and an interrupt loses little."""
    share = 2 * max(1, workers)
    most = max(most, least)
    out: list[list[int]] = []
    i = 0
    while i < len(indices):
        size = max(least, min(most, (len(indices) - i) // share))
        out.append(list(indices[i:i + size]))
        i += size
    return out


def run_inline(campaign: Campaign, indices: Sequence[int], on_row: OnRow, on_ready: OnReady = None, *,
               batch: int = 1) -> None:
    w = worker_for(campaign)
    if on_ready is not None:
        on_ready()
    if batch == 1:
        for k in indices:
            on_row(w.run(k))
        return
    size = batch_size(batch)
    for group in chunks(indices, 1, most=size, least=size):
        for row in run_chunk(campaign, group, batch):
            on_row(row)


_CAMPAIGN: Campaign | None = None
_BATCH = 1


def _init_worker() -> None:
    # Ctrl-C reaches the whole process group: the parent alone decides, the workers go on
    # until it terminates them (SIGTERM: the default, whatever handler the parent had at the fork).
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)


def _chunk(indices: list[int]) -> list[Row]:
    assert _CAMPAIGN is not None
    return run_chunk(_CAMPAIGN, indices, _BATCH)


def warm(campaign: Campaign, index: int, batch: int = 1) -> float:
    """Prepare `campaign` in this process (this thread's Worker) and run variant `index` once (in
    a batch of `batch` copies of it), its row dropped: the imports, the compiled kernels (the
    batch's too) and the controller's module are loaded before the first chunk. The seconds it
    took."""
    t0 = time.perf_counter()
    run_chunk(campaign, [index] * batch_size(batch), batch)
    return time.perf_counter() - t0


def run_local(campaign: Campaign, indices: Sequence[int], workers: int, on_row: OnRow,
              on_ready: OnReady = None, *, batch: int = 1) -> None:
    """`workers` forked processes (1: this process); `batch` variants at a time in one batch."""
    if workers <= 1 or len(indices) <= 1:
        run_inline(campaign, indices, on_row, on_ready, batch=batch)
        return
    global _CAMPAIGN, _BATCH
    _CAMPAIGN, _BATCH = campaign, batch
    # Warmed here, before the fork: the children inherit the imports, the variant table and the
    # compiled kernels instead of loading them each.
    warm(campaign, indices[0], batch)
    ctx = multiprocessing.get_context("fork")
    pool = ctx.Pool(workers, initializer=_init_worker)
    if on_ready is not None:
        on_ready()
    try:
        for rows in pool.imap_unordered(_chunk, chunks(indices, workers, least=batch_size(batch))):
            for row in rows:
                on_row(row)
        pool.close()
    except BaseException:
        pool.terminate()
        raise
    finally:
        pool.join()
        _CAMPAIGN, _BATCH = None, 1


def run_dask(campaign: Campaign, indices: Sequence[int], address: str, on_row: OnRow, on_ready: OnReady = None, *,
             timeout: float = 10.0, batch: int = 1) -> None:
    """On the Dask cluster whose scheduler is at `address` (tcp://HOST:PORT); `batch` variants at a
    time in one batch."""
    try:
        import distributed
    except ImportError as err:   # pragma: no cover - pinned in requirements/common.txt
        raise UsageError(f"--scheduler: dask.distributed is not installed ({err})") from None
    # distributed's Client and as_completed carry no annotations: typed Any here, strict elsewhere.
    dask_api: Any = distributed
    Client, as_completed = dask_api.Client, dask_api.as_completed
    try:
        client = Client(address, timeout=timeout)
    except (OSError, TimeoutError) as err:
        raise UsageError(f"--scheduler {address}: no Dask scheduler answered ({err}); accepted is the address "
                         "of a running `dask scheduler`, e.g. tcp://127.0.0.1:8786") from None
    with client:
        threads = client.nthreads()
        n = max(1, sum(threads.values()))
        if indices:
            # Every worker imports the package at once, in a task of a standard-library function
            # (which the scheduler unpickles without importing anything); unpickling the first task
            # that carries the campaign would import it too, later and one process at a time.
            dask_api.wait([client.submit(importlib.import_module, __name__, workers=[addr], allow_other_workers=False,
                                         pure=False) for addr in threads])
            # One warm-up per worker, pinned to it: each loads what the first variant needs
            # (a worker that joins later warms itself with its first chunk).
            client.gather([client.submit(warm, campaign, indices[0], batch, workers=[addr], allow_other_workers=False,
                                         pure=False) for addr in threads])
        if on_ready is not None:
            on_ready()
        # The campaign goes inline in every task (~15 kB, ~0.3 ms to unpickle): a task that
        # depends on a scattered future took ~30 ms more (14 tasks on a localhost cluster:
        # 0.4-1.1 s against 0.05-0.17 s inline). One map: one graph for the scheduler to read.
        parts = chunks(indices, n, least=batch_size(batch))
        futures = client.map(run_chunk, [campaign] * len(parts), parts, [batch] * len(parts), pure=False)
        try:
            # with_results: finished chunks' rows come in batches (14 chunks gathered in ~8 ms, ~33 ms
            # by one result() call each: a round trip through the scheduler apiece)
            for _future, rows in as_completed(futures, with_results=True):
                for row in rows:
                    on_row(row)
        except BaseException:
            client.cancel(futures)
            raise
