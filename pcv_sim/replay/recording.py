"""A bag as a replay sees it: the input timeline and the measured outputs, validated.

Signals are found by role (see :mod:`pcv_sim.io.topics`): by default the emulator's root
namespace names (``/duty_cycle``, ``/pressure``, ...), else a single topic ending in
``/<role>`` (a namespaced emulator such as ``/left/pressure``); ``namespace`` selects one
device of a bag holding several (the rig node's bag: ``/left/...``, ``/right/...``; the full
namespace or its last part(s), ``left``); ``topic_map`` overrides any of these
(``{"pressure": "/rig/p"}``), because other recorders use other names.

Time: the bag's log time, except for FluidPressure messages, whose header stamp is the sample
time (docs/interface.md). Replay time 0 is the first duty command: the model starts at rest
there. Nothing is dropped without saying so: every exclusion is listed in ``notes``, every loss
the bag reader found in ``warnings``.

Gaps: where the measured outputs stop for more than :data:`GAP_FACTOR` times their usual sample
period (an emulator that skipped steps under load, a logger that dropped samples), the recording
lists a :class:`Gap`. The device's state did not follow the inputs through such an interval the
way a continuous model does, so :func:`pcv_sim.replay.compare.replay` keeps the samples after a
gap out of its metrics until the model could have re-synchronised (see there).
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Final

import numpy as np
import numpy.typing as npt

from pcv_sim.io.bag import DECODABLE_TYPES, FLUID_PRESSURE, BagContents, TopicSeries, read_bag
from pcv_sim.io.topics import (
    DUTY_CYCLE,
    INPUT_ROLES,
    LOAD_FLOW,
    OUTPUT_ROLES,
    ROLE_ALIASES,
    ROLE_TYPES,
    ROLES,
    SUPPLY_PRESSURE,
    bag_topic,
    role_of,
)
from pcv_sim.replay.errors import ReplayError
from pcv_sim.units import NS_PER_S

__all__ = ["GAP_FACTOR", "Gap", "Recording", "Series", "device_namespaces", "find_gaps", "load_recording",
           "parse_topic_map"]

_STAMP_OFFSET_NOTE_NS = 1_000_000  # report header stamps that differ from log times by > 1 ms
#: A pause between two output samples longer than this many median sample periods is a gap. A
#: 1 kHz recording has gaps from 5 ms on: far beyond the jitter of a logger, far below the
#: 51-60 ms stalls of an emulator that skipped steps.
GAP_FACTOR: Final = 5.0


@dataclass(frozen=True)
class Series:
    """One signal: times in ns relative to the first duty command, values in SI units."""

    role: str
    topic: str
    t_ns: npt.NDArray[np.int64]
    value: npt.NDArray[np.float64]

    @property
    def t(self) -> npt.NDArray[np.float64]:
        """Times in s."""
        return self.t_ns.astype(np.float64) / NS_PER_S

    def __len__(self) -> int:
        return len(self.t_ns)


@dataclass(frozen=True)
class Gap:
    """No output sample between ``start_ns`` (the last before) and ``end_ns`` (the first after),
    relative ns; ``missing`` samples at the usual period would have been in between."""

    start_ns: int
    end_ns: int
    missing: int
    roles: tuple[str, ...]

    @property
    def start(self) -> float:
        return self.start_ns / NS_PER_S

    @property
    def end(self) -> float:
        return self.end_ns / NS_PER_S

    @property
    def duration(self) -> float:
        """s"""
        return (self.end_ns - self.start_ns) / NS_PER_S


def find_gaps(measured: Mapping[str, Series], factor: float = GAP_FACTOR) -> tuple[Gap, ...]:
    """Intervals where the measured outputs pause for more than ``factor`` median periods;
    overlapping pauses of several signals make one gap."""
    found: list[tuple[int, int, int, str]] = []
    for role, s in measured.items():
        if len(s) < 3:
            continue
        d = np.diff(s.t_ns)
        period = float(np.median(d))
        if period <= 0:
            continue
        for k in np.nonzero(d > factor * period)[0].tolist():
            found.append((int(s.t_ns[k]), int(s.t_ns[k + 1]), round(d[k] / period) - 1, role))
    found.sort()
    merged: list[Gap] = []
    for start, end, missing, role in found:
        if merged and start < merged[-1].end_ns:
            g = merged[-1]
            roles = g.roles if role in g.roles else (*g.roles, role)
            merged[-1] = Gap(min(g.start_ns, start), max(g.end_ns, end), max(g.missing, missing), roles)
        else:
            merged.append(Gap(start, end, missing, (role,)))
    return tuple(merged)


@dataclass(frozen=True)
class Recording:
    """What the replay drives the model with and compares it against.

    ``inputs`` holds the duty command (always) and the load flow / supply pressure when the
    bag has them; ``measured`` the outputs present (at least one). ``start_ns`` is the absolute
    bag time of replay time 0. ``gaps``: where the measured outputs pause (:func:`find_gaps`).
    """

    path: Path
    start_ns: int
    topics: Mapping[str, str]
    inputs: Mapping[str, Series]
    measured: Mapping[str, Series]
    closed_cleanly: bool
    warnings: tuple[str, ...] = ()
    notes: tuple[str, ...] = field(default=())
    gaps: tuple[Gap, ...] = ()

    @property
    def duty(self) -> Series:
        return self.inputs[DUTY_CYCLE]

    @property
    def end_ns(self) -> int:
        """The last measured sample (relative ns): the replay's end."""
        return int(max(int(s.t_ns[-1]) for s in self.measured.values()))


