"""Rig data as CSV -> a bag with the device topics in SI units, for ``pcv-sim replay``.

Columns are named by role (:mod:`pcv_sim.io.topics`: ``time``, ``duty``/``duty_cycle``,
``pressure``, ``current``, ``position``/``spool_position``, ``load_flow``, ``supply_pressure``;
``-`` ignores a column) with a unit each, given either by flags (``columns``, ``units``) or by a
header line such as ``time[s],duty[%],pressure[bar],current[A],position[mm]``. Every value is
converted to SI once, here. Bad rows (wrong field count, empty or non-numeric fields, NaN/inf,
time not increasing, duty outside 0..1) are reported with their line numbers: the import refuses
them, or with ``skip_bad_rows`` leaves them out and lists them in the result.
"""

from __future__ import annotations

import csv
import math
import os
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Final

from pcv_sim.errors import BagError, PcvSimError
from pcv_sim.io.bag import FLOAT64, FLUID_PRESSURE, BagWriter
from pcv_sim.io.topics import (
    CURRENT,
    DUTY_CYCLE,
    LOAD_FLOW,
    OUTPUT_ROLES,
    PRESSURE,
    ROLE_TYPES,
    SPOOL_POSITION,
    SUPPLY_PRESSURE,
    bag_topic,
    role_of,
)
from pcv_sim.units import KINDS, M3S_PER_LPM

__all__ = ["RANGES", "UNITS", "BadRow", "CsvImportError", "CsvImportResult", "Range", "import_csv", "parse_units"]

TIME: Final = "time"


def _of_table(kind: str, *names: str) -> dict[str, float]:
    """Units of the one table (`pcv_sim.units.KINDS`) by their names there, keyed as a header is read
    (lower case)."""
    return {name.lower(): KINDS[kind].factor(name) for name in names}


_PRESSURE_UNITS: Final = _of_table("pressure", "Pa", "kPa", "bar", "mbar", "MPa", "psi")
#: Accepted units per column and their factor to SI; beside the table's, the words a data logger's
#: header uses for them (ns, percent, lpm, l/s).
UNITS: Final[Mapping[str, Mapping[str, float]]] = {
    TIME: {**_of_table("time", "s", "ms", "us"), "ns": 1e-9},
    DUTY_CYCLE: {"1": 1.0, "fraction": 1.0, **_of_table("fraction", "-"), "percent": KINDS["fraction"].factor("%"),
                 **_of_table("fraction", "%")},
    PRESSURE: _PRESSURE_UNITS,
    SUPPLY_PRESSURE: _PRESSURE_UNITS,
    CURRENT: _of_table("current", "A", "mA"),
    SPOOL_POSITION: _of_table("length", "m", "mm", "um"),
    LOAD_FLOW: {**_of_table("flow", "m3/s", "m^3/s", "L/min"), "lpm": KINDS["flow"].factor("L/min"), "l/s": 1e-3},
}
_SI: Final = {TIME: "s", DUTY_CYCLE: "1", PRESSURE: "pa", SUPPLY_PRESSURE: "pa", CURRENT: "a",
              SPOOL_POSITION: "m", LOAD_FLOW: "m3/s"}  # keys of UNITS (lower case)
_HEADER_FIELD: Final = re.compile(r"^\s*([A-Za-z_][\w]*|-)\s*(?:[\[(]\s*([^\])]*?)\s*[\])])?\s*$")
_MAX_LISTED: Final = 20


class CsvImportError(PcvSimError, ValueError):
    """A CSV file cannot be imported as asked: columns, units or rows."""


@dataclass(frozen=True)
class BadRow:
    line: int          # 1-based line number in the file
    reason: str

    def __str__(self) -> str:
        return f"line {self.line}: {self.reason}"


@dataclass(frozen=True)
class CsvImportResult:
    bag: Path
    rows: int                       # rows written
    skipped: tuple[BadRow, ...]     # bad rows left out (only with skip_bad_rows)
    columns: tuple[str, ...]        # role per column ('-' ignored)
    units: Mapping[str, str]        # role -> unit as read
    topics: Mapping[str, str]       # role -> bag topic
    ignored_columns: tuple[str, ...] = ()


def _canonical(name: str) -> str | None:
    n = name.strip().lower()
    if n in ("-", "_", "skip"):
        return "-"
    if n in ("time", "t", "timestamp"):
        return TIME
    return role_of(n)


