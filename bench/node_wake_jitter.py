"""Benchmark: how late this machine wakes a sleeping Python loop (no ROS): the floor under the
emulator's late steps.

    .venv-kilted/bin/python bench/node_wake_jitter.py [--duration 20] [--fifo 10]

A loop sleeps to a 1 ms grid of the monotonic clock (1 ns timer slack, GC frozen, as the
emulator does) and records how late each wake-up comes. --fifo N runs it under SCHED_FIFO.
"""
import argparse
import ctypes
import gc
import os
import time


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--fifo", type=int, default=0)
    opts = ap.parse_args()
    ctypes.CDLL(None).prctl(29, 1, 0, 0, 0)
    if opts.fifo:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(opts.fifo))
    gc.collect()
    gc.freeze()
    late = []
    t0 = time.monotonic()
    wake = t0
    while time.monotonic() - t0 < opts.duration:
        wake += 0.001
        delay = wake - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        late.append(time.monotonic() - wake)
    late.sort()
    n = len(late)
    print(f"| {'SCHED_FIFO ' + str(opts.fifo) if opts.fifo else 'normal'} | {n} | "
          f"{late[n // 2] * 1e6:.0f} / {late[int(n * 0.99)] * 1e6:.0f} / {late[int(n * 0.999)] * 1e6:.0f} / "
          f"{late[-1] * 1e6:.0f} | {sum(1 for x in late if x > 0.001)} |")


if __name__ == "__main__":
    main()
