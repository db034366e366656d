"""Benchmark: does recording make model steps late? Recording off vs on at the full 0.1 ms rate.

    .venv-kilted/bin/python bench/node_recording.py                       # writer costs, loop and node parts, 60 s per run
    .venv-kilted/bin/python bench/node_recording.py --part node --duration 600
    .venv-kilted/bin/python bench/node_recording.py --part loop --duration 20

Part `loop` (no ROS, one fresh process per configuration): the emulator's real-time loop as
`pcv_sim.node.emulator` runs it (1 ms wakes on the monotonic grid, `RealTimeSchedule`,
`ValveDevice.run`, 1 ns timer slack, frozen heap), with the device's recorder hook called at every
0.1 ms step and all six signals recorded at every step (10 kHz outputs). Configurations:

- `off`: no recorder (the device still steps in batches);
- `hook`: the hook called at every step with a recorder that does nothing (the device's cost of
  recording at every step: single steps and a signals dict);
- `inline`: the emulator's `DeviceRecorder` (`writer="inline"`): messages serialised and chunks flushed inside the call;
- `thread per-message [5ms]`: the first threaded design: the writer thread serialises message by
  message (`write_float64` / `write_fluid_pressure`, ~3.5 µs each), with Python's default switch
  interval (5 ms) or the one the node sets (`SWITCH_INTERVAL`, 1 ms);
- `thread [5ms]`: a writer thread serialising the output samples in bulk
  (`BagWriter.write_samples`), with the default or the node's switch interval;
- `process`: the recorder as the nodes run it (`writer="process"`): the loop pickles a batch
  every 20 ms into a shared-memory ring, a writer process does the rest.

The configurations run in `--rounds` interleaved rounds (each round runs every configuration for
duration / rounds), so that other load on the machine falls on all of them alike; late steps are
summed and lags are the maxima over the rounds.

Per configuration: late steps (late_threshold 1 ms, as the node), max model lag before / after a
batch, the recorder's cost per step (time inside the hook calls / steps), the longest single
hook call (a chunk flush inline), CPU of the process (all threads), bag size per minute.

Part `node` (real DDS): `bench/node_realtime.py` (the node as a subprocess, a client stepping the
duty 0.3 <-> 0.7 every ~0.7 s) twice, recording off and on (`record.rate_hz: 10000`, all signals),
for `--duration` s each; late steps, lags, CPU and the bag's size from its files.
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
LOOP_CONFIGS = ("off", "hook", "inline", "thread per-message 5ms", "thread per-message", "thread 5ms", "thread",
                "process")


# --- part loop: one configuration in this process --------------------------------------------------


def _run_loop(config: str, duration: float, out_dir: Path) -> dict:
    import ctypes

    from pcv_sim.device.recording import BagLayout, DeviceRecorder
    from pcv_sim.io.recorder import SWITCH_INTERVAL, WriterSettings
    _PerMessageRecorder = _per_message_recorder()
    from pcv_sim.device.valve import ValveDevice
    from pcv_sim.params import load_params
    from pcv_sim.simulation.clock import RealTimeSchedule

    params = load_params()
    dev = ValveDevice(params, safe_duty=0.3, watchdog_timeout=0.0, sample_every=10)
    rec = None
    spent = [0.0, 0.0, 0]                              # total s in the hook, longest call, calls
    perf = time.perf_counter

    class Timed:
        """The hook and, when the recorder has it, the device's block call (`record_block`), timed."""

        def __init__(self, inner):
            self.inner = inner
            if hasattr(inner, "record_block"):
                self.record_block = self._block

        def _time(self, f, *args):
            t = perf()
            f(*args)
            d = perf() - t
            spent[0] += d
            spent[2] += 1
            spent[1] = max(spent[1], d)

        def __call__(self, t_ns, signals):
            self._time(self.inner, t_ns, signals)

        def _block(self, t0_ns, dt_ns, rows):
            self._time(self.inner.record_block, t0_ns, dt_ns, rows)

    if config == "hook":
        dev.recorder, dev.record_every = Timed(lambda t_ns, s: None), 1
    elif config != "off":
        cls = _PerMessageRecorder if "per-message" in config else DeviceRecorder
        writer = "inline" if config == "inline" else "process" if config == "process" else "thread"
        layout = BagLayout.of(dev, every=1, frame_id="load_port", faults=False, events=False)
        rec = cls(out_dir, layout, name="bag", dt_ns=dev.dt_ns, writing=WriterSettings(writer=writer))
        dev.recorder, dev.record_every = Timed(rec), 1
        sys.setswitchinterval(0.005 if config.endswith("5ms") else
                              float(config.split("@")[1]) * 1e-3 if "@" in config else SWITCH_INTERVAL)
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL(None).prctl(29, 1, 0, 0, 0)        # PR_SET_TIMERSLACK 1 ns, as the node
    gc.collect()
    gc.freeze()
    sched = RealTimeSchedule(dev.dt, wake_period=1e-3, late_threshold=1e-3, max_catchup=0.05)
    mono = time.monotonic
    sched.start()
    dev.origin_ns = time.time_ns()
    if rec is not None:
        rec.start(dev.stamp_ns(), dev.record_values())
    duties = (0.3, 0.7)
    next_cmd, n_cmd = 0.7, 0
    cpu0 = time.process_time()
    t_end = sched.t0 + duration
    while True:
        now = mono()
        if now >= t_end:
            break
        if now - sched.t0 >= next_cmd:                 # duty steps as bench/node_realtime.py sends them
            n_cmd += 1
            dev.submit("duty_cycle", duties[n_cmd % 2])
            next_cmd += 0.7
        plan = sched.plan(now)
        if plan.skipped:
            dev.skip(plan.skipped)
        if plan.steps:
            dev.run(plan.steps)
        sched.finish()
        delay = sched.next_wake() - mono()
        if delay > 0.0:
            time.sleep(delay)
    cpu = time.process_time() - cpu0
    steps = sched.computed_steps
    res = {
        "config": config, "duration_s": duration, "steps": steps,
        "late_steps": sched.late_steps, "skipped_steps": sched.skipped_steps,
        "max_lag_ms": sched.max_lag * 1e3, "max_lag_after_ms": sched.max_lag_after * 1e3,
        "hook_us_per_step": spent[0] / max(steps, 1) * 1e6, "hook_max_ms": spent[1] * 1e3,
        "cpu_percent": 100.0 * cpu / duration, "switch_interval_s": sys.getswitchinterval(),
    }
    if rec is not None:
        t = perf()
        st = rec.close()
        child = os.times()
        res["writer_process_cpu_percent"] = 100.0 * (child.children_user + child.children_system) / duration
        res.update(close_s=perf() - t, messages=st.messages, dropped=st.dropped,
                   bag_mb_per_min=sum(f.stat().st_size for f in st.path.glob("*.mcap")) / 1e6 * 60 / duration)
    return res