def _accepted_columns() -> str:
    return "time, duty (duty_cycle), pressure, current, position (spool_position), load_flow, supply_pressure, - (ignore)"


def parse_units(spec: str | Sequence[str] | None) -> dict[str, str]:
    """``"pressure=bar,time=ms"`` (or a list of such) -> ``{"pressure": "bar", "time": "ms"}``."""
    items: list[str] = []
    for s in [spec] if isinstance(spec, str) else (spec or []):
        items += [p for p in s.split(",") if p.strip()]
    out: dict[str, str] = {}
    for item in items:
        name, sep, unit = item.partition("=")
        role = _canonical(name)
        if not sep or role is None or role == "-":
            msg = f"--units {item!r}: expected COLUMN=UNIT with a column of: {_accepted_columns()}"
            raise CsvImportError(msg)
        out[role] = _check_unit(role, unit)
    return out


def _check_unit(role: str, unit: str) -> str:
    u = unit.strip().lower()
    if u not in UNITS[role]:
        msg = f"unit {unit.strip()!r} for {role}: accepted are {', '.join(UNITS[role])}"
        raise CsvImportError(msg)
    return u


@dataclass(frozen=True)
class Range:
    """The physical range of a converted signal (SI), what it means, and the unit tried first."""

    low: float
    high: float
    meaning: str
    typical: float            # a typical largest |value| (SI): the suggested unit comes nearest it
    min_peak: float = 0.0     # the largest |value| must reach this (when the duty reaches 0.3)


#: Plausible ranges after conversion to SI, for a valve of this class (the shipped one holds
#: up to ~200 bar, strokes -0.55..+0.85 mm, draws up to ~2.1 A at 12 V / 5.6 ohm). Generous
#: so that offsets, noise and other valves of the class pass, tight enough that a unit left
#: out (a factor of 1e3 or 1e5) does not.
RANGES: Final[Mapping[str, Range]] = {
    PRESSURE: Range(-5e5, 1e8, "-5 .. 1000 bar", 100e5, 1e4),
    SUPPLY_PRESSURE: Range(0.0, 1e8, "0 .. 1000 bar", 200e5, 1e5),
    SPOOL_POSITION: Range(-5e-3, 5e-3, "within +-5 mm (the stroke is about -0.55 .. +0.85 mm)", 0.5e-3),
    CURRENT: Range(-1.0, 10.0, "-1 .. 10 A", 1.5, 0.05),
    LOAD_FLOW: Range(-100 * M3S_PER_LPM, 100 * M3S_PER_LPM, "+-100 L/min", 10 * M3S_PER_LPM),
}


