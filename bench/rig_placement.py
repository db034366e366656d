"""Benchmark: the same machine code of the rig's steps at different places in memory, in one process.

    .venv-kilted/bin/python bench/rig_placement.py [--rounds 12] [--json]

Each compiled entry point (`sim_advance`, `sim_sample`, `sim_advance_sample`, `sim_run` of
`pcv_sim.simulation.compile`) carries its own copy of what it calls (the integrator loop,
`derivs`, `project`), and a process runs the copies of the entry it loaded first. Here the rig's
kernel module is loaded once per entry as its own module (its source plus a comment line: the same
instructions, its own machine code in the cache; the first run compiles them, minutes), that entry
first, and the floor (10 steps of 0.1 ms in one `sim_advance` call, thread CPU time, best of 5 of
300 calls) is timed for each copy in turn, in rounds of alternating order. Printed per copy: where
its `derivs` starts within a 4 KiB page and the floor (best and median of the rounds); the
copies differ only in where their code lies. The arena moved within a page (every 64-byte slot)
is timed as well, the code fixed: the data's placement for comparison.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from typing import Any

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=12)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()

    import numba

    import pcv_sim.simulation.compile as compile_
    from pcv_sim.rig import Rig, load_rig
    from pcv_sim.simulation.simulator import Simulator

    rig = Rig(load_rig())
    plant, dt, integ = rig.sim.plant, rig.sim.dt, rig.sim.integrator
    S0 = rig.sim.arena.copy()
    Fa, FL = rig.sim.tables, np.array(rig.sim.table_layout, dtype=np.int64)
    ints, vec, mat = np.zeros(1, dtype=np.int64), np.zeros(1), np.zeros((1, 1))
    examples: dict[str, tuple[Any, ...]] = {
        "sim_advance": (S0, Fa, FL, 0, 0, dt),
        "sim_sample": (S0, Fa, FL, 0, 0, dt, ints, vec, 0, vec, vec),
        "sim_advance_sample": (S0, Fa, FL, 0, 0, dt, ints, vec, 0, ints, mat, 0, vec, vec),
        "sim_run": (S0, Fa, FL, 0, dt, ints, mat, ints, mat)}
    generate = compile_.generate_source
    sims: dict[str, Simulator] = {}
    try:
        for i, first in enumerate(examples):
            compile_.generate_source = lambda p, i=i: generate(p) + f"\n# placement copy {i}\n"  # type: ignore[misc]
            module = compile_.compiled_module(plant)
            entry = getattr(module, f"{first}_{integ}")
            entry.compile(tuple(numba.typeof(a) for a in examples[first]))      # loaded before any other
            sim = Simulator(plant, dt, integ)
            sim.arena[:] = S0
            sims[first] = sim
    finally:
        compile_.generate_source = generate

    def derivs_at(sim: Simulator) -> int:
        """Where `derivs` (the copy this simulator's `sim_advance` calls) starts within its page."""
        lib = next(iter(sim._advance.overloads.values())).library
        for f in lib._shared_module.functions:
            if "6derivs" in f.name and not f.is_declaration and not f.name.startswith(("cfunc", "_ZN7cpython")):
                return int(lib._codegen._engine._ee.get_function_address(f.name)) % 4096
        return -1

    def floor(sim: Simulator, S: np.ndarray, calls: int = 300, reps: int = 5) -> float:
        advance, F, L = sim._advance, sim.tables, sim._FL
        S[:] = S0
        best = float("inf")
        for _ in range(reps):
            k = 0
            t0 = time.thread_time_ns()
            for _ in range(calls):
                advance(S, F, L, 10, k, dt)
                k += 10
            best = min(best, (time.thread_time_ns() - t0) / calls / 1e3)
        return best

    for sim in sims.values():
        floor(sim, sim.arena, 50, 1)
    code: dict[str, list[float]] = {k: [] for k in sims}
    for r in range(args.rounds):
        for k in (list(sims) if r % 2 == 0 else list(reversed(sims))):
            code[k].append(floor(sims[k], sims[k].arena))
    # The data's placement: the arena at each 64-byte slot of a page, the code of the first copy.
    first = next(iter(sims.values()))
    buf = np.empty(S0.size + 1024)
    base = (-buf.ctypes.data % 4096) // 8
    data = {slot: min(floor(first, buf[base + slot // 8: base + slot // 8 + S0.size], reps=3) for _ in range(2))
            for slot in range(0, 4096, 64)}
    out = {"load_before": os.getloadavg()[0],
           "code": {k: {"derivs_in_page": derivs_at(sims[k]), "best_us": min(v), "median_us": statistics.median(v)}
                    for k, v in code.items()},
           "data": {"best_us_min": min(data.values()), "best_us_max": max(data.values()),
                    "best_us_median": statistics.median(data.values())}}
    if args.json:
        json.dump(out, sys.stdout, indent=2)
        print()
        return
    code_rows = [f"| {k} | {v['derivs_in_page']:#05x} | {v['best_us']:.2f} | {v['median_us']:.2f} |"
                 for k, v in out["code"].items()]      # type: ignore[attr-defined]
    d = out["data"]
    print("\n".join([
        f"load average {out['load_before']:.1f}; floor (10 steps), us, best / median of {args.rounds} rounds",
        "| copy loaded first | derivs in its page | best | median |", "|---|---|---|---|", *code_rows,
        f"the arena at each 64-byte slot of a page (code fixed): {d['best_us_min']:.2f}-"     # type: ignore[index]
        f"{d['best_us_max']:.2f} us (median {d['best_us_median']:.2f})"]))                    # type: ignore[index]


if __name__ == "__main__":
    main()
