"""Assertions of a scenario: what each kind checks, its validation, and its outcomes on a run.

Values take units (`pcv_sim.units`: `180 bar`, `0.5 mm`, `60 ms`; a bare number is SI); a window
is `after`/`before` (s), either also `{event: fault, delay: 0.2}` (the first timeline event of
that kind, `fault | clear | force | duty | supply`, or a fault's kind such as `coil_open`; `delay`
s after it). `measured: true` checks what the controller saw.

    max_error      |signal - reference| <= max in the window (reference: a signal or a value)
    within_band    the same, drawn as the band reference +- tolerance
    never_above    signal <= max in the window
    never_below    signal >= min in the window
    flag_within    controller.<flag> raised within `within` s after `at` (a time or an event), never before
    step_response  the step of `reference` (default setpoint) at `at`: each limit given of
                   rise_time (10 % -> 90 % of the step), overshoot (a fraction: `10 %`),
                   settling_time (from `at` until the signal stays within `band` of the final
                   reference: `2 %` of the step (default) or a value), steady_state_error (the
                   mean |error| over the window's last 5 %); the window ends at `before` or the
                   reference's next change
    baseline       the run against an earlier one (`file`: a bag directory, a --csv directory,
                   or a --json file): `signals: {name: {nrmse: 2 %, max_error: 0.5 mm}}`
                   compares signals (NRMSE: RMS error / the baseline's range); with a JSON
                   file, `tolerance` (a fraction of each limit) lets an assertion's margin
                   shrink at most that much against the baseline's

Every outcome has its value, limit, margin (positive: inside the limit, in the limit's unit) and
the time of its worst point.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pcv_sim.errors import ParameterError, PcvSimError
from pcv_sim.keys import check_keys, closest
from pcv_sim.params import check_mapping, check_value, declarations, non_empty, one_of, parameter, read, refused_as
from pcv_sim.rig.lockstep import RigRun
from pcv_sim.rig.rig import signal_kind

__all__ = ["ASSERTION_TYPES", "EVENTS", "AssertionKeys", "BaselineSignalKeys", "EventKeys", "Outcome",
           "check_assertions", "outcome_kind", "outcomes", "signal_kind"]

ASSERTION_TYPES = ("max_error", "within_band", "never_above", "never_below", "flag_within", "step_response",
                   "baseline")
EVENTS = ("fault", "clear", "force", "duty", "supply")
_WINDOW = ("after", "before")
_COMMON = ("type", "name", "signal", "measured")
KEYS: dict[str, tuple[str, ...]] = {
    "max_error": (*_COMMON, "reference", "max", *_WINDOW),
    "within_band": (*_COMMON, "reference", "tolerance", *_WINDOW),
    "never_above": (*_COMMON, "max", *_WINDOW),
    "never_below": (*_COMMON, "min", *_WINDOW),
    "flag_within": ("type", "name", "signal", "at", "within"),
    "step_response": (*_COMMON, "reference", "at", "before", "rise_time", "overshoot", "settling_time", "band",
                      "steady_state_error"),
    "baseline": ("type", "name", "file", "signals", "tolerance", "measured", *_WINDOW),
}
_STEP_LIMITS = ("rise_time", "overshoot", "settling_time", "steady_state_error")
_EPS = 1e-12


class AssertionSpecError(ParameterError):
    """An assertion that cannot be checked as written (the scenario loader names its path)."""


# --- the keys of an assertion, declared once (pcv_sim.params; kind value: the signal's unit) ------

_TIME_OR_EVENT = "a time (s, or with a unit) or {event, delay}"


@dataclass(frozen=True, kw_only=True)
class AssertionKeys:
    """Every key of an assertion; `KEYS` says which a type takes."""

    type: str = parameter("-", "what it checks: " + " | ".join(ASSERTION_TYPES), one_of(*ASSERTION_TYPES), kind="str")
    name: str | None = parameter("-", "its name in reports (default: its type and signal)", non_empty, kind="str",
                                 default=None)
    signal: str | None = parameter("-", "the signal checked (step_response: default cylinder.position)", kind="str",
                                   default=None)
    measured: bool = parameter("-", "check what the controller saw (sensor faults applied)", kind="bool",
                               default=False)
    reference: Any = parameter("-", "a signal, or a value in the signal's unit (default: setpoint)", kind="any",
                               default=None)
    max: float | None = parameter("-", "the limit: of max_error's |signal - reference|, of never_above's signal",
                                  kind="value", default=None)
    min: float | None = parameter("-", "never_below's limit", kind="value", default=None)
    tolerance: float | None = parameter("-", "within_band: the band's half width; baseline with a --json file: the "
                                        "margin each assertion may lose, a fraction of its limit", kind="value",
                                        default=None)
    after: Any = parameter("s", f"the window's start: {_TIME_OR_EVENT}", kind="any", default=None)
    before: Any = parameter("s", f"the window's end: {_TIME_OR_EVENT}", kind="any", default=None)
    at: Any = parameter("s", f"flag_within's event, step_response's step: {_TIME_OR_EVENT}", kind="any", default=None)
    within: float | None = parameter("s", "flag_within: the flag raised at most this long after `at`", kind="time",
                                     default=None)
    rise_time: float | None = parameter("s", "step_response: 10 % -> 90 % of the step at most", kind="time",
                                        default=None)
    overshoot: float | None = parameter("-", "step_response: beyond the step at most (a fraction: 10 %)",
                                        kind="fraction", default=None)
    settling_time: float | None = parameter("s", "step_response: from `at` until the signal stays within `band`",
                                            kind="time", default=None)
    band: Any = parameter("-", "step_response's settling band: a percentage of the step (2 %, the default) or a value",
                          kind="any", default=None)
    steady_state_error: float | None = parameter("-", "step_response: mean |error| over the window's last 5 % at most",
                                                 kind="value", default=None)
    file: str | None = parameter("-", "baseline: a bag directory, a --csv directory or a --json file of an earlier "
                                 "run, relative to the scenario", kind="str", default=None)
    signals: Mapping[str, Any] | None = parameter("-", "baseline: signal -> {nrmse, max_error}", non_empty,
                                                  kind="mapping", default=None)


@dataclass(frozen=True, kw_only=True)
class EventKeys:
    """A time on the timeline: `{event: fault, delay: 200 ms}`."""

    event: str = parameter("-", f"the first timeline event of this kind ({' | '.join(EVENTS)}) or of this fault",
                           kind="str")
    delay: float = parameter("s", "after the event", kind="time", default=0.0)


@dataclass(frozen=True, kw_only=True)
class BaselineSignalKeys:
    """A signal compared with the baseline's (either or both)."""

    nrmse: float | None = parameter("-", "RMS error / the baseline's range at most (a fraction: 2 %)", kind="fraction",
                                    default=None)
    max_error: float | None = parameter("-", "|signal - baseline| at most, in the signal's unit", kind="value",
                                        default=None)