def _check_ranges(path: Path, values: Mapping[str, Sequence[float]], unit_of: Mapping[str, str]) -> None:
    """Refuse a signal whose converted values leave its physical range, suggesting the unit that
    would bring them into it (the usual cause: a unit left out)."""
    duty_reaches = max(values.get(DUTY_CYCLE, [0.0]), default=0.0) >= 0.3
    for role, rng in RANGES.items():
        if role not in values or not values[role]:
            continue
        lo, hi = min(values[role]), max(values[role])
        peak = max(abs(lo), abs(hi))
        too_small = duty_reaches and peak < rng.min_peak
        if rng.low <= lo and hi <= rng.high and not too_small:
            continue
        raw = peak / UNITS[role][unit_of[role]]
        fits = [u for u, f in UNITS[role].items() if rng.low <= lo / UNITS[role][unit_of[role]] * f
                and hi / UNITS[role][unit_of[role]] * f <= rng.high and raw * f >= rng.min_peak
                and u != unit_of[role]]
        fits.sort(key=lambda u: abs(math.log(max(raw * UNITS[role][u], 1e-300) / rng.typical)))
        name = "position" if role == SPOOL_POSITION else role
        hint = (f": looks like {fits[0]}: add --units {name}={fits[0]} (or a unit in the header, "
                f"{name}[{fits[0]}])") if fits else ""
        si = {"pa": "Pa", "a": "A"}.get(_SI[role], _SI[role])
        if too_small:
            what = (f"reaches at most {peak:.6g} {si} (read as {unit_of[role]}), below the {rng.min_peak:g} {si} "
                    f"that a valve driven to 30 % duty or more holds (range {rng.meaning})")
        else:
            what = f"spans {lo:.6g} .. {hi:.6g} {si} (read as {unit_of[role]}), outside the physical range {rng.meaning}"
        msg = f"{str(path)!r}: {role} {what}{hint}; --no-range-check imports it as it is"
        raise CsvImportError(msg)


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def import_csv(
    csv_path: str | os.PathLike[str],
    bag_path: str | os.PathLike[str],
    *,
    columns: Sequence[str] | None = None,
    units: Mapping[str, str] | None = None,
    skip_bad_rows: bool = False,
    delimiter: str | None = None,
    start_ns: int = 0,
    namespace: str = "/",
    check_ranges: bool = True,
) -> CsvImportResult:
    """Convert ``csv_path`` to a bag at ``bag_path`` (which must not exist).

    With ``check_ranges`` every signal is checked against its physical range after conversion
    (:data:`RANGES`): a unit left out (bar read as Pa, mm read as m) is refused with a hint.
    Times become bag timestamps ``start_ns + round(time_s * 1e9)``; a FluidPressure's header
    stamp is the same time. Lines starting with ``#`` are comments; blank lines are ignored.

    Raises:
        CsvImportError: unknown columns or units, no time or duty or output column, bad rows
            (listed by line number) unless ``skip_bad_rows``, no good row at all, or a signal
            outside its physical range.
        BagError: the bag cannot be written.
    """
    path = Path(csv_path)
    try:
        text = path.read_text("utf-8-sig")
    except FileNotFoundError:
        msg = f"CSV file {str(path)!r} does not exist"
        raise CsvImportError(msg) from None
    except (OSError, UnicodeDecodeError) as exc:
        msg = f"cannot read {str(path)!r} as UTF-8 text: {exc}"
        raise CsvImportError(msg) from exc
    lines = [(n, line) for n, line in enumerate(text.splitlines(), start=1)
             if line.strip() and not line.lstrip().startswith("#")]
    if not lines:
        msg = f"{str(path)!r} holds no data rows"
        raise CsvImportError(msg)
    if delimiter is None:
        try:
            delimiter = csv.Sniffer().sniff(lines[0][1], delimiters=",;\t ").delimiter
        except csv.Error:
            delimiter = ","
    rows = [(n, [f.strip() for f in fields]) for (n, _), fields in
            zip(lines, csv.reader([line for _, line in lines], delimiter=delimiter))]
    if delimiter == " ":
        rows = [(n, [f for f in fields if f]) for n, fields in rows]

    _first_n, first = rows[0]
    header_units: dict[str, str] = {}
    header_roles: list[str] | None = None
    ignored: list[str] = []
    if not all(_is_number(f) for f in first if f):  # a header line
        header_roles = []
        for field in first:
            m = _HEADER_FIELD.match(field)
            role = _canonical(m.group(1)) if m else None
            if role is None:
                if columns is None:
                    ignored.append(field)
                header_roles.append("-")
                continue
            header_roles.append(role)
            if m and m.group(2) and role != "-":
                header_units[role] = _check_unit(role, m.group(2))
        rows = rows[1:]
    if columns is not None:
        roles = []
        for c in columns:
            role = _canonical(c)
            if role is None:
                msg = f"--columns: unknown column {c!r}; accepted: {_accepted_columns()}"
                raise CsvImportError(msg)
            roles.append(role)
    elif header_roles is not None:
        roles = header_roles
    else:
        msg = (
            f"{str(path)!r} has no header line: name the columns with --columns, e.g. "
            f"--columns time,duty,pressure,current,position, or add a header such as "
            f"time[s],duty[%],pressure[bar],current[A],position[mm]"
        )
        raise CsvImportError(msg)
    named = [r for r in roles if r != "-"]
    if dups := sorted({r for r in named if named.count(r) > 1}):
        msg = f"column(s) {dups} appear more than once"
        raise CsvImportError(msg)
    if TIME not in named or DUTY_CYCLE not in named:
        if columns is None and header_roles is not None:
            seen = [f for f in first]
            understood = [f"{f!r} -> {r}" for f, r in zip(seen, header_roles) if r != "-"]
            msg = (
                f"the header names {seen} give no {' and no '.join(n for n in ('time', 'duty') if n not in named)} "
                f"column (a time and a duty column are needed); understood: {', '.join(understood) or 'none'}; accepted names: "
                f"{_accepted_columns()}, each with an optional unit in brackets (pressure[bar]); or name "
                f"the columns in order with --columns, e.g. --columns time,duty,pressure,current,position"
            )
        else:
            msg = f"columns {roles}: a time and a duty column are needed; accepted: {_accepted_columns()}"
        raise CsvImportError(msg)
    if not any(r in OUTPUT_ROLES for r in named):
        names_seen = f" (header names seen: {first}, understood: {named})" if columns is None and header_roles else ""
        msg = f"columns {roles}: at least one of pressure, current, position is needed to compare{names_seen}"
        raise CsvImportError(msg)
    unit_of = {r: _SI[r] for r in named}
    unit_of.update({r: u for r, u in header_units.items() if r in unit_of})
    for r, u in (units or {}).items():
        if r not in unit_of:
            msg = f"--units names {r!r}, which is not among the columns {named}"
            raise CsvImportError(msg)
        unit_of[r] = _check_unit(r, u)
    factor = {r: UNITS[r][unit_of[r]] for r in named}

    bad: list[BadRow] = []
    good: list[tuple[int, list[float]]] = []  # (time ns, values in SI per named role)
    idx = [(i, r) for i, r in enumerate(roles) if r != "-"]
    last_t: float | None = None
    for n, fields in rows:
        if len(fields) != len(roles):
            bad.append(BadRow(n, f"{len(fields)} fields, expected {len(roles)}"))
            continue
        values: list[float] = []
        reason = None
        for i, role in idx:
            raw = fields[i]
            if raw == "":
                reason = f"{role} is empty"
                break
            try:
                v = float(raw)
            except ValueError:
                reason = f"{role} {raw!r} is not a number"
                break
            if not math.isfinite(v):
                reason = f"{role} is {raw}"
                break
            values.append(v * factor[role])
        if reason is None:
            named_values = dict(zip((r for _, r in idx), values))
            t = named_values[TIME]
            d = named_values[DUTY_CYCLE]
            if not 0.0 <= d <= 1.0:
                hint = " (declare duty=percent?)" if unit_of[DUTY_CYCLE] != "percent" and 1 < d <= 100 else ""
                reason = f"duty {d:g} is outside 0..1 after conversion{hint}"
            elif t < 0:
                reason = f"time {t:g} s is negative"
            elif last_t is not None and t <= last_t:
                reason = f"time {t:.9g} s does not increase (previous good row: {last_t:.9g} s)"
        if reason is not None:
            bad.append(BadRow(n, reason))
            continue
        last_t = values[[r for _, r in idx].index(TIME)]
        good.append((n, values))
    if bad and not skip_bad_rows:
        listed = "; ".join(str(b) for b in bad[:_MAX_LISTED])
        more = f"; and {len(bad) - _MAX_LISTED} more" if len(bad) > _MAX_LISTED else ""
        msg = (
            f"{str(path)!r}: {len(bad)} bad row(s): {listed}{more}. Fix them, or pass "
            f"--skip-bad-rows to leave them out (they are then listed)"
        )
        raise CsvImportError(msg)
    if not good:
        msg = f"{str(path)!r}: no good data row"
        raise CsvImportError(msg)

    order = [r for _, r in idx]
    if check_ranges:
        _check_ranges(path, {r: [v[k] for _, v in good] for k, r in enumerate(order)}, unit_of)
    topics = {r: bag_topic(r, namespace) for r in order if r != TIME}
    types = {topics[r]: ROLE_TYPES[r] for r in topics}
    t_col = order.index(TIME)
    try:
        writer = BagWriter(bag_path, topics=types, flush_thread=False, clock=lambda: 0.0)
    except BagError:
        raise
    with writer as w:
        for _, values in good:
            t_ns = start_ns + round(values[t_col] * 1e9)
            for role, v in zip(order, values):
                if role == TIME:
                    continue
                if ROLE_TYPES[role] == FLUID_PRESSURE:
                    w.write_fluid_pressure(topics[role], t_ns, v, 0.0)
                else:
                    assert ROLE_TYPES[role] == FLOAT64
                    w.write_float64(topics[role], t_ns, v)
    return CsvImportResult(
        bag=Path(bag_path),
        rows=len(good),
        skipped=tuple(bad),
        columns=tuple(roles),
        units={r: unit_of[r] for r in order},
        topics=topics,
        ignored_columns=tuple(ignored),
    )
