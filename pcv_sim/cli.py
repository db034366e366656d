"""`pcv-sim`: the command line. A thin argparse layer over the analysis and simulation code.

Exit status: 0 done, 1 a check failed (e.g. replay thresholds), 2 bad arguments or input.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from pathlib import Path

from pcv_sim import __version__
from pcv_sim.commands import COMMANDS
from pcv_sim.errors import PcvSimError
from pcv_sim.params import DEFAULT_CONFIG


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="pcv-sim",
        description="Model of a solenoid proportional pressure control valve (reducing + relieving).",
    )
    parser.add_argument("--version", action="version", version=f"pcv_sim {__version__}")
    config_help = f"valve parameter YAML (default: {DEFAULT_CONFIG.name} shipped with pcv_sim)"
    parser.add_argument("--config", type=Path, default=None, help=config_help)
    # The common options are accepted after the subcommand too (`pcv-sim step --config F`);
    # SUPPRESS keeps a value given before the subcommand when none is given after it.
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--config", type=Path, default=argparse.SUPPRESS, help=config_help)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMANDS:
        mod = importlib.import_module(name)
        p = sub.add_parser(mod.NAME, help=mod.HELP, description=mod.__doc__, parents=[common])
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args._run(args))
    except PcvSimError as err:
        print(f"pcv-sim {args.command}: error: {err}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # e.g. `pcv-sim static --json | head`: the reader left, nothing to report
        sys.stderr.close()
        return 0
    except KeyboardInterrupt:
        print(f"pcv-sim {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
