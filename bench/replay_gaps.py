"""Measurement: how long after a skipped interval the emulator and a continuous model agree again.

    .venv-kilted/bin/python bench/replay_gaps.py [--skip-ms 55]

The emulator's device (0.1 ms Heun) runs duty steps 0.5 -> 0.7 (at 100 ms) -> 0.4 (at 600 ms);
once continuously, once with the state standing still for ``--skip-ms`` (time jumps, as when the
emulator skips steps) starting at several points of the transients. Prints, per skip, the
largest pressure difference in the 1 ms starting 0, 20, 50, 100, 200, 300 ms after the skip ends:
the basis of ``pcv_sim.replay.compare.RESYNC_S``. Not a timing: the numbers are deterministic.
"""

from __future__ import annotations

import argparse

import numpy as np

from pcv_sim.device.valve import VALVE, ValveDevice
from pcv_sim.params import load_params

PLAN = {0: 0.5, 1000: 0.7, 6000: 0.4}          # step (0.1 ms) -> duty
STARTS = (1050, 1100, 1300, 1800, 6050, 6200, 6500)
AFTER_MS = (0, 20, 50, 100, 200, 300, 400)
N = 12000


def run(skip_at: int, skip: int) -> np.ndarray:
    dev = ValveDevice(load_params(), safe_duty=0.5, watchdog_timeout=0.0)
    out = np.full(N, np.nan)
    k = 0
    while k < N:
        if k == skip_at:
            for s in (s for s in PLAN if k <= s < k + skip):
                dev.set_duty(VALVE, PLAN[s])
            dev.skip(skip)
            k += skip
            continue
        if k in PLAN:
            dev.set_duty(VALVE, PLAN[k])
        out[k] = dev.sim.x[3]
        dev.advance_to(k + 1)
        k += 1
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--skip-ms", type=float, default=55.0)
    args = ap.parse_args()
    skip = round(args.skip_ms * 10)
    ref = run(-1, 0)
    print("| skip at [ms] | " + " | ".join(f"+{a} ms [bar]" for a in AFTER_MS) + " |")
    print("|---|" + "---|" * len(AFTER_MS))
    for at in STARTS:
        d = np.abs(run(at, skip) - ref) / 1e5
        end = at + skip
        cells = [f"{np.nanmax(d[end + 10 * a:end + 10 * a + 10]):.4f}" for a in AFTER_MS]
        print(f"| {at / 10:g} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
