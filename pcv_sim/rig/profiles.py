"""Profiles: a quantity as a function of time, in segments that each start at a time `t`.

A segment is one of (values with units, `pcv_sim.units`; times relative to the segment's `t`):

    value: X                                      X from t on (a step)
    ramp: {to: X, duration: D, from: X0}          linear X0 -> X over D, then X; `from` defaults
                                                  to the value just before t
    table: [[0, X0], [0.2 s, X1], ...]            piecewise linear through (time, value); the last
                                                  value held after the last time
    sine: {amplitude: A, frequency: F, offset: O} O + A sin(2 pi F tau)
    chirp: {amplitude: A, from: F0, to: F1,       O + A sin(phi), phi = 2 pi (F0 tau + (F1 - F0)
            duration: D, offset: O}               tau^2 / (2 D)) up to D, then at F1 (phase continuous)
    file: {path: profile.csv, column: NAME,       a table from a CSV column (header row; a header
           unit: U, time: NAME, time_unit: U}     `name [unit]` gives the unit); times counted from
                                                  the file's first row; `time` defaults to the
                                                  first column

with tau = time - t. Each segment holds until the next one's t.
"""

from __future__ import annotations

import csv
import itertools
import math
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pcv_sim.errors import ParameterError
from pcv_sim.keys import closest, exactly_one, unknown_message
from pcv_sim.params import (
    Check,
    at_least,
    between,
    check_mapping,
    check_si,
    check_value,
    declarations,
    non_empty,
    parameter,
    read,
    refused_as,
)
from pcv_sim.units import quantity

__all__ = ["SHAPES", "ChirpKeys", "FileKeys", "Profile", "ProfileError", "RampKeys", "Segment", "ShapeKeys", "SineKeys",
           "parse_segment"]

_HEADER = re.compile(r"^\s*(.*?)\s*\[(.*)\]\s*$")
_FREQUENCY = between(0.0, 1000.0, "a frequency")


class ProfileError(ParameterError):
    """A profile segment that cannot be evaluated as written."""


# --- the keys of each shape, declared once (kind value: the profile's quantity) -----------------


@dataclass(frozen=True, kw_only=True)
class RampKeys:
    to: float = parameter("-", "the final value", kind="value")
    duration: float = parameter("s", "the ramp's time", at_least(0.0, "a time"), kind="time")
    start: float | None = parameter("-", "the start value (default: the value just before t)", kind="value",
                                    default=None, name="from")


@dataclass(frozen=True, kw_only=True)
class SineKeys:
    amplitude: float = parameter("-", "half the peak-to-peak swing", at_least(0.0), kind="value", difference=True)
    frequency: float = parameter("Hz", "the sine's frequency", _FREQUENCY, kind="frequency")
    offset: float = parameter("-", "the value it swings about", kind="value", default=0.0)


@dataclass(frozen=True, kw_only=True)
class ChirpKeys:
    amplitude: float = parameter("-", "half the peak-to-peak swing", at_least(0.0), kind="value", difference=True)
    f0: float = parameter("Hz", "the start frequency", _FREQUENCY, kind="frequency", name="from")
    f1: float = parameter("Hz", "the end frequency (held after the sweep)", _FREQUENCY, kind="frequency", name="to")
    duration: float = parameter("s", "the sweep's time", at_least(0.0, "a duration", strict=True), kind="time")
    offset: float = parameter("-", "the value it swings about", kind="value", default=0.0)


@dataclass(frozen=True, kw_only=True)
class FileKeys:
    path: str = parameter("-", "a CSV file with a header row, relative to the scenario", kind="str")
    column: str = parameter("-", "the column's name in the header row", kind="str")
    unit: str | None = parameter("-", "the column's unit (default: the header's `name [unit]`, else SI)", kind="str",
                                 default=None)
    time: str | None = parameter("-", "the time column (default: the first)", kind="str", default=None)
    time_unit: str | None = parameter("-", "the time column's unit (default: its header's, else s)", kind="str",
                                      default=None)


