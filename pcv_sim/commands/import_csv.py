"""Import rig data from CSV into a bag with the device topics (SI units), for `pcv-sim replay`.
Columns and units come from --columns/--units or from a header line such as
`time[s],duty[%],pressure[bar],current[A],position[mm]`. Bad rows are reported by line number:
the import refuses them, or leaves them out with --skip-bad-rows (and lists them)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from pcv_sim.commands.common import emit_json
from pcv_sim.io.csv_import import import_csv, parse_units

NAME = "import-csv"
HELP = "convert rig data (CSV: time, duty, pressure, current, position) into a bag for replay"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("csv", type=Path, metavar="FILE", help="CSV file")
    p.add_argument("out", type=Path, metavar="OUT_BAG", help="bag directory to create (must not exist)")
    p.add_argument("--columns", metavar="NAMES",
                   help="column names in order, e.g. time,duty,pressure,current,position ('-' ignores a column); "
                        "default: the file's header line")
    p.add_argument("--units", action="append", metavar="COL=UNIT",
                   help="e.g. pressure=bar,time=ms,position=mm,duty=percent (SI by default: s, fraction, Pa, A, m, "
                        "m3/s); overrides units in the header")
    p.add_argument("--skip-bad-rows", action="store_true", help="leave bad rows out (and list them) instead of refusing")
    p.add_argument("--delimiter", metavar="CHAR", help="field separator (default: guessed from the first line)")
    p.add_argument("--start-time", type=float, default=0.0, metavar="EPOCH_S",
                   help="bag time of CSV time 0, in s since the epoch (default: 0)")
    p.add_argument("--no-range-check", action="store_true",
                   help="import signals outside their physical range (by default refused: a unit left out)")
    p.add_argument("--json", action="store_true", help="print the result as JSON")


def run(args: argparse.Namespace) -> int:
    columns = [c for c in args.columns.split(",")] if args.columns else None
    delimiter = {"tab": "\t", "\\t": "\t"}.get(args.delimiter, args.delimiter) if args.delimiter else None
    result = import_csv(args.csv, args.out, columns=columns, units=parse_units(args.units),
                        skip_bad_rows=args.skip_bad_rows, delimiter=delimiter,
                        start_ns=round(args.start_time * 1e9), check_ranges=not args.no_range_check)
    if args.json:
        emit_json({"bag": str(result.bag), "rows": result.rows, "columns": list(result.columns),
                   "units": dict(result.units), "topics": dict(result.topics),
                   "skipped_rows": [{"line": b.line, "reason": b.reason} for b in result.skipped],
                   "ignored_columns": list(result.ignored_columns)})
    else:
        print(f"wrote {result.bag}: {result.rows} rows -> " +
              ", ".join(f"{t} ({result.units[r]} -> SI)" for r, t in result.topics.items()))
        for name in result.ignored_columns:
            print(f"  ignored column {name!r} (not a device signal)")
    for b in result.skipped:
        print(f"pcv-sim import-csv: skipped {b}", file=sys.stderr)
    if result.skipped:
        print(f"pcv-sim import-csv: {len(result.skipped)} bad row(s) skipped", file=sys.stderr)
    return 0
