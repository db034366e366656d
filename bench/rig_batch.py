"""Benchmark: would a batch axis win? Two rig variants in one compiled call against one each.

    .venv-kilted/bin/python bench/rig_batch.py [--repeats 9] [--periods 500] [--json]

The rig of config/rig.yaml (two simplified valves + the steering cylinder at 0.1 ms) composed
once (one variant) and twice side by side in one plant (two variants: two independent copies,
the second's valves with another spring preload), both compiled by the simulation core, each
copy starting from the rig's rest at its initial duties. Per 1 ms
control period (10 steps, the period's sampling and the answer's step: `Simulator.advance_sample`,
as the lockstep calls it) and per variant: the one-variant plant called twice against the
two-variant plant called once (best of the repeats; interleaved). What a batch could save is the
per-call cost; the steps themselves are the same work per variant either way. The compile of the
two-variant plant is not counted (a first run compiles it: minutes under load).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=9)
    ap.add_argument("--periods", type=int, default=500)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()

    from pcv_sim.plant.cylinder import cylinder_system
    from pcv_sim.rig import Rig, load_rig
    from pcv_sim.simulation.simulator import Simulator
    from pcv_sim.simulation.system import compose
    from pcv_sim.simulation.valve import valve_integrator, valve_system

    params = load_rig()
    rest = Rig(params).sim
    kind = params.valves[0].params.simulation.model

    def plant(copies: int):
        systems, wires = [], []
        for c in range(copies):
            for v in params.valves:
                vp = v.params
                if c:                   # another variant: a different spring preload
                    vp = dataclasses.replace(vp, spool=dataclasses.replace(vp.spool,
                                                                            spring_preload=vp.spool.spring_preload * 1.02))
                systems.append(valve_system(vp, kind, f"{v.name}{c}"))
                wires += [(f"{v.name}{c}.pressure", f"cylinder{c}.pressure_{v.chamber}"),
                          (f"cylinder{c}.flow_{v.chamber}", f"{v.name}{c}.load_flow"),
                          (f"cylinder{c}.volume_{v.chamber}", f"{v.name}{c}.load_volume")]
            systems.append(cylinder_system(params.cylinder, f"cylinder{c}"))
        sim = Simulator(compose(systems, wires), params.timing.time_step, valve_integrator(params.valves[0].params, kind))
        # Each copy from the rig's rest (the layout of one copy is the rig's own plant's).
        sim.x[:], sim.W[:], sim.u[:] = (np.tile(a, copies) for a in (rest.x, rest.W, rest.u))
        select = np.array([sim.plant.index("output", f"cylinder{c}.position") for c in range(copies)])
        return sim, select

    one, sel1 = plant(1)
    two, sel2 = plant(2)
    out1, out2 = np.empty(len(sel1)), np.empty(len(sel2))
    per = params.steps_per_period
    for sim, sel, out in ((one, sel1, out1), (two, sel2, out2)):     # compile (or load) before timing
        sim.advance_sample(per - 1, sel, out, 1)

    def period_us(sim, sel, out, calls: int) -> float:
        t0 = time.perf_counter()
        for _ in range(args.periods):
            for _ in range(calls):
                sim.advance_sample(per - 1, sel, out, 1)
        return (time.perf_counter() - t0) / args.periods / 2 * 1e6       # per variant

    load0 = os.getloadavg()[0]
    separate, batched = [], []
    for _ in range(args.repeats):
        separate.append(period_us(one, sel1, out1, 2))
        batched.append(period_us(two, sel2, out2, 1))
    res = {"separate_us_per_variant": min(separate), "batched_us_per_variant": min(batched),
           "load_before": load0, "load_after": os.getloadavg()[0]}
    res["batched_over_separate"] = res["batched_us_per_variant"] / res["separate_us_per_variant"]
    if args.json:
        json.dump(res, sys.stdout, indent=2)
        print()
        return
    print(f"load average {res['load_before']:.1f} -> {res['load_after']:.1f}; one 1 ms period per variant: "
          f"one variant per call {res['separate_us_per_variant']:.2f} us, two in one call "
          f"{res['batched_us_per_variant']:.2f} us ({res['batched_over_separate']:.3f}x)")


if __name__ == "__main__":
    main()