@dataclass(frozen=True, kw_only=True)
class ShapeKeys:
    """A segment: exactly one of these (or a bare value: `value`)."""

    value: float = parameter("-", "the value from t on (a step)", kind="value")
    ramp: RampKeys = parameter("-", "linear from the value before t (or `from`) to `to` over `duration`",
                               kind="section", section=RampKeys)
    table: list[Any] = parameter("-", "[[time, value], ...] piecewise linear, times from t; the last value held",
                                 non_empty, kind="list")
    sine: SineKeys = parameter("-", "offset + amplitude sin(2 pi frequency (time - t))", kind="section",
                               section=SineKeys)
    chirp: ChirpKeys = parameter("-", "a sine sweeping from `from` to `to` Hz over `duration`, phase continuous",
                                 kind="section", section=ChirpKeys)
    file: FileKeys = parameter("-", "a table from a CSV column, times from the file's first row", kind="section",
                               section=FileKeys)


SHAPES = tuple(declarations(ShapeKeys))
_SHAPE = declarations(ShapeKeys)
#: A table row's time (from the segment's t).
_ROW_TIME = parameter("s", "a row's time from t", kind="time").metadata


@dataclass(frozen=True)
class Segment:
    """One segment from `t` (s): `shape` and its numbers in SI (`start` None: a ramp from the
    value before t)."""

    t: float
    shape: str
    value: float = 0.0                      # value: X; ramp: to; sine/chirp: offset
    start: float | None = None              # ramp: from
    duration: float = 0.0                   # ramp, chirp
    amplitude: float = 0.0
    f0: float = 0.0                         # sine: frequency; chirp: from
    f1: float = 0.0                         # chirp: to
    times: tuple[float, ...] = ()           # table, file (from 0)
    values: tuple[float, ...] = ()
    source: str = field(default="", compare=False)    # a file's path, for the events

    @property
    def constant(self) -> bool:
        return self.shape == "value"

    def end(self) -> float:
        """The tau after which the segment is constant (inf: never)."""
        if self.shape == "value":
            return 0.0
        if self.shape == "ramp":
            return self.duration
        if self.shape in ("table", "file"):
            return self.times[-1]
        return math.inf

    def at(self, tau: float, before: float) -> float:
        """The value at tau = time - t >= 0; `before` is the profile's value just before t."""
        s = self.shape
        if s == "value":
            return self.value
        if s == "ramp":
            x0 = before if self.start is None else self.start
            if self.duration <= 0.0 or tau >= self.duration:
                return self.value
            return x0 + (self.value - x0) * tau / self.duration
        if s in ("table", "file"):
            return float(np.interp(tau, self.times, self.values))
        if s == "sine":
            return self.value + self.amplitude * math.sin(2.0 * math.pi * self.f0 * tau)
        # chirp: the frequency sweeps linearly F0 -> F1 over D; the phase is its integral
        d = self.duration
        if tau <= d:
            phase = self.f0 * tau + (self.f1 - self.f0) * tau * tau / (2.0 * d)
        else:
            phase = self.f0 * d + (self.f1 - self.f0) * d / 2.0 + self.f1 * (tau - d)
        return self.value + self.amplitude * math.sin(2.0 * math.pi * phase)

    def describe(self, unit: str = "", scale: float = 1.0) -> str:
        """The segment in words for the events list (values in `unit`, SI x `scale`)."""
        u = f" {unit}" if unit else ""

        def q(x: float) -> str:
            return f"{x * scale:.4g}{u}"
        s = self.shape
        if s == "value":
            return q(self.value)
        if s == "ramp":
            fr = "the value before" if self.start is None else q(self.start)
            return f"ramp from {fr} to {q(self.value)} over {self.duration * 1e3:g} ms"
        if s == "sine":
            return f"sine {q(self.amplitude)} at {self.f0:g} Hz about {q(self.value)}"
        if s == "chirp":
            return (f"chirp {q(self.amplitude)} from {self.f0:g} to {self.f1:g} Hz over {self.duration:g} s "
                    f"about {q(self.value)}")
        if s == "file":
            return f"{self.source}: {len(self.times)} points over {self.times[-1]:g} s"
        return f"table of {len(self.times)} points over {self.times[-1]:g} s"