def parse_topic_map(items: list[str] | None) -> dict[str, str]:
    """``["pressure=/rig/p", "duty=/rig/cmd"]`` -> ``{"pressure": "/rig/p", "duty_cycle": ...}``."""
    out: dict[str, str] = {}
    accepted = ", ".join(ROLES) + f" (aliases: {', '.join(sorted(ROLE_ALIASES))})"
    for item in items or []:
        role_name, sep, topic = item.partition("=")
        role = role_of(role_name)
        if not sep or not topic.strip():
            msg = f"--topic {item!r}: expected ROLE=/topic, e.g. pressure=/rig/p; roles: {accepted}"
            raise ReplayError(msg)
        if role is None:
            msg = f"--topic {item!r}: unknown role {role_name!r}; roles: {accepted}"
            raise ReplayError(msg)
        topic = topic.strip()
        if not topic.startswith("/"):
            topic = "/" + topic
        if role in out and out[role] != topic:
            msg = f"--topic gives two topics for {role}: {out[role]!r} and {topic!r}"
            raise ReplayError(msg)
        out[role] = topic
    return out


def _listing(types: Mapping[str, str]) -> str:
    return ", ".join(f"{t} ({ty})" for t, ty in sorted(types.items())) or "none"


def device_namespaces(types: Mapping[str, str]) -> list[str]:
    """The namespaces of a bag that hold a device's duty command and an output (``/left``,
    ``/rig/right``; ``/`` for the root namespace), sorted."""
    by_ns: dict[str, set[str]] = {}
    for topic in types:
        ns, _, last = topic.rpartition("/")
        if last in ROLES:
            by_ns.setdefault(ns or "/", set()).add(last)
    return sorted(ns for ns, roles in by_ns.items() if DUTY_CYCLE in roles and roles & set(OUTPUT_ROLES))


def _select_namespace(namespace: str, types: Mapping[str, str]) -> str:
    """The device namespace of the bag `namespace` names: itself, or the one ending in it."""
    found = device_namespaces(types)
    want = "/" + namespace.strip().strip("/")
    if want in found:
        return want
    ending = [ns for ns in found if ns.endswith(want)]
    if len(ending) == 1:
        return ending[0]
    listed = ", ".join(found) or "none"
    if ending:
        msg = f"--namespace {namespace!r} matches several devices in the bag: {', '.join(ending)}; give the full one"
    else:
        msg = (f"--namespace {namespace!r}: no device (a duty_cycle and an output topic) in that namespace; "
               f"the bag's device namespaces: {listed}")
    raise ReplayError(msg)


