"""A batch of rigs: several variants of one rig stepped in one compiled call per control period.

The rigs of a batch have one structure (the same valves, kinds, options, integrator, step and
control period; other parameters, faults, onsets, profiles, seeds, controllers). Their plants are
composed side by side into one composite (`batch_plant`): each array of its arena (state, inputs,
parameters, workspace, outputs, ...) holds the copies' own arrays one after the other, so one
compiled call steps every copy and samples every copy's signals, and a second copy in the call
costs a fraction of a call of its own (BENCHMARKS.md, "A batch axis").

Each rig stays the whole device it is alone: its inputs and queue, watchdogs, faults, sensors
with its seed, feed, its controller. `run_lockstep_batch` runs each rig's own lockstep
(`pcv_sim.rig.lockstep.lockstep_periods`) one control period at a time: a period in which every
copy would take the lockstep's fast path (nothing but its controller's array-form duties falls
due) is taken by the batch's compiled call for all, its sample written into each copy's row;
any other period (a fault's onset, a watchdog deadline, a fed input, a sensor fault, the last
sample, a copy without an array form) every copy takes alone, on its own arrays, as it would in
a run of its own. So a batch wins where such periods are rare: a setpoint profile costs nothing
(the lockstep evaluates it per copy), a profile of a model input that changes every period (an
external force, a duty) makes every period one taken alone.

While the batch holds a copy's state, the copy's `Simulator` arrays are views of the batch's
arena (`bind`), so whatever the rig writes (its duties) goes where the batch steps; they are
copied back before the copy steps alone (`unbind`). The same operations on the
same numbers in either case: every copy's run is bit for bit its run alone (the tests compare
both). A period whose batched call fails or runs away in any copy is taken again by every copy
alone from the state before it (the batch keeps that state), so a copy that runs away fails
alone, as it would alone, and the others go on.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
import threading
import weakref
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from pcv_sim.device.device import MODEL_FAILURES
from pcv_sim.errors import PcvSimError
from pcv_sim.jit import cache_root, enabled, source_digest
from pcv_sim.rig.lockstep import Batched, Controller, RigRun, lockstep_periods
from pcv_sim.rig.rig import Rig
from pcv_sim.simulation.compile import ARENA, arena_layout, generate_source
from pcv_sim.simulation.simulator import Simulator
from pcv_sim.simulation.system import Composite, compose

__all__ = ["BatchError", "RigBatch", "batch_plant", "batchable", "compiled_before", "run_lockstep_batch"]


class BatchError(PcvSimError, ValueError):
    """Rigs that cannot share a batch (another structure), said with what differs."""


#: `_structure` per rig (by its plant, which is the rig's for its life): generating the plant's
#: source costs about a millisecond, a batch of a 2 s scenario saves a few per variant.
_STRUCTURES: weakref.WeakKeyDictionary[Composite, tuple[Any, ...]] = weakref.WeakKeyDictionary()


def _structure(rig: Rig) -> tuple[Any, ...]:
    """What must be equal for rigs to share a batch's compiled code and its lockstep (the plant's
    source first)."""
    found = _STRUCTURES.get(rig.plant)
    if found is None:
        sim = rig.sim
        found = _STRUCTURES[rig.plant] = (generate_source(rig.plant), sim.integrator, sim.dt,
                                          rig.params.steps_per_period, rig.signals, tuple(rig.signal_outputs.tolist()),
                                          sim.table_layout)
    return found


def batchable(rigs: Sequence[Rig]) -> str | None:
    """None when `rigs` can share a batch; else what differs."""
    if len(rigs) < 1:
        return "no rigs"
    first = _structure(rigs[0])
    names = ("plant", "integrator", "time step", "control period", "signals", "signals", "tables")
    for k, rig in enumerate(rigs[1:], 1):
        other = _structure(rig)
        for name, a, b in zip(names, first, other, strict=True):
            if a != b:
                return f"rig {k} has another {name} than rig 0"
        if rig.steps != rigs[0].steps:
            return f"rig {k} is at step {rig.steps}, rig 0 at {rigs[0].steps}"
    return None


def batch_plant(plant: Composite, copies: int) -> Composite:
    """`copies` copies of `plant` side by side (systems `<name>_<copy>`), wired as `plant` is."""
    systems, wires = [], []
    for c in range(copies):
        names = [f"{s.name}_{c}" for s in plant.systems]
        systems += [dataclasses.replace(s, name=name) for s, name in zip(plant.systems, names, strict=True)]
        wires += [(f"{names[ka]}.{plant.systems[ka].outputs[oa]}", f"{names[kb]}.{plant.systems[kb].inputs[ib]}")
                  for (ka, oa), (kb, ib) in plant.connections]
    return compose(systems, wires)


#: Whether a batch's compiled code is at hand, by (the copy's plant source, copies, integrator).
_READY: dict[tuple[str, int, str], bool] = {}


def compiled_before(rig: Rig, copies: int) -> bool:
    """Whether the compiled code of a batch of `copies` rigs of `rig`'s structure is loaded in
    this process or in the kernel cache on disk (numba's index of its sampling entry point): a
    batch then costs no compile (minutes: BENCHMARKS.md), which is what decides whether it wins."""
    key = (_structure(rig)[0], copies, rig.sim.integrator)
    if any(k[:3] == key for k in _simulators()):
        _READY[key] = True
    if key in _READY:
        return _READY[key]
    digest = hashlib.sha1(generate_source(batch_plant(rig.plant, copies)).encode()).hexdigest()[:16]
    pattern = f"pcv_sim_kernel_{digest}.sim_sample_{rig.sim.integrator}-*.nbi"
    found = enabled() and any((cache_root() / "numba" / source_digest()).rglob(pattern))
    _READY[key] = found
    return found


#: Batch simulators by (the copy's plant source, copies, integrator, step), per thread (a Dask
#: worker may run batches on several): one compile each, a batch's arrays never shared.
_KEPT = threading.local()


def _simulators() -> dict[tuple[str, int, str, float],
                          tuple[Simulator, list[np.ndarray], list[dict[str, np.ndarray]], np.ndarray,
                                tuple[np.ndarray, np.ndarray]]]:
    kept = getattr(_KEPT, "simulators", None)
    if kept is None:
        kept = _KEPT.simulators = {}
    return kept


def _simulator(rig: Rig, copies: int) -> tuple[Simulator, list[np.ndarray], list[dict[str, np.ndarray]], np.ndarray,
                                               tuple[np.ndarray, np.ndarray]]:
    """The batch's simulator for `copies` rigs like `rig`; per copy the place in its arena of
    each element of the copy's own arena, and the copy's parts as views of it (what
    `Simulator.bind` takes); the outputs the batch samples (each copy's signals, in copy order)
    and their bounds (each copy's physical limits)."""
    sim = Simulator(batch_plant(rig.plant, copies), rig.sim.dt, rig.sim.integrator)
    one = arena_layout(rig.plant)
    many = arena_layout(sim.plant)
    indices: list[np.ndarray] = []
    views: list[dict[str, np.ndarray]] = []
    for c in range(copies):
        index, own = [], {}
        for name in ARENA:
            a, b = one[name]
            start = many[name][0] + c * (b - a)
            index.append(np.arange(start, start + b - a))
            own[name] = sim.arena[start:start + b - a]
        indices.append(np.concatenate(index))
        views.append(own)
    ny = len(rig.plant.outputs)
    select = np.concatenate([rig.signal_outputs + c * ny for c in range(copies)]).astype(np.int64)
    lo, hi = rig.signal_bounds
    return sim, indices, views, select, (np.tile(lo, copies), np.tile(hi, copies))


class RigBatch:
    """The batch's simulator over `rigs` (one structure, `batchable`) and the copies' places in it."""

    def __init__(self, rigs: Sequence[Rig]) -> None:
        problem = batchable(rigs)
        if problem is not None:
            raise BatchError(f"these rigs cannot share a batch: {problem}")
        self.rigs = list(rigs)
        first = rigs[0].sim
        copies = len(rigs)
        key = (_structure(rigs[0])[0], copies, first.integrator, first.dt)
        kept = _simulators()
        made = kept.get(key)
        if made is None:
            if len(kept) >= 4:
                kept.pop(next(iter(kept)))
            made = kept[key] = _simulator(rigs[0], copies)
        self.sim, self._index, self._views, self.select, self.bounds = made
        # Each copy's tables (its valves' curve fits), one after the other as the systems are.
        self.sim.tables[:] = np.concatenate([r.sim.tables for r in rigs])
        self.bound = [False] * copies

    def bind(self, c: int) -> None:
        """Copy c's state into the batch; its simulator's arrays become views of the batch's."""
        if self.bound[c]:
            return
        self.rigs[c].sim.bind(self._views[c])
        self.bound[c] = True

    def unbind(self, c: int) -> None:
        """Copy c's state back into its own simulator's arrays, which are its own again."""
        if not self.bound[c]:
            return
        self.rigs[c].sim.unbind()
        self.bound[c] = False

    def mirror(self, c: int, source: int) -> None:
        """Copy c's place in the batch takes copy `source`'s state (a copy whose run ended: its
        place is still stepped, and must neither run away nor cost more than a live one)."""
        arena = self.sim.arena
        arena[self._index[c]] = arena[self._index[source]]


def run_lockstep_batch(rigs: Sequence[Rig], controllers: Sequence[Controller | None], duration: float, *,
                       setpoints: Sequence[Callable[[float], float] | None] | None = None,
                       counts: dict[str, int] | None = None) -> list[RigRun | BaseException]:
    """Each rig's `run_lockstep(rig, controllers[c], duration, setpoint=setpoints[c])`, the copies
    stepped together (see the module docstring): per rig its run, or the exception its run
    raised (a model that ran away, a controller that raised): that copy stops, the others go on.
    BatchError when the rigs do not share one structure. `counts`, when given, gets the control
    periods taken `together` (in one call), `alone` (each copy alone) and of those `retaken`
    (alone again after the batch's call ran away)."""
    batch = RigBatch(rigs)
    copies = len(rigs)
    sps = list(setpoints) if setpoints is not None else [None] * copies
    if len(controllers) != copies or len(sps) != copies:
        raise BatchError(f"{copies} rigs need as many controllers and setpoints: {len(controllers)}, {len(sps)}")
    per = rigs[0].params.steps_per_period
    n = round(duration / rigs[0].params.timing.control_period)
    k0 = rigs[0].steps
    samples = np.empty((n + 1, copies, len(rigs[0].signals)))
    rows = samples.reshape(n + 1, -1)       # period k's samples of every copy: the batch's call writes them
    runs: list[RigRun | BaseException | None] = [None] * copies
    periods = [lockstep_periods(rig, controllers[c], duration, setpoint=sps[c], rows=samples[:, c, :], batched=True)
               for c, rig in enumerate(rigs)]
    asks = [0] * copies                 # per running copy: the period before which it may go on in the batch
    live: list[int] = []                # the copies still running, in order
    sim = batch.sim
    fused, (S, Fa, FL) = sim.sample_entry()
    before = np.empty_like(S)
    select = batch.select
    lo, hi = batch.bounds
    dt = sim.dt
    stale: list[int] = []               # places of copies whose run ended, not yet mirroring a live one
    bound = False                       # every live copy's state in the batch
    together = alone = retaken = 0

    def ended(c: int, run: RigRun | BaseException) -> None:
        runs[c] = run
        live.remove(c)
        batch.unbind(c)                 # its rig ends as it would alone
        stale.append(c)

    try:
        for c in range(copies):
            live.append(c)
            try:
                asks[c] = next(periods[c])
            except StopIteration as done:
                ended(c, done.value)
            except Exception as err:    # its model ran away, its controller raised: it alone stops
                ended(c, err)
        k = 0
        while live:
            got: Batched = None
            if len(live) > 1 and min([asks[c] for c in live]) > k:
                if not bound:
                    for c in live:
                        batch.bind(c)
                    bound = True
                for c in stale:
                    batch.mirror(c, live[0])
                stale.clear()
                now = rigs[live[0]].sim.steps
                at = k0 + k * per
                before[:] = S
                try:
                    norm = fused(S, Fa, FL, at - now, now, dt, select, rows[k], 1, lo, hi)
                except MODEL_FAILURES:
                    norm = math.nan
                if math.isfinite(norm):
                    got = norm
                    together += 1
                else:
                    retaken += 1
                    # Every copy takes this period again alone, from the state before it: one that
                    # runs away fails there as it would alone.
                    S[:] = before
                    stale = [c for c in range(copies) if runs[c] is not None]
            if got is None:
                alone += 1
                if bound:
                    for c in live:
                        batch.unbind(c)
                    bound = False
            for c in list(live):
                try:
                    asks[c] = periods[c].send(got)
                except StopIteration as done:
                    ended(c, done.value)
                except Exception as err:  # its model ran away, its controller raised: it alone stops
                    ended(c, err)
            k += 1
    finally:
        for c in range(copies):
            batch.unbind(c)
        for gen in periods:
            gen.close()
        if counts is not None:
            counts.update(together=together, alone=alone, retaken=retaken)
    return [r if r is not None else PcvSimError("the batch stopped before this copy's run ended") for r in runs]
