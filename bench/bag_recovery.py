"""Measurement: what each bag reader gives back from complete, unclosed and cut-off bags.

    .venv-kilted/bin/python bench/bag_recovery.py [--seconds 10] [--repeats 5]

Writes a bag as the emulator's recorder does (1 kHz pressure/current/spool position, a duty
change every 100 ms, BagWriter with a 1 s flush period driven by a fake clock, so a chunk ends
every simulated second), then makes the damaged copies a crash leaves:

- ``unclosed``: the writer was killed after its last flush: finished chunks, no summary, no
  footer, the provisional metadata.yaml of open time (message count 0);
- ``cut mid-chunk``: the unclosed file cut at 70 % of its size (a chunk cut in half);
- ``footer cut``: the complete file with its last 100 bytes missing;
- ``no metadata``: the complete MCAP file without metadata.yaml (read as a single .mcap file).

Each is read by pcv_sim's reader (``read_bag``), rosbags (``AnyReader`` on the directory; on the
single file where there is no directory), and the mcap package (``make_reader``: the indexed
reader for a seekable file). Prints the messages each gives back (of those written and of those
flushed to disk) or its error, and the median time to read the complete bag.
"""

from __future__ import annotations

import argparse
import platform
import shutil
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
from mcap.reader import make_reader
from rosbags.highlevel import AnyReader

from pcv_sim.io import BagWriter, read_bag
from pcv_sim.io.topics import BAG_TOPICS, ROLE_QOS, bag_topic

T0 = 1_704_067_200 * 1_000_000_000


def write(path: Path, seconds: int) -> tuple[int, Path]:
    """The complete bag at ``path``; returns messages written and an unclosed copy."""
    now = [0.0]
    qos = {bag_topic(r): q for r, q in ROLE_QOS.items()}
    w = BagWriter(path, topics=dict(BAG_TOPICS), qos=qos, flush_period_s=1.0, flush_thread=False,
                  clock=lambda: now[0])
    unclosed = path.with_name(path.name + "_unclosed")
    n = seconds * 1000
    t = T0 + np.arange(n, dtype=np.int64) * 1_000_000
    for k in range(0, n, 100):                       # 100 ms batches, as the recorder's thread
        sl = slice(k, k + 100)
        w.write_float64("/duty_cycle", int(t[k]), 0.3 + 0.1 * (k // 100 % 5))
        w.write_samples(t[sl], {"/pressure": np.full(100, 1e7), "/current": np.full(100, 1.2),
                                "/spool_position": np.full(100, 1e-4)}, frame_id="load_port")
        now[0] += 0.1
    w.flush()
    shutil.copytree(path, unclosed)                  # what a SIGKILL leaves after the last flush
    # The copy's metadata.yaml is the last one written: at open time (0 messages).
    written = w.message_count
    w.close()
    return written, unclosed


def read_pcv(p: Path) -> str:
    bag = read_bag(p)
    return str(sum(len(s) for s in bag.topics.values()))


def read_rosbags(p: Path) -> str:
    with AnyReader([p]) as r:
        return str(sum(1 for _ in r.messages()))


def read_mcap(p: Path) -> str:
    f = p if p.is_file() else next(p.glob("*.mcap"))
    with open(f, "rb") as fh:
        return str(sum(1 for _ in make_reader(fh).iter_messages()))


def attempt(fn, p: Path) -> str:
    try:
        return fn(p)
    except Exception as exc:
        text = str(exc).split("\n")[0]
        return f"error: {type(exc).__name__}: {text[:70]}"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=int, default=10)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        written, unclosed = write(root / "bag", args.seconds)
        mcap_name = "bag_0.mcap"
        cut = root / "cut"
        shutil.copytree(unclosed, cut)
        (cut / "bag_0.mcap").rename(cut / "cut_0.mcap")
        data = (cut / "cut_0.mcap").read_bytes()
        (cut / "cut_0.mcap").write_bytes(data[: int(0.7 * len(data))])
        meta = (cut / "metadata.yaml").read_text().replace(mcap_name, "cut_0.mcap")
        (cut / "metadata.yaml").write_text(meta)
        footer = root / "footer"
        shutil.copytree(root / "bag", footer)
        (footer / "bag_0.mcap").rename(footer / "footer_0.mcap")
        data = (footer / "footer_0.mcap").read_bytes()
        (footer / "footer_0.mcap").write_bytes(data[:-100])
        (footer / "metadata.yaml").write_text((footer / "metadata.yaml").read_text().replace(mcap_name, "footer_0.mcap"))
        single = root / "single.mcap"
        shutil.copy(root / "bag" / mcap_name, single)
        cases = [("complete", root / "bag"), ("unclosed", unclosed), ("cut mid-chunk", cut),
                 ("footer cut", footer), ("no metadata (one .mcap)", single)]
        print(f"machine: {platform.machine()}, Python {platform.python_version()}; "
              f"{written} messages written ({args.seconds} s at 1 kHz, 3 outputs + duty)")
        print("| bag | pcv_sim read_bag | rosbags AnyReader | mcap make_reader |")
        print("|---|---|---|---|")
        for name, p in cases:
            row = [attempt(f, p) for f in (read_pcv, read_rosbags, read_mcap)]
            print(f"| {name} | " + " | ".join(row) + " |")
        print()
        print("| reader | read the complete bag [ms], median |")
        print("|---|---|")
        for label, fn in (("pcv_sim read_bag (arrays)", read_pcv), ("rosbags AnyReader (raw messages)", read_rosbags),
                          ("mcap make_reader (raw messages)", read_mcap)):
            times = []
            for _ in range(args.repeats):
                t0 = time.perf_counter()
                fn(root / "bag")
                times.append(time.perf_counter() - t0)
            print(f"| {label} | {statistics.median(times) * 1e3:.1f} |")


if __name__ == "__main__":
    main()