class Profile:
    """Segments in time order; `initial` before the first one."""

    def __init__(self, segments: Sequence[Segment], initial: float = 0.0) -> None:
        self.segments = tuple(segments)
        self.initial = initial
        self._before: list[float] = []
        prev = initial
        for k, seg in enumerate(self.segments):
            self._before.append(prev)
            nxt = self.segments[k + 1].t if k + 1 < len(self.segments) else math.inf
            if math.isfinite(nxt):
                prev = seg.at(nxt - seg.t, prev)
        self._starts = [s.t for s in self.segments]

    def index(self, t: float) -> int:
        """The segment in force at t (-1: before the first)."""
        k = -1
        for j, t0 in enumerate(self._starts):
            if t0 <= t + 1e-12:
                k = j
            else:
                break
        return k

    def sample(self, times: Sequence[float]) -> list[float]:
        """The profile at each of `times` (not decreasing): `[self(t) for t in times]` to the last
        bit, with each segment looked up once."""
        out = []
        starts = self._starts
        k = -1
        for t in times:
            while k + 1 < len(starts) and starts[k + 1] <= t + 1e-12:
                k += 1
            if k < 0:
                out.append(self.initial)
            else:
                seg = self.segments[k]
                out.append(seg.at(max(0.0, t - seg.t), self._before[k]))
        return out

    def __call__(self, t: float) -> float:
        k = self.index(t)
        if k < 0:
            return self.initial
        seg = self.segments[k]
        return seg.at(max(0.0, t - seg.t), self._before[k])


def _table(where: str, raw: Any, kind: str, check: Callable[[str, float], float]
           ) -> tuple[tuple[float, ...], tuple[float, ...]]:
    if not isinstance(raw, list) or len(raw) < 2:
        raise ProfileError(f"{where}: got {raw!r}; accepted is a list of at least two [time, value] pairs")
    times, values = [], []
    for k, row in enumerate(raw):
        if not isinstance(row, (list, tuple)) or len(row) != 2:
            raise ProfileError(f"{where}[{k}]: got {row!r}; accepted is a pair [time, value]")
        times.append(check_value(f"{where}[{k}][0]", _ROW_TIME, row[0]))
        values.append(check_value(f"{where}[{k}][1]", _SHAPE["value"].metadata, row[1], of=kind))
        check(f"{where}[{k}][1]", values[-1])
    _check_times(where, times)
    return tuple(times), tuple(values)


def _check_times(where: str, times: Sequence[float]) -> None:
    if times[0] < 0.0 or any(b <= a for a, b in itertools.pairwise(times)):
        raise ProfileError(f"{where}: times {list(times)[:6]}...; accepted are increasing times >= 0 s")