_KEY = declarations(AssertionKeys)


@dataclass(frozen=True)
class Outcome:
    """One checked limit: `value` found, `limit` asked (SI of the signal, or s), `margin` how far
    inside (+) or beyond (-) the limit, `time` the worst point's (s; None: no such point).
    `draw` says how the report draws it (signal, window, band or line)."""

    name: str
    passed: bool
    value: float
    limit: float
    detail: str
    margin: float = math.nan
    time: float | None = None
    kind: str = ""
    signal: str = ""
    draw: Mapping[str, Any] = field(default_factory=dict)


def outcome_kind(o: Outcome) -> str:
    """The kind of an outcome's value, limit and margin."""
    tail = o.name.rsplit(" ", 1)[-1]
    if o.kind == "flag_within" or tail.endswith(("rise_time", "settling_time")):
        return "time"
    if tail.endswith(("overshoot", "nrmse")):
        return "fraction"
    return signal_kind(o.signal) if o.signal else "number"


# --- validation -------------------------------------------------------------------------------


def event_time(where: str, raw: Any, events: list[tuple[float, str, str]]) -> float:
    """A time: a value (s, or with a unit) or `{event: KIND, delay: D}` resolved on the timeline
    (`events`: (t, kind, fault kind or '') in time order)."""
    if not isinstance(raw, Mapping):
        return float(check_value(where, declarations(EventKeys)["delay"].metadata, raw))
    check_mapping(EventKeys, raw, where)
    ev = read(EventKeys, raw, "event", where)
    delay = read(EventKeys, raw, "delay", where)
    kinds = {k for _, k, _ in events} | {f for _, _, f in events if f}
    for t, k, f in events:
        if ev in (k, f):
            return float(t + delay)
    near = closest(ev, [*EVENTS, *kinds])
    raise AssertionSpecError(f"{where}.event: {ev!r} is not on the timeline{f' (did you mean {near!r}?)' if near else ''}; "
                             f"accepted are {', '.join(EVENTS)} or a fault's kind, of an event the timeline has "
                             f"({', '.join(sorted(kinds)) or 'none'})")


