"""Write the reference bags (bags/README.md): the paper's dynamic test (Sec. 3.2: zero load
flow, duty steps at several levels and amplitudes, falls rate-limited to 2 /s) simulated on the
full model and written as the emulator records them. With the default parameters the bytes are
the same on every run on one machine (bit for bit; on another processor the stiff solver's last
bits can move an output sample by one quantum): test/replay/test_reproducible.py checks the
committed ones."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from pcv_sim.commands.common import params_from
from pcv_sim.errors import UsageError
from pcv_sim.replay.reference_bags import DEFAULT_OUT, PROTOCOLS, write_reference_bags

NAME = "reference-bags"
HELP = "regenerate the reference bags of bags/ (bit for bit) or write them elsewhere"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, metavar="DIR",
                   help="directory for the bags; bags of the same name there are replaced "
                        "(default: the repository's bags/)")
    p.add_argument("--only", choices=sorted(PROTOCOLS), action="append",
                   help="write only this bag (repeatable)")


def run(args: argparse.Namespace) -> int:
    if args.out.exists() and not args.out.is_dir():
        msg = f"--out {str(args.out)!r} is a file; expected a directory for the bags"
        raise UsageError(msg)
    params = params_from(args)
    for path in write_reference_bags(args.out, args.only, params):
        size = sum(f.stat().st_size for f in path.iterdir())
        print(f"wrote {path} ({size / 1e3:.0f} kB)", file=sys.stderr)
    return 0