def _csv(where: str, spec: Mapping[str, Any], kind: str, base: Path | None) -> tuple[
        tuple[float, ...], tuple[float, ...], str]:
    path = read(FileKeys, spec, "path", where)
    column = read(FileKeys, spec, "column", where)
    p = (base / str(path)) if base is not None else Path(str(path))
    try:
        with p.open(newline="", encoding="utf-8") as fh:
            rows = [r for r in csv.reader(fh) if r and not r[0].lstrip().startswith("#")]
    except OSError as err:
        raise ProfileError(f"{where}.path: cannot read {p}: {err.strerror}") from None
    if len(rows) < 3:
        raise ProfileError(f"{where}.path: {p} has {len(rows)} rows; accepted is a header row and at least two rows")
    names, units = [], []
    for h in rows[0]:
        m = _HEADER.match(h)
        names.append(m.group(1) if m else h.strip())
        units.append(m.group(2).strip() if m else None)
    tcol = read(FileKeys, spec, "time", where) or names[0]
    for key, col in (("column", column), ("time", tcol)):
        if col not in names:
            near = closest(col, names)
            raise ProfileError(f"{where}.{key}: no column {col!r} in {p}{f' (did you mean {near!r}?)' if near else ''};"
                               f" columns: {', '.join(names)}")
    jt, jv = names.index(tcol), names.index(column)
    unit = read(FileKeys, spec, "unit", where) or units[jv]
    tunit = read(FileKeys, spec, "time_unit", where) or units[jt] or "s"
    t_factor = quantity(f"1 {tunit}", "time", f"{where}.time_unit")
    times, values = [], []
    for r, row in enumerate(rows[1:], start=2):
        try:
            t = float(row[jt]) * t_factor
            v = quantity(f"{row[jv]} {unit}" if unit else float(row[jv]), kind, f"{p}:{r} {column}")
        except (ValueError, IndexError):
            raise ProfileError(f"{p}:{r}: {row!r}; accepted are numbers in columns {tcol} and {column}") from None
        times.append(t)
        values.append(v)
    t0 = times[0]
    times = [t - t0 for t in times]
    _check_times(f"{where} ({p})", times)
    return tuple(times), tuple(values), str(path)


@refused_as(ProfileError)
def parse_segment(where: str, t: float, raw: Any, kind: str, *, base: Path | None = None,
                  check: Check | None = None) -> Segment:
    """One segment at `t` from the file's `raw` (a bare value, or a mapping with one of SHAPES).
    `kind` is the quantity's kind (`pcv_sim.units.KINDS`); `check` (a `pcv_sim.params` check:
    None when fine, else what is accepted) holds each value the profile can reach. ProfileError
    naming the key and what is accepted."""
    value = _SHAPE["value"].metadata

    def reach(w: str, v: float) -> float:
        return check_si(w, value, v, check=check, of=kind)

    if not isinstance(raw, Mapping):
        return Segment(t, "value", value=check_value(where, value, raw, check=check, of=kind))
    shape = exactly_one(where, raw, SHAPES)
    extra = unknown_message(where, {k: v for k, v in raw.items() if k != "t"}, (shape,))
    if extra:
        raise ProfileError(extra)
    spec = raw[shape]
    w = f"{where}.{shape}"
    if shape == "value":
        return Segment(t, "value", value=check_value(w, value, spec, check=check, of=kind))
    if shape == "table":
        times, values = _table(w, spec, kind, reach)
        return Segment(t, "table", times=times, values=values)
    if shape == "file":
        if isinstance(spec, str):
            raise ProfileError(f"{w}: got {spec!r}; accepted is {{path: {spec}, column: NAME, unit: U}}")
        times, values, src = _csv(w, check_mapping(FileKeys, spec, w), kind, base)
        for v in (min(values), max(values)):
            reach(f"{w}.column", v)
        return Segment(t, "file", times=times, values=values, source=src)
    if shape == "ramp":
        spec = check_mapping(RampKeys, spec, w)
        d = read(RampKeys, spec, "duration", w)
        start = read(RampKeys, spec, "from", w, check=check, of=kind)
        return Segment(t, "ramp", value=read(RampKeys, spec, "to", w, check=check, of=kind), start=start, duration=d)
    keys = SineKeys if shape == "sine" else ChirpKeys
    spec = check_mapping(keys, spec, w)
    amp = read(keys, spec, "amplitude", w, of=kind)
    offset = read(keys, spec, "offset", w, check=check, of=kind)
    for x in (offset - amp, offset + amp):
        reach(f"{w} (offset +- amplitude)", x)
    if shape == "sine":
        return Segment(t, "sine", value=offset, amplitude=amp, f0=read(SineKeys, spec, "frequency", w))
    return Segment(t, "chirp", value=offset, amplitude=amp, f0=read(ChirpKeys, spec, "from", w),
                   f1=read(ChirpKeys, spec, "to", w), duration=read(ChirpKeys, spec, "duration", w))