@refused_as(AssertionSpecError)
def normalize(where: str, raw: Any, *, signals: tuple[str, ...], has_setpoint: bool,
              events: list[tuple[float, str, str]], base: Path | None) -> dict[str, Any]:
    """The assertion with its values in SI and event times resolved; AssertionSpecError naming
    the key and what is accepted."""
    if not isinstance(raw, Mapping):
        raise AssertionSpecError(f"{where}: got {raw!r}; accepted is a mapping {{type: {' | '.join(ASSERTION_TYPES)}, "
                                 "...}")
    kind = raw.get("type")
    if kind not in KEYS:
        near = closest(kind, ASSERTION_TYPES)
        raise AssertionSpecError(f"{where}.type: got {kind!r}{f' (did you mean {near!r}?)' if near else ''}; accepted "
                                 f"are {', '.join(ASSERTION_TYPES)}")
    check_keys(where, raw, KEYS[kind])
    out: dict[str, Any] = dict(raw)
    known = signals if has_setpoint else tuple(s for s in signals if s != "setpoint")

    def check_signal(key: str, sig: Any, *, flags: bool = True) -> str:
        if isinstance(sig, str) and (sig in known or (flags and sig.startswith("controller."))):
            return sig
        near = closest(sig, known)
        extra = " and controller.<flag>" if flags else ""
        no_sp = " (the scenario has no setpoint)" if sig == "setpoint" else ""
        raise AssertionSpecError(f"{where}.{key}: got {sig!r}{no_sp}{f' (did you mean {near!r}?)' if near else ''}; "
                                 f"accepted are {', '.join(known)}{extra}")

    sk = "number"
    if kind != "baseline":
        default = "cylinder.position" if kind == "step_response" else None
        if "signal" not in raw and default is None:
            raise AssertionSpecError(f"{where}: {kind} needs signal")
        out["signal"] = sig = check_signal("signal", raw.get("signal", default))
        sk = signal_kind(sig)
    for key in (*_WINDOW, "at"):
        if key in raw:
            out[key] = event_time(f"{where}.{key}", raw[key], events)
    for key in ("name", "measured", "within", "rise_time", "settling_time", "overshoot"):
        if key in raw:
            out[key] = read(AssertionKeys, raw, key, where)
    need = {"max_error": ("reference", "max"), "within_band": ("reference", "tolerance"), "never_above": ("max",),
            "never_below": ("min",), "flag_within": ("at", "within"), "step_response": ("at",),
            "baseline": ("file",)}[kind]
    for key in need:
        if key not in raw:
            raise AssertionSpecError(f"{where}: {kind} needs {key}")
    for key in ("max", "min", "tolerance", "steady_state_error"):
        if key in raw and kind != "baseline":
            out[key] = read(AssertionKeys, raw, key, where, of=sk)
    if kind in ("max_error", "within_band", "step_response"):
        ref = raw.get("reference", "setpoint")
        if isinstance(ref, str) and not ref[:1].isdigit() and not ref.startswith(("-", "+", ".")):
            out["reference"] = check_signal("reference", ref, flags=False)
        else:
            out["reference"] = check_value(f"{where}.reference", _KEY["max"].metadata, ref, of=sk)
    if kind == "step_response":
        if not any(k in raw for k in _STEP_LIMITS):
            raise AssertionSpecError(f"{where}: step_response needs at least one of {', '.join(_STEP_LIMITS)}")
        band = raw.get("band", "2 %")
        if isinstance(band, str) and band.strip().endswith("%"):
            out["band"] = ("fraction", check_value(f"{where}.band", _KEY["overshoot"].metadata, band))
        else:
            out["band"] = ("value", check_value(f"{where}.band", _KEY["max"].metadata, band, of=sk))
    if kind == "baseline":
        _baseline_spec(where, raw, out, known, base)
    return out