def _resolve(
    role: str, types: Mapping[str, str], topic_map: Mapping[str, str], notes: list[str],
    namespace: str | None = None,
) -> str | None:
    """The topic that carries `role`, or None when the bag has none (only the default search)."""
    if role in topic_map:
        topic = topic_map[role]
        if topic not in types:
            msg = (
                f"--topic {role}={topic}: topic {topic!r} is not in the bag; topics in the bag: "
                f"{_listing(types)}"
            )
            raise ReplayError(msg)
        return topic
    if namespace is not None:
        topic = bag_topic(role, namespace)
        return topic if topic in types else None
    default = bag_topic(role)
    if default in types:
        return default
    suffix = "/" + role
    candidates = sorted(t for t in types if t.endswith(suffix))
    if len(candidates) == 1:
        notes.append(f"{role}: using {candidates[0]} (no {default} in the bag)")
        return candidates[0]
    if len(candidates) > 1:
        namespaces = device_namespaces(types)
        msg = (
            f"several topics could be the {role}: {candidates}; choose one with --topic "
            f"{role}={candidates[0]}, or a device with --namespace NS (the bag's device namespaces: "
            f"{', '.join(namespaces) or 'none'})"
        )
        raise ReplayError(msg)
    return None


def _check_type(role: str, topic: str, types: Mapping[str, str]) -> None:
    msgtype = types[topic]
    if msgtype not in DECODABLE_TYPES:
        msg = (
            f"{role}: topic {topic!r} has message type {msgtype!r}, which replay cannot read; "
            f"accepted types: {', '.join(DECODABLE_TYPES)} (expected {ROLE_TYPES[role]})"
        )
        raise ReplayError(msg)


def _times(role: str, ts: TopicSeries, notes: list[str]) -> npt.NDArray[np.int64]:
    """Sample times: the header stamp for FluidPressure (the sample time), else the log time."""
    stamps = ts.stamp_ns
    if ts.msgtype != FLUID_PRESSURE or stamps is None or len(stamps) == 0:
        return ts.t_ns.astype(np.int64)
    if np.any((stamps <= 0) & (ts.t_ns != stamps)):
        notes.append(f"{role}: {ts.topic} has unset header stamps; using the bag's log times")
        return ts.t_ns.astype(np.int64)
    offset = np.median(stamps - ts.t_ns)
    if abs(offset) > _STAMP_OFFSET_NOTE_NS:
        notes.append(
            f"{role}: header stamps of {ts.topic} differ from the bag's log times by "
            f"{offset / 1e6:+.3f} ms (median); using the stamps (the sample times)"
        )
    return stamps.astype(np.int64)


def _check_order(role: str, topic: str, t: npt.NDArray[np.int64], strict: bool) -> None:
    d = np.diff(t)
    bad = np.nonzero(d < 0 if not strict else d <= 0)[0]
    if bad.size:
        k = int(bad[0])
        what = "goes backwards" if d[k] < 0 else "repeats"
        msg = (
            f"{role}: time {what} on {topic} at message {k + 1} (0-based, in bag order): "
            f"{t[k]} ns -> {t[k + 1]} ns ({(t[k + 1] - t[k]) / 1e6:+.6f} ms); "
            f"{bad.size} such place(s) in all; replay needs "
            f"{'strictly increasing' if strict else 'non-decreasing'} sample times"
        )
        raise ReplayError(msg)


def _check_finite(role: str, topic: str, values: npt.NDArray[np.float64]) -> None:
    bad = np.nonzero(~np.isfinite(values))[0]
    if bad.size:
        msg = (
            f"{role}: {bad.size} non-finite value(s) on {topic}, first at message {int(bad[0])} "
            f"({values[bad[0]]!r}); replay needs finite values"
        )
        raise ReplayError(msg)