def _per_message_recorder():
    from pcv_sim.device.recording import DeviceRecorder
    from pcv_sim.io import FLOAT64

    class PerMessage(DeviceRecorder):
        """The writer thread serialising message by message (the design before write_samples)."""

        def _drain(self) -> None:
            q = self._queue
            with self._lock:
                for _ in range(len(q)):
                    item = q.popleft()
                    if item[0] == 1:                           # a row
                        self._row(item[1], item[2])
                    elif item[0] == 4:                         # a block of rows at t0, t0 + dt ...
                        _, t0, dt, rows = item
                        for k, row in enumerate(rows.tolist()):
                            self._row(t0 + k * dt, row)
                    else:
                        self._write_message(item)

        def _row(self, t: int, row) -> None:
            w = self._bag
            for c in self.layout.of_kind("column"):
                if c.type == FLOAT64:
                    w.write_float64(c.topic, t, row[c.source[0]])
                else:
                    w.write_fluid_pressure(c.topic, t, row[c.source[0]], 0.0, c.frame_id)

    return PerMessage


def _merge(runs: list[dict]) -> dict:
    out = dict(runs[0])
    for key in ("duration_s", "steps", "late_steps", "skipped_steps", "messages", "dropped"):
        if key in out:
            out[key] = sum(r[key] for r in runs)
    for key in ("max_lag_ms", "max_lag_after_ms", "hook_max_ms", "close_s"):
        if key in out:
            out[key] = max(r[key] for r in runs)
    for key in ("hook_us_per_step", "cpu_percent", "bag_mb_per_min", "writer_process_cpu_percent"):
        if key in out:
            out[key] = sum(r[key] * r["duration_s"] for r in runs) / out["duration_s"]
    return out