def _baseline_spec(where: str, raw: Mapping[str, Any], out: dict[str, Any], known: tuple[str, ...],
                   base: Path | None) -> None:
    f = read(AssertionKeys, raw, "file", where)
    p = (base / str(f)) if base is not None else Path(str(f))
    if not p.exists():
        raise AssertionSpecError(f"{where}.file: {p} does not exist; accepted is a bag directory, a --csv directory or "
                                 "a --json file of an earlier run")
    out["file"] = p
    if p.suffix == ".json":
        if raw.get("signals") is not None:
            raise AssertionSpecError(f"{where}.signals: a --json baseline holds assertion values, not signals; "
                                     "accepted is tolerance (a fraction of each limit)")
        out["tolerance"] = check_value(f"{where}.tolerance", _KEY["tolerance"].metadata, raw.get("tolerance", 0.0),
                                       of="fraction")
        return
    if raw.get("signals") is None:
        raise AssertionSpecError(f"{where}.signals: missing; accepted is a mapping {_KEY['signals'].metadata['description']}")
    sigs = read(AssertionKeys, raw, "signals", where)
    spec: dict[str, dict[str, float]] = {}
    for sig, tol in sigs.items():
        w = f"{where}.signals.{sig}"
        if sig not in known and not str(sig).startswith("controller."):
            near = closest(sig, known)
            raise AssertionSpecError(f"{w}: no signal {sig!r}{f' (did you mean {near!r}?)' if near else ''}; accepted "
                                     f"are {', '.join(known)}")
        check_mapping(BaselineSignalKeys, tol, w)
        if not tol:
            raise AssertionSpecError(f"{w}: got {tol!r}; accepted is nrmse (a fraction) and/or max_error (a value)")
        spec[str(sig)] = {k: read(BaselineSignalKeys, tol, k, w, of=signal_kind(str(sig))) for k in tol}
    out["signals"] = spec


# --- checking ---------------------------------------------------------------------------------


def _window(t: np.ndarray, a: Mapping[str, Any]) -> np.ndarray:
    mask = np.ones(len(t), bool)
    if "after" in a:
        mask &= t >= float(a["after"]) - _EPS
    if "before" in a:
        mask &= t <= float(a["before"]) + _EPS
    return mask


def _span(t: np.ndarray, mask: np.ndarray) -> dict[str, float]:
    idx = np.flatnonzero(mask)
    return {"t0": float(t[idx[0]]), "t1": float(t[idx[-1]])} if len(idx) else {}


def _signal(run: RigRun, name: str, measured: bool) -> np.ndarray | None:
    try:
        return run.signal(name, measured=measured)
    except KeyError:
        return None