def load_recording(
    path: str | os.PathLike[str], topic_map: Mapping[str, str] | None = None, *, namespace: str | None = None
) -> Recording:
    """Read a bag for replay; `namespace` selects one device of several (see the module docstring).

    Raises:
        BagError: not a bag, unreadable (from :func:`pcv_sim.io.read_bag`).
        ReplayError: no duty command or no output to compare, a topic of a type replay cannot
            read, time going backwards, non-finite values, duty outside 0..1, a namespace that
            is not a device of the bag (naming those found).
    """
    mapping = dict(topic_map or {})
    for role in mapping:
        if role not in ROLES:
            msg = f"unknown role {role!r} in the topic map; roles: {', '.join(ROLES)}"
            raise ReplayError(msg)
    contents: BagContents = read_bag(path)
    types = contents.topic_types
    notes: list[str] = []
    topics: dict[str, str] = {}
    ns = _select_namespace(namespace, types) if namespace is not None else None
    for role in ROLES:
        topic = _resolve(role, types, mapping, notes, ns)
        if topic is not None:
            topics[role] = topic
    if DUTY_CYCLE not in topics:
        msg = (
            f"no duty command in {str(path)!r}: no topic {bag_topic(DUTY_CYCLE)!r} (or */"
            f"{DUTY_CYCLE}); topics in the bag: {_listing(types)}; map yours with "
            f"--topic duty_cycle=/your/topic"
        )
        raise ReplayError(msg)
    if not any(r in topics for r in OUTPUT_ROLES):
        expected = ", ".join(bag_topic(r) for r in OUTPUT_ROLES)
        msg = (
            f"nothing to compare in {str(path)!r}: none of {expected} is in the bag; topics in "
            f"the bag: {_listing(types)}; map yours with e.g. --topic pressure=/rig/p"
        )
        raise ReplayError(msg)
    for role, topic in topics.items():
        _check_type(role, topic, types)
    for role in (*OUTPUT_ROLES, LOAD_FLOW, SUPPLY_PRESSURE):
        if role not in topics:
            what = "not compared" if role in OUTPUT_ROLES else "the model uses the configured value"
            notes.append(f"{role}: no topic {bag_topic(role)} in the bag; {what}")

    raw: dict[str, tuple[npt.NDArray[np.int64], npt.NDArray[np.float64]]] = {}
    for role, topic in topics.items():
        ts = contents.topics[topic]
        if len(ts) == 0:
            if role in (DUTY_CYCLE,):
                msg = f"duty_cycle: topic {topic!r} holds no readable message"
                raise ReplayError(msg)
            notes.append(f"{role}: {topic} holds no readable message; not used")
            continue
        t = _times(role, ts, notes)
        v = np.asarray(ts.value, dtype=np.float64)
        _check_order(role, topic, t, strict=role in OUTPUT_ROLES)
        _check_finite(role, topic, v)
        raw[role] = (t, v)
    if not any(r in raw for r in OUTPUT_ROLES):
        msg = f"nothing to compare in {str(path)!r}: the output topics hold no readable message"
        raise ReplayError(msg)

    t_duty, duty = raw[DUTY_CYCLE]
    out_of_range = np.nonzero((duty < 0.0) | (duty > 1.0))[0]
    if out_of_range.size:
        k = int(out_of_range[0])
        hint = " (percent? the duty is a fraction 0..1)" if 2.0 <= duty[k] <= 100.0 else ""
        msg = (
            f"duty_cycle: {out_of_range.size} value(s) on {topics[DUTY_CYCLE]} outside 0..1, "
            f"first {duty[k]:g} at message {k}{hint}"
        )
        raise ReplayError(msg)

    start = int(t_duty[0])
    inputs: dict[str, Series] = {}
    measured: dict[str, Series] = {}
    for role, (t, values) in raw.items():
        rel, v = t - start, values
        if role in INPUT_ROLES:
            if role != DUTY_CYCLE:
                before = np.nonzero(rel <= 0)[0]
                if before.size:  # the latest value at or before time 0 holds from time 0
                    keep = int(before[-1])
                    if keep:
                        notes.append(
                            f"{role}: {keep} message(s) before the first duty command "
                            f"superseded; the last one holds from time 0"
                        )
                    rel, v = rel[keep:].copy(), v[keep:]
                    rel[0] = max(int(rel[0]), 0)
            inputs[role] = Series(role, topics[role], rel.astype(np.int64), v)
        else:
            early = int(np.count_nonzero(rel < 0))
            if early:
                notes.append(
                    f"{role}: {early} sample(s) before the first duty command not compared "
                    f"(the model starts at rest at the first command)"
                )
            measured[role] = Series(role, topics[role], rel[early:].astype(np.int64), v[early:])
            if len(measured[role]) == 0:
                del measured[role]
    if not measured:
        msg = (
            f"nothing to compare in {str(path)!r}: every output sample lies before the first "
            f"duty command on {topics[DUTY_CYCLE]}"
        )
        raise ReplayError(msg)
    gaps = find_gaps(measured)
    return Recording(
        path=Path(path),
        start_ns=start,
        topics=dict(topics),
        inputs=inputs,
        measured=measured,
        closed_cleanly=contents.closed_cleanly,
        warnings=contents.warnings,
        notes=tuple(notes),
        gaps=gaps,
    )