def part_loop(duration: float, rounds: int, configs: tuple[str, ...] = LOOP_CONFIGS, load: int = 0) -> list[dict]:
    runs: dict[str, list[dict]] = {c: [] for c in configs}
    hogs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(load)]
    try:
        for _ in range(rounds):
            for config in configs:
                with tempfile.TemporaryDirectory(prefix="pcv_rec_bench_") as tmp:
                    out = subprocess.run([sys.executable, __file__, "--_loop", config, "--duration",
                                          str(duration / rounds), "--_dir", tmp], capture_output=True, text=True,
                                         check=True)
                    runs[config].append(json.loads(out.stdout.strip().splitlines()[-1]))
    finally:
        for h in hogs:
            h.kill()
            h.wait()
    results = [_merge(runs[c]) for c in configs]
    print(f"\nLoop without ROS, {duration:g} s per configuration ({rounds} rounds), all signals at every 0.1 ms "
          f"step, {load} CPU burner(s):\n")
    print(f"| configuration | late / skipped steps (of ~{duration * 1e4:.0f}) | max lag before / after a batch [ms] "
          "| recorder µs per step | longest hook call [ms] | CPU [% of a core] | bag [MB/min] |")
    print("|---|---|---|---|---|---|---|")
    for r in results:
        name = r["config"].replace(" 5ms", "") + (f" ({r['switch_interval_s'] * 1e3:g} ms switch interval)"
                                                  if r["config"].startswith("thread") else "")
        bag = f"{r['bag_mb_per_min']:.1f}" if "bag_mb_per_min" in r else "-"
        hook = f"{r['hook_us_per_step']:.2f}" if r["config"] != "off" else "-"
        longest = f"{r['hook_max_ms']:.2f}" if r["config"] != "off" else "-"
        cpu = f"{r['cpu_percent']:.1f}" + (f" + {r['writer_process_cpu_percent']:.1f} (writer process)"
                                           if r["config"] == "process" else "")
        print(f"| {name} | {r['late_steps']} / {r['skipped_steps']} | {r['max_lag_ms']:.2f} / "
              f"{r['max_lag_after_ms']:.2f} | {hook} | {longest} | {cpu} | {bag} |")
    return results


# --- part costs: per-message serialisation and chunk flushes ---------------------------------------