def outcomes(run: RigRun, a: Mapping[str, Any], *, next_change: Callable[[float], float] | None = None
             ) -> list[Outcome]:
    """The outcomes of one (normalized) assertion on `run`: one per limit it sets."""
    kind = a["type"]
    if kind == "baseline":
        return _baseline(run, a)
    sig = a["signal"]
    measured = bool(a.get("measured", False))
    name = a.get("name") or f"{kind} {sig}"
    t = run.times

    def fail(detail: str, limit: float = math.nan) -> list[Outcome]:
        return [Outcome(name, False, math.nan, limit, detail, kind=kind, signal=sig)]

    if kind == "flag_within":
        return [_flag_within(run, a, name)]
    y = _signal(run, sig, measured)
    if y is None:
        return fail(f"no signal {sig} in the run (a flag the controller never reported)")
    if kind == "step_response":
        return _step_response(run, a, name, y, next_change)
    mask = _window(t, a) & np.isfinite(y)
    if not np.any(mask):
        return fail("no samples in the window")
    idx = np.flatnonzero(mask)
    if kind in ("max_error", "within_band"):
        ref = a["reference"]
        r = np.full(len(t), float(ref)) if isinstance(ref, (int, float)) else run.signal(ref, measured=measured)
        lim = float(a["max"] if kind == "max_error" else a["tolerance"])
        err = np.abs(y - r)[mask]
        j = int(np.argmax(err))
        worst, k = float(err[j]), int(idx[j])
        draw = {"signal": sig, "reference": ref, "tolerance": lim, **_span(t, mask)}
        return [Outcome(name, worst <= lim, worst, lim, f"|{sig} - {ref}| at most {worst:.6g} (at {t[k]:.4f} s), "
                        f"limit {lim:g}", lim - worst, float(t[k]), kind, sig, draw)]
    if kind == "never_above":
        lim = float(a["max"])
        j = int(np.argmax(y[mask]))
        worst, k = float(y[mask][j]), int(idx[j])
        return [Outcome(name, worst <= lim, worst, lim, f"{sig} at most {worst:.6g} (at {t[k]:.4f} s), limit {lim:g}",
                        lim - worst, float(t[k]), kind, sig, {"signal": sig, "hi": lim, **_span(t, mask)})]
    lim = float(a["min"])
    j = int(np.argmin(y[mask]))
    worst, k = float(y[mask][j]), int(idx[j])
    return [Outcome(name, worst >= lim, worst, lim, f"{sig} at least {worst:.6g} (at {t[k]:.4f} s), limit {lim:g}",
                    worst - lim, float(t[k]), kind, sig, {"signal": sig, "lo": lim, **_span(t, mask)})]


def _flag_within(run: RigRun, a: Mapping[str, Any], name: str) -> Outcome:
    sig, t = a["signal"], run.times
    at, within = float(a["at"]), float(a["within"])
    draw = {"signal": sig, "at": at, "deadline": at + within}
    flag = run.flags.get(sig)
    if flag is None:
        return Outcome(name, False, math.nan, within, f"the controller never reported {sig}", kind="flag_within",
                       signal=sig, draw=draw)
    raised = np.nan_to_num(flag, nan=0.0) != 0.0
    early = raised & (t < at - _EPS)
    if np.any(early):
        te = float(t[np.argmax(early)])
        return Outcome(name, False, te - at, within, f"{sig} raised at {te:.4f} s, before the event at {at:g} s",
                       te - at, te, "flag_within", sig, draw)
    late = raised & (t >= at - _EPS)
    if not np.any(late):
        return Outcome(name, False, math.inf, within, f"{sig} never raised after {at:g} s", -math.inf, at + within,
                       "flag_within", sig, draw)
    delay = float(t[np.argmax(late)] - at)
    return Outcome(name, delay <= within + _EPS, delay, within,
                   f"{sig} raised {delay * 1e3:.1f} ms after {at:g} s (limit {within * 1e3:g} ms)", within - delay,
                   at + delay, "flag_within", sig, draw)


