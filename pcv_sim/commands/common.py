"""Shared pieces of the subcommands: options, output, progress, saving plots."""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any, TypeVar

from pcv_sim.analysis.in_force import DAMPING_CHOICES
from pcv_sim.params import ValveParams, load_params

T = TypeVar("T")


def add_output_options(parser: argparse.ArgumentParser, *, plot: bool = True) -> None:
    parser.add_argument("--json", action="store_true", help="print machine-readable JSON (SI units) instead of text")
    if plot:
        parser.add_argument("--plot", metavar="FILE.png", type=Path, help="also write a plot to FILE.png")


def _number(text: str, not_a_number: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(not_a_number) from None


def _positive(text: str, not_a_number: str, not_positive: str) -> float:
    v = _number(text, not_a_number)
    if not math.isfinite(v) or v <= 0:
        raise argparse.ArgumentTypeError(not_positive)
    return v


def fraction(text: str) -> float:
    """argparse type for a duty: a fraction 0..1; refuses percent with a hint."""
    v = _number(text, f"{text!r} is not a number; a duty is a fraction 0..1")
    if not math.isfinite(v) or not 0.0 <= v <= 1.0:
        hint = f" (did you mean {v / 100:g}? the duty is a fraction, not percent)" if 2.0 <= v <= 100.0 else ""
        raise argparse.ArgumentTypeError(f"{text} is outside 0..1{hint}")
    return v


def positive(text: str) -> float:
    """argparse type: a finite number > 0."""
    return _positive(text, f"{text!r} is not a number", f"{text} must be a finite number > 0")


def damping_option(text: str) -> float | str:
    """argparse type: ``equivalent``, ``paper`` or a damping in Ns/m (> 0)."""
    if text in DAMPING_CHOICES:
        return text
    return _positive(text, f"{text!r}: accepted are equivalent, paper or a number in Ns/m",
                     f"{text}: a damping must be a finite number > 0 (Ns/m)")


def metric_limits(items: list[str] | None, flag: str, error: type[Exception], example: str) -> dict[str, float]:
    """``--fail-below`` style gates: ``["pressure_fit_percent=99,current_rmse_a=0.01"]`` -> {metric: limit}.

    ``error`` is the subcommand's own error class, so the exit code and message prefix stay its own.
    """
    out: dict[str, float] = {}
    for part in (p for item in items or [] for p in item.split(",")):
        key, sep, value = part.partition("=")
        try:
            limit = float(value)
        except ValueError:
            limit = math.nan
        if not sep or not key.strip() or not math.isfinite(limit):
            raise error(f"{flag} {part!r}: expected METRIC=NUMBER, e.g. {example}")
        out[key.strip()] = limit
    return out


def params_from(args: argparse.Namespace) -> ValveParams:
    return load_params(args.config)


def emit_json(data: Any) -> None:
    def default(o: Any) -> Any:
        if hasattr(o, "tolist"):
            return o.tolist()
        if isinstance(o, complex):
            return [o.real, o.imag]
        return str(o)

    def clean(o: Any) -> Any:  # JSON has no NaN/inf: write null
        if isinstance(o, float) and not math.isfinite(o):
            return None
        if isinstance(o, dict):
            return {k: clean(v) for k, v in o.items()}
        if isinstance(o, (list, tuple)):
            return [clean(v) for v in o]
        return o

    json.dump(clean(data), sys.stdout, indent=2, default=default)
    sys.stdout.write("\n")


def progress(items: Iterable[T], total: int, label: str) -> Iterator[T]:
    """Yield items; on a terminal, show a progress line on stderr (nothing when piped)."""
    tty = sys.stderr.isatty()
    start = time.monotonic()
    for k, item in enumerate(items):
        if tty:
            sys.stderr.write(f"\r{label}: {k}/{total} ({time.monotonic() - start:.1f} s)")
            sys.stderr.flush()
        yield item
    if tty:
        sys.stderr.write(f"\r{label}: {total}/{total} ({time.monotonic() - start:.1f} s)\n")


def save(fig: Any, path: Path) -> None:
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    print(f"wrote {path}", file=sys.stderr)