def part_costs() -> dict:
    """Writer costs for 10 kHz samples of all three outputs (30 000 messages per second of model
    time): per message one by one vs in bulk, and the pause of one chunk flush (zstd, 1 MiB)."""

    from pcv_sim.io.bag import BagWriter
    from pcv_sim.io.topics import BAG_TOPICS

    n = 20_000
    t = 1_700_000_000_000_000_000 + np.arange(n, dtype=np.int64) * 100_000
    rng = np.random.default_rng(0)
    p, i, x = 1e7 + rng.normal(size=n) * 1e5, 1.0 + rng.normal(size=n) * 0.1, rng.normal(size=n) * 1e-4
    res: dict = {}
    with tempfile.TemporaryDirectory(prefix="pcv_rec_cost_") as tmp:
        for mode in ("one by one", "bulk"):
            for fsync in (False, True):
                flushes: list[float] = []
                w = BagWriter(Path(tmp) / f"{mode.replace(' ', '_')}{fsync}", topics=BAG_TOPICS, flush_thread=False,
                              fsync=fsync, flush_period_s=100.0)
                inner = w._flush_locked

                def timed_flush(inner=inner, flushes=flushes):
                    t0 = time.perf_counter()
                    inner()
                    flushes.append(time.perf_counter() - t0)

                w._flush_locked = timed_flush
                t0 = time.perf_counter()
                if mode == "bulk":
                    for s in range(0, n, 200):                  # 20 ms batches, as the writer thread
                        sl = slice(s, s + 200)
                        w.write_samples(t[sl], {"/pressure": p[sl], "/current": i[sl], "/spool_position": x[sl]},
                                        frame_id="load_port")
                else:
                    for k in range(n):
                        tk = int(t[k])
                        w.write_fluid_pressure("/pressure", tk, float(p[k]), 0.0, "load_port")
                        w.write_float64("/current", tk, float(i[k]))
                        w.write_float64("/spool_position", tk, float(x[k]))
                total = time.perf_counter() - t0
                w.close()
                per_msg = (total - sum(flushes)) / (3 * n) * 1e6
                res[f"{mode}{' + fsync' if fsync else ''}"] = {
                    "us_per_message": per_msg, "flush_ms_median": float(np.median(flushes)) * 1e3,
                    "flush_ms_max": max(flushes) * 1e3, "flushes": len(flushes)}
    print("\nWriter costs (all three outputs, 20 000 samples, 1 MiB zstd chunks):\n")
    print("| serialisation | µs per message (without flushes) | chunk flush median / max [ms] |")
    print("|---|---|---|")
    for k, v in res.items():
        print(f"| {k} | {v['us_per_message']:.2f} | {v['flush_ms_median']:.1f} / {v['flush_ms_max']:.1f} "
              f"({v['flushes']} flushes) |")
    return res


# --- part node: the real node over DDS ---------------------------------------------------------------


def _node_run(record: bool, duration: float, load: int) -> dict | None:
    """One run of bench/node_realtime.py; None when it failed (e.g. no diagnostics under heavy load)."""
    env = {k: v for k, v in os.environ.items() if k != "_ROS_WHEELS_BOOTSTRAP_COMPLETE"}
    tmp = Path(tempfile.mkdtemp(prefix="pcv_rec_bench_node_"))
    try:
        cmd = [sys.executable, str(HERE / "node_realtime.py"), "--duration", str(duration),
               "--json", str(tmp / "figures.json"), "--load", str(load)]
        if record:
            cmd += ["--param", "record.enabled:=true", "--param", "record.rate_hz:=10000.0",
                    "--param", f"record.directory:={tmp / 'bags'}", "--param", "record.name:=bench"]
        if subprocess.run(cmd, check=False, env=env, stdout=subprocess.DEVNULL).returncode != 0:
            return None
        res = json.loads((tmp / "figures.json").read_text())
        res["record"] = record
        if record:
            files = list((tmp / "bags" / "bench").glob("*.mcap"))
            res["bag_bytes"] = sum(f.stat().st_size for f in files)
            from pcv_sim.io import read_bag

            bag = read_bag(tmp / "bags" / "bench")
            t_p = bag["/bench/pressure"].t_ns
            span = (int(t_p[-1]) - int(t_p[0])) / 1e9          # the node records from its start
            gaps = np.diff(t_p)
            res["bag_closed_cleanly"] = bag.closed_cleanly
            res["bag_pressure_samples"] = len(t_p)
            res["bag_span_s"] = span
            res["bag_gaps"] = int(np.count_nonzero(gaps > 100_000))
            res["bag_mb_per_min"] = res["bag_bytes"] / 1e6 * 60 / span
        return res
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _merge_node(runs: list[dict]) -> dict:
    out = {"record": runs[0]["record"], "rounds": len(runs)}
    for key in ("duration_s", "steps", "late_steps", "skipped_steps", "bag_gaps", "bag_bytes", "bag_span_s"):
        if key in runs[0]:
            out[key] = sum(r[key] for r in runs)
    out["max_lag_before_batch_ms"] = max(r["max_lag_before_batch_ms"] for r in runs)
    out["max_lag_after_batch_ms"] = max(r["max_lag_after_batch_ms"] for r in runs)
    out["publish_lag_p99_ms"] = max(r["publish_lag_ms"]["p99"] for r in runs)
    out["publish_lag_max_ms"] = max(r["publish_lag_ms"]["max"] for r in runs)
    out["cpu_percent"] = sum(r["cpu_percent"] * r["duration_s"] for r in runs) / out["duration_s"]
    out["per_round"] = [(r["late_steps"], r["skipped_steps"]) for r in runs]
    if "bag_bytes" in out:
        out["bag_mb_per_min"] = out["bag_bytes"] / 1e6 * 60 / out["bag_span_s"]
        out["bag_closed_cleanly"] = all(r["bag_closed_cleanly"] for r in runs)
    return out