def _step_response(run: RigRun, a: Mapping[str, Any], name: str, y: np.ndarray,
                   next_change: Callable[[float], float] | None) -> list[Outcome]:
    sig, t = a["signal"], run.times
    measured = bool(a.get("measured", False))
    at = float(a["at"])
    ref = a["reference"]
    r = np.full(len(t), float(ref)) if isinstance(ref, (int, float)) else run.signal(ref, measured=measured)
    end = float(a["before"]) if "before" in a else (next_change(at) if next_change else math.inf)
    mask = (t >= at - _EPS) & (t < end - _EPS) & np.isfinite(y)
    pre = np.flatnonzero((t < at - _EPS) & np.isfinite(r))
    idx = np.flatnonzero(mask)
    base = {"kind": "step_response", "signal": sig}
    if len(idx) < 2 or not len(pre):
        return [Outcome(f"{name}: {lim}", False, math.nan, float(a[lim]), "no samples before or after the step",
                        **base) for lim in _STEP_LIMITS if lim in a]
    r0, r1 = float(r[pre[-1]]), float(r[idx[-1]])
    step = r1 - r0
    if step == 0.0:
        return [Outcome(f"{name}: {lim}", False, math.nan, float(a[lim]),
                        f"the reference does not step at {at:g} s (stays {r0:g})", **base) for lim in _STEP_LIMITS
                if lim in a]
    tw, yw = t[idx], y[idx]
    rel = (yw - r0) / step                       # 0 before, 1 at the final value
    mode, b = a["band"]
    band = abs(step) * b if mode == "fraction" else b
    out = []
    span = {"t0": float(tw[0]), "t1": float(tw[-1])}
    if "rise_time" in a:
        lim = float(a["rise_time"])
        i10 = np.flatnonzero(rel >= 0.1)
        i90 = np.flatnonzero(rel >= 0.9)
        if len(i90) == 0:
            out.append(Outcome(f"{name}: rise_time", False, math.inf, lim, f"{sig} never reached 90 % of the step",
                               -math.inf, float(tw[-1]), **base, draw={"signal": sig, "at": at, "deadline": at + lim}))
        else:
            v = float(tw[i90[0]] - tw[i10[0]])
            out.append(Outcome(f"{name}: rise_time", v <= lim + _EPS, v, lim,
                               f"10-90 % rise time {v * 1e3:.1f} ms (limit {lim * 1e3:g} ms)", lim - v,
                               float(tw[i90[0]]), **base, draw={"signal": sig, "at": at, "deadline": float(tw[i10[0]]) + lim}))
    if "overshoot" in a:
        lim = float(a["overshoot"])
        j = int(np.argmax(rel))
        v = max(0.0, float(rel[j]) - 1.0)
        out.append(Outcome(f"{name}: overshoot", v <= lim + _EPS, v, lim,
                           f"overshoot {v * 100:.2f} % of the {abs(step):.4g} step (limit {lim * 100:g} %)", lim - v,
                           float(tw[j]), **base, draw={"signal": sig, "hi" if step > 0 else "lo": r1 + lim * step,
                                                        **span}))
    if "settling_time" in a:
        lim = float(a["settling_time"])
        outside = np.flatnonzero(np.abs(yw - r1) > band)
        if len(outside) and outside[-1] == len(yw) - 1:
            v, tv = math.inf, float(tw[-1])
            text = f"{sig} not within +-{band:.4g} of {r1:.4g} at the window's end ({tw[-1]:.4f} s)"
        else:
            tv = float(tw[outside[-1] + 1]) if len(outside) else float(tw[0])
            v = tv - at
            text = f"settled within +-{band:.4g} after {v * 1e3:.1f} ms (limit {lim * 1e3:g} ms)"
        out.append(Outcome(f"{name}: settling_time", v <= lim + _EPS, v, lim, text, lim - v, tv, **base,
                           draw={"signal": sig, "reference": r1, "tolerance": band, "t0": at + lim, "t1": span["t1"],
                                 "deadline": at + lim}))
    if "steady_state_error" in a:
        lim = float(a["steady_state_error"])
        n = max(1, len(yw) // 20)
        v = float(abs(np.mean(yw[-n:]) - r1))
        out.append(Outcome(f"{name}: steady_state_error", v <= lim, v, lim,
                           f"mean |error| over the last {n} samples {v:.4g} (limit {lim:g})", lim - v,
                           float(tw[-1]), **base, draw={"signal": sig, "reference": r1, "tolerance": lim,
                                                        "t0": float(tw[-n]), "t1": float(tw[-1])}))
    return out


def _baseline(run: RigRun, a: Mapping[str, Any]) -> list[Outcome]:
    from pcv_sim.rig.record import read_signals

    p: Path = a["file"]
    name = a.get("name") or f"baseline {p.name}"
    if p.suffix == ".json":
        return [Outcome(name, False, math.nan, math.nan, "a --json baseline compares assertions: see "
                        "check_assertions", kind="baseline")]
    measured = bool(a.get("measured", False))
    try:
        base = read_signals(p)
    except (PcvSimError, OSError) as err:
        return [Outcome(name, False, math.nan, math.nan, f"cannot read the baseline {p}: {err}", kind="baseline")]
    out = []
    t = run.times
    mask = _window(t, a)
    for sig, tols in a["signals"].items():
        y = _signal(run, sig, measured)
        if y is None or sig not in base:
            missing = "this run" if y is None else f"the baseline ({', '.join(sorted(base))})"
            out += [Outcome(f"{name}: {sig} {k}", False, math.nan, v, f"no {sig} in {missing}", kind="baseline",
                            signal=sig) for k, v in tols.items()]
            continue
        tb, yb = base[sig]
        inside = mask & np.isfinite(y) & (t >= tb[0] - _EPS) & (t <= tb[-1] + _EPS)
        if not np.any(inside):
            out += [Outcome(f"{name}: {sig} {k}", False, math.nan, v, "no common samples with the baseline",
                            kind="baseline", signal=sig) for k, v in tols.items()]
            continue
        ok = np.isfinite(yb)
        ref = np.interp(t[inside], tb[ok], yb[ok])
        diff = np.abs(y[inside] - ref)
        j = int(np.argmax(diff))
        tw = float(t[inside][j])
        draw = {"signal": sig, "baseline": (tb, yb)}
        if "max_error" in tols:
            lim = tols["max_error"]
            v = float(diff[j])
            out.append(Outcome(f"{name}: {sig} max_error", v <= lim, v, lim,
                               f"|{sig} - baseline| at most {v:.6g} (at {tw:.4f} s), limit {lim:g}", lim - v, tw,
                               "baseline", sig, draw))
        if "nrmse" in tols:
            lim = tols["nrmse"]
            rng = float(np.ptp(ref))
            rms = float(np.sqrt(np.mean(diff ** 2)))
            v = rms / rng if rng > 0 else (0.0 if rms == 0 else math.inf)
            out.append(Outcome(f"{name}: {sig} nrmse", v <= lim, v, lim,
                               f"NRMSE {v * 100:.3g} % of the baseline's range {rng:.4g} (limit {lim * 100:g} %); "
                               f"worst at {tw:.4f} s", lim - v, tw, "baseline", sig, draw))
    return out


def against_json(run_outcomes: list[Outcome], a: Mapping[str, Any]) -> list[Outcome]:
    """A --json baseline: each assertion of the same name may lose at most `tolerance` x |limit|
    of its margin against the baseline run's."""
    p: Path = a["file"]
    name = a.get("name") or f"baseline {p.name}"
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, ValueError) as e:
        return [Outcome(name, False, math.nan, math.nan, f"cannot read the baseline {p}: {e}", kind="baseline")]
    runs = data.get("scenarios", [data]) if isinstance(data, dict) else []
    old: dict[str, Mapping[str, Any]] = {}
    for r in runs:
        for o in r.get("assertions", []):
            old[o.get("name")] = o
    tol = float(a["tolerance"])
    out = []
    for o in run_outcomes:
        b = old.get(o.name)
        if b is None or not math.isfinite(o.margin) or not math.isfinite(float(b.get("margin", math.nan))):
            continue
        allowed = float(b["margin"]) - tol * abs(o.limit)
        out.append(Outcome(f"{name}: {o.name}", o.margin >= allowed, o.margin, allowed,
                           f"margin {o.margin:.6g} vs the baseline's {float(b['margin']):.6g} (at least {allowed:.6g})",
                           o.margin - allowed, o.time, "baseline", o.signal))
    if not out:
        out.append(Outcome(name, False, math.nan, math.nan, f"no assertion of this run in {p} (by name)",
                           kind="baseline"))
    return out


def check_assertions(run: RigRun, assertions: tuple[Mapping[str, Any], ...], *,
                     next_change: Callable[[float], float] | None = None) -> list[Outcome]:
    """Every outcome of every assertion (a --json baseline after the others, which it compares)."""
    out: list[Outcome] = []
    later = []
    for a in assertions:
        if a["type"] == "baseline" and Path(a["file"]).suffix == ".json":
            later.append(a)
        else:
            out += outcomes(run, a, next_change=next_change)
    for a in later:
        out += against_json(list(out), a)
    return out
