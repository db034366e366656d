"""Run every benchmark with its short settings (`make bench`); each prints Markdown for
BENCHMARKS.md. The long runs (the 10-minute real-time soak) are separate:

    .venv-kilted/bin/python bench/node_realtime.py --duration 600
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent

# (script, arguments): short enough for a few minutes in all.
RUNS = [
    ("model_speed.py", []),
    ("replay_speed.py", ["--repeats", "3"]),
    ("node_wake_jitter.py", ["--duration", "10"]),
    ("node_drain.py", []),
    ("node_realtime.py", ["--duration", "30"]),
    ("node_recording.py", ["--duration", "30"]),
]


def main() -> int:
    failed = []
    for script, args in RUNS:
        path = HERE / script
        if not path.exists():
            print(f"\n## {script}: not present, skipped\n")
            continue
        cmd = [sys.executable, str(path), *args]
        print(f"\n## {script}\n\n`{' '.join(['python', 'bench/' + script, *args])}`\n", flush=True)
        if subprocess.run(cmd, check=False).returncode != 0:
            failed.append(script)
    if failed:
        print(f"\nfailed: {', '.join(failed)}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