def part_node(duration: float, rounds: int, load: int) -> list[dict]:
    """Recording off and on alternated in `rounds` rounds (duration / rounds s per run), so that
    other load on the machine falls on both alike; `load` CPU burners beside the node."""
    runs: dict[bool, list[dict]] = {False: [], True: []}
    failed = 0
    for k in range(rounds):
        pair = {record: _node_run(record, duration / rounds, load)
                for record in ((False, True) if k % 2 == 0 else (True, False))}
        if pair[False] is None or pair[True] is None:       # a round counts only with both settings
            failed += 1
            continue
        for record, res in pair.items():
            runs[record].append(res)
    if not runs[False]:
        print(f"\nThe node over DDS: all {rounds} rounds failed")
        return []
    results = [_merge_node(runs[False]), _merge_node(runs[True])]
    print(f"\nThe node over DDS (bench/node_realtime.py), {duration:g} s per setting in {rounds} alternated "
          f"rounds ({failed} left out: a run failed), {load} CPU burner(s):\n")
    print("| recording | late / skipped steps | late / skipped per round | max lag before / after a batch [ms] "
          "| publish lag p99 / max [ms] | node CPU [% of a core] | bag [MB/min] | gaps in the bag |")
    print("|---|---|---|---|---|---|---|---|")
    for r in results:
        what = "on, 10 kHz, all signals" if r["record"] else "off"
        bag = f"{r['bag_mb_per_min']:.1f}" if r["record"] else "-"
        gaps = str(r["bag_gaps"]) if r["record"] else "-"
        pct = 100.0 * r["late_steps"] / r["steps"]
        rounds_s = ", ".join(f"{a}/{b}" for a, b in r["per_round"])
        print(f"| {what} | {r['late_steps']} ({pct:.2f} %) / {r['skipped_steps']} (of ~{r['steps']}) | {rounds_s} | "
              f"{r['max_lag_before_batch_ms']:.2f} / {r['max_lag_after_batch_ms']:.2f} | "
              f"{r['publish_lag_p99_ms']:.3f} / {r['publish_lag_max_ms']:.3f} | {r['cpu_percent']:.1f} | {bag} | "
              f"{gaps} |")
    return results


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--duration", type=float, default=60.0, help="s per run (default 60)")
    ap.add_argument("--part", choices=("loop", "costs", "node", "all"), default="all")
    ap.add_argument("--rounds", type=int, default=3, help="interleaved rounds of the loop and node parts (default 3)")
    ap.add_argument("--load", type=int, default=0, help="CPU burners beside the loop / node (default 0)")
    ap.add_argument("--configs", help=f"loop part: comma-separated configurations (default all: {','.join(LOOP_CONFIGS)})")
    ap.add_argument("--json", type=Path, help="write the raw figures here")
    ap.add_argument("--_loop", help=argparse.SUPPRESS)
    ap.add_argument("--_dir", type=Path, help=argparse.SUPPRESS)
    opts = ap.parse_args()
    if opts._loop:
        print(json.dumps(_run_loop(opts._loop, opts.duration, opts._dir)))
        return 0
    figures = {}
    if opts.part in ("costs", "all"):
        figures["costs"] = part_costs()
    if opts.part in ("loop", "all"):
        configs = tuple(opts.configs.split(",")) if opts.configs else LOOP_CONFIGS
        figures["loop"] = part_loop(opts.duration, opts.rounds, configs, opts.load)
    if opts.part in ("node", "all"):
        figures["node"] = part_node(opts.duration, opts.rounds, opts.load)
    if opts.json:
        opts.json.write_text(json.dumps(figures, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
