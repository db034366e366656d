"""Scenarios: a rig, a timeline, a controller and assertions in one YAML file; run in lockstep.

    name: step                       # optional (default: the file name)
    rig: ../config/rig.yaml          # relative to this file (default: the shipped config/rig.yaml)
    valves:                          # optional: valve YAML keys written over the rig's valve files
      fluid: {temperature: input}    # a section: every valve (here: the oil temperature an input, R34)
      left: {solenoid: {coil_temperature: lumped}}   # a valve's name: that valve only (wins over the above)
    duration: 2.0                    # s
    seed: 0                          # sensor noise
    controller: steering:PositionController   # `module:callable`; module.py beside this file or importable
    controller_params: {kp: 5.0}     # optional: a class is instantiated with them, a function called
                                     # with them to make the controller; without, a function is the controller;
                                     # checked on load when the callable has a check_params (PositionController)
    # or a ROS 2 controller node (pcv_sim.node.scenario_host): the runner hosts the rig node
    # (`ros2 run pcv_sim rig`) in lockstep in `namespace` and waits up to `wait` s for the node
    # to answer; `command`, if given, is started by the runner (in a ROS domain of its own, cwd
    # this file's folder; `{namespace}` and `{python}` are replaced) and stopped after the run
    # controller: {ros: {namespace: /rig, wait: 30,
    #                    command: ["{python}", -m, pcv_sim.node.steering_controller, --ros-args, -r, "__ns:={namespace}"]}}
    setpoint:                        # optional: each segment holds from its t until the next one's
      - {t: 0.0, value: 0 mm}
      - {t: 0.5, ramp: {to: 20 mm, duration: 200 ms}}                  # from the value before
      - {t: 1.0, sine: {amplitude: 20 mm, frequency: 1 Hz, offset: 0}}  # phase from t
      - {t: 3.0, chirp: {amplitude: 2 mm, from: 0.5 Hz, to: 10 Hz, duration: 5 s}}
      - {t: 8.0, table: [[0, 0 mm], [0.5 s, 5 mm], [1 s, 0 mm]]}         # times from t
      - {t: 9.0, file: {path: profile.csv, column: position, unit: mm}}
    timeline:                        # at the first step at or after t; each value a profile as above
      - {t: 0.1, duty: {left: 70 %}}                    # duty command(s), fraction
      - {t: 0.2, force: -1 kN}                          # external force on the rod, N (+ extends)
      - {t: 0.3, force: {ramp: {to: 500 N, duration: 100 ms}}}
      - {t: 0.4, supply: {right: {ramp: {to: 150 bar, duration: 50 ms}}}}   # supply pressure
      - {t: 0.0, oil_temperature: -20 degC}             # every valve with fluid.temperature: input (R34)
      - {t: 0.0, oil_temperature: {ramp: {to: 40 degC, duration: 60 s}}}  # a cold start warming up
      - {t: 1.0, ambient_temperature: {left: 0 degC}}   # a coil's ambient (solenoid.coil_temperature: lumped, R33)
      - {t: 0.5, fault: supply_drop, target: left, pressure: 80 bar}     # values of the fault
      - {t: 0.8, clear: supply_drop, target: left}
    assertions:                      # pcv_sim.rig.assertions: every kind and key
      - {type: max_error, signal: cylinder.position, reference: setpoint, max: 2 mm, after: 0.5}
      - {type: never_above, signal: left.pressure, max: 150 bar}
      - {type: flag_within, signal: controller.fault_detected, at: {event: supply_drop}, within: 50 ms}
      - {type: step_response, at: 0.5, rise_time: 150 ms, overshoot: 10 %, settling_time: 400 ms}
      - {type: within_band, signal: cylinder.position, reference: setpoint, tolerance: 1 mm,
         after: {event: clear, delay: 0.2}}

Values take units (`pcv_sim.units`: `100 bar`, `5 mm`, `20 ms`, `-1 kN`, `12 L/min`, `70 %`); a
bare number is SI, and one whose size says another unit was meant (a supply pressure of 100) is
refused with the likely meaning. A misspelt key anywhere is named with its path and the closest
accepted key. Temperatures are absolute (`-20 degC`, or K bare); a temperature entry is one
profile for every valve that has that input, or a mapping per valve; a valve without the input
(its YAML option off) is refused naming the option. Profiles on the rig (force, supply, duty,
temperatures) are applied at each control instant
(held over the period); a supply profile acts as the supply_drop fault (the configured
pressure: none). Timeline events after `duration` (a run shortened from the file's) are dropped
with a note in the result.

With a ROS controller the setpoint is published each period on `<namespace>/setpoint`
(std_msgs/Float64, m) before the period's samples, and the node's flags are taken from
`<namespace>/controller/flags` (diagnostic_msgs/DiagnosticArray, header.stamp = the sample's model
time, KeyValue `name: value`); docs/interface.md. A controller that does not answer within `wait`
(or whose command exits) fails the run with that reason (the CLI exits 1, as for a model that ran
away; 2 stays for a file that is wrong as written).

Signals: `<valve>.pressure|current|spool_position|duty`, with a valve's options also
`<valve>.coil_temperature|coil_resistance` (solenoid.coil_temperature: lumped) and
`<valve>.core_position` (spool.core: separate), `cylinder.position|velocity|effort`, `setpoint`,
and the controller's flags `controller.<name>`. A bad file raises `ScenarioError`
naming the key and what is accepted (the CLI exits 2).
"""

from __future__ import annotations

import dataclasses
import datetime
import functools
import hashlib
import importlib
import importlib.util
import inspect
import json
import math
import re
import sys
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pcv_sim.device.faults import Fault, FaultError, fault_kind, fault_value_kind, parse_fault
from pcv_sim.errors import CommandError, ParameterError, PcvSimError
from pcv_sim.io.topics import AMBIENT_TEMPERATURE, OIL_TEMPERATURE
from pcv_sim.keys import check_keys, exactly_one
from pcv_sim.model import kernel
from pcv_sim.params import (
    Check,
    ValveParams,
    at_least,
    between,
    check_mapping,
    check_value,
    declarations,
    non_empty,
    parameter,
    read,
    read_yaml,
    refused_as,
)
from pcv_sim.rig.assertions import ASSERTION_TYPES, Outcome, check_assertions, normalize
from pcv_sim.rig.lockstep import Controller, RigRun, run_lockstep
from pcv_sim.rig.params import RigParams, ValveChanges, load_rig
from pcv_sim.rig.profiles import SHAPES, Profile, Segment, parse_segment
from pcv_sim.rig.rig import EXTERNAL_FORCE, MAX_EXTERNAL_FORCE, TEMPERATURE_INPUTS, Rig, RigError, rig_signals
from pcv_sim.simulation.valve import MAX_TEMPERATURE, MIN_TEMPERATURE
from pcv_sim.units import MM_PER_M, PA_PER_BAR, fmt

__all__ = [
    "ASSERTION_TYPES",
    "RUN_STOPS",
    "Outcome",
    "RosController",
    "Scenario",
    "ScenarioError",
    "ScenarioKeys",
    "ScenarioResult",
    "SetpointKeys",
    "TimelineKeys",
    "load_scenario",
    "run_scenario",
    "scenario_from_mapping",
    "scenario_result",
    "scenario_stopped",
    "schedule_timeline",
]

_MAX_DURATION = 3600.0
#: The sections of a valve YAML (the `valves:` overlay's keys for every valve).
VALVE_SECTIONS = tuple(f.name for f in dataclasses.fields(ValveParams))
_NAMESPACE = re.compile(r"^(/[A-Za-z_][A-Za-z0-9_]*)*$")


class ScenarioError(PcvSimError, ValueError):
    """A scenario file that cannot be run as written."""


# --- the keys of a scenario file, declared once (pcv_sim.params); the loader below reads them -----


def _controller(v: Any) -> str | None:
    ok = v is None or isinstance(v, Mapping) or (isinstance(v, str) and v.count(":") == 1 and all(v.split(":")))
    return None if ok else "'module:callable' (e.g. steering:controller) or {ros: {namespace, command, wait}}"


def _rig_file(v: str) -> str | None:
    return None if v else "the path of a rig YAML (relative to the scenario)"


@dataclass(frozen=True, kw_only=True)
class ScenarioKeys:
    """The top level of a scenario file."""

    name: str | None = parameter("-", "the scenario's name (default: the file name)", non_empty, kind="str",
                                 default=None)
    rig: str | None = parameter("-", "the rig YAML, relative to the scenario (default: the shipped config/rig.yaml)",
                                _rig_file, kind="str", default=None)
    duration: float = parameter("s", "the run's length, at least the rig's control period",
                                between(0.0, _MAX_DURATION, "a duration"), kind="time")
    seed: int = parameter("-", "the seed of the sensor noise", at_least(0, "an integer"), kind="int", default=0)
    controller: Any = parameter("-", "`module:callable` (module.py beside the file, or importable), or a ROS node "
                                "{ros: {namespace, command, wait}}", _controller, kind="any", default=None)
    controller_params: Mapping[str, Any] | None = parameter(
        "-", "of keyword arguments: a class is instantiated, a function called with them; checked on load by "
        "the callable's check_params, if it has one", kind="mapping", default=None)
    setpoint: list[Any] | None = parameter(
        "-", "of segments {t, value | ramp | table | sine | chirp | file} of the position setpoint (m)", non_empty,
        kind="list", item=parameter("-", "{t, value | ramp | table | sine | chirp | file}", kind="mapping"),
        default=None)
    timeline: list[Any] | None = parameter(
        "-", "of entries {t, duty | force | supply | ambient_temperature | oil_temperature | fault | clear, ...}",
        kind="list", item=parameter("-", "{t, duty | force | supply | ... | fault | clear, ...}", kind="mapping"),
        default=None)
    assertions: list[Any] | None = parameter(
        "-", f"of checks {{type: {' | '.join(ASSERTION_TYPES)}, ...}} (pcv_sim.rig.assertions)", kind="list",
        default=None)
    valves: Mapping[str, Any] | None = parameter(
        "-", "of valve YAML keys written over the rig's valve files: a section for every valve, a valve's name for "
        "that valve", kind="mapping", default=None)


@dataclass(frozen=True, kw_only=True)
class SetpointKeys:
    """A segment of the setpoint: its start and one shape of pcv_sim.rig.profiles (in m)."""

    t: float = parameter("s", "the segment's start, after the previous one's", at_least(0.0, "a time"), kind="time")
    position: float | None = parameter("m", "the setpoint from t on (or one of the other shapes: a profile)",
                                       between(-1.0, 1.0, "a position"), kind="length", default=None, name="value")


_DUTY = parameter("-", "a duty profile", between(0.0, 1.0, "a duty fraction"), kind="fraction")
_SUPPLY = parameter("Pa", "a supply pressure profile, up to the configured one (acts as supply_drop)",
                    kind="pressure", role="supply pressure")
_TEMPERATURE = parameter("K", "a temperature profile", between(MIN_TEMPERATURE, MAX_TEMPERATURE), kind="temperature")


@dataclass(frozen=True, kw_only=True)
class TimelineKeys:
    """An entry of the timeline: its time and exactly one action (a fault's values beside it, as
    the tables of pcv_sim.device.faults declare them)."""

    t: float = parameter("s", "the entry's time: it acts at the first step at or after it",
                         at_least(0.0, "a time"), kind="time")
    duty: Mapping[str, Any] | None = parameter("-", "valve -> duty profile (a fraction)", kind="mapping",
                                               default=None)
    force: float | None = parameter("N", "the external force on the rod, + extends (a profile)",
                                    between(-MAX_EXTERNAL_FORCE, MAX_EXTERNAL_FORCE, "a force"), kind="force",
                                    default=None)
    supply: Mapping[str, Any] | None = parameter("-", "valve -> supply pressure profile (Pa), up to the configured "
                                                 "one", kind="mapping", default=None)
    ambient_temperature: Any = parameter("K", "a coil's ambient (solenoid.coil_temperature: lumped): one profile "
                                         "for every valve with it, or valve -> profile", kind="any", default=None)
    oil_temperature: Any = parameter("K", "the oil's temperature (fluid.temperature: input): one profile for every "
                                     "valve with it, or valve -> profile", kind="any", default=None)
    fault: str | None = parameter("-", "a fault's kind, injected on `target` with its values",
                                  kind="str", default=None)
    clear: str | None = parameter("-", "a fault's kind, cleared on `target`", kind="str", default=None)
    target: str | None = parameter("-", "a fault's target: a valve, cylinder, or a measured signal (left.pressure)",
                                   kind="str", default=None)


_TOP = tuple(declarations(ScenarioKeys))
_ACTIONS = ("duty", "force", "supply", AMBIENT_TEMPERATURE, OIL_TEMPERATURE, "fault", "clear")


def _ros_namespace(v: str) -> str | None:
    return None if _NAMESPACE.match("" if v == "/" else v) else "a ROS namespace such as /rig ('' or / for the root)"


def _command(v: list[Any]) -> str | None:
    if not v or not all(isinstance(c, str) and c for c in v):
        return "at least one string, none empty"
    for c in v:
        try:
            c.format(namespace="", python="")
        except (KeyError, IndexError, ValueError) as err:
            return f"in {c!r} {err!r}; accepted placeholders are {{namespace}} and {{python}}"
    return None


@dataclass(frozen=True)
class RosController:
    """A controller that is a ROS 2 node: in `namespace` ('' = the root), started by the runner
    with `command` (None: the user starts it), answering within `wait` s."""

    namespace: str = parameter("-", "the namespace of the rig node and the controller ('' or / for the root)",
                               _ros_namespace, kind="str", default="")
    command: tuple[str, ...] | None = parameter(
        "-", "of strings: the command the runner starts, {namespace} and {python} replaced (none: you start the "
        "node)", _command,
        kind="list", default=None)
    wait: float = parameter("s", "how long the runner waits for the node to answer",
                            between(0.1, _MAX_DURATION, "a time"), kind="time", default=30.0)

    def argv(self, python: str) -> list[str]:
        """The command with `{namespace}` and `{python}` replaced."""
        return [c.format(namespace=self.namespace or "/", python=python) for c in self.command or ()]


@dataclass(frozen=True)
class Scenario:
    """A validated scenario: every value in SI, profiles as `Segment`s, event times resolved."""

    name: str
    path: Path | None
    rig: RigParams
    duration: float
    seed: int
    controller: str | None
    controller_params: Mapping[str, Any] | None
    setpoint: tuple[Segment, ...]
    timeline: tuple[Mapping[str, Any], ...]
    assertions: tuple[Mapping[str, Any], ...]
    ros: RosController | None = None       # the controller is a ROS node (then `controller` is None)
    rig_file: Path | None = None            # the rig YAML (None: the shipped one), for the rig node
    notes: tuple[str, ...] = ()             # what the loader changed (timeline events after the duration)
    config_hash: str = ""                   # sha256 of the scenario as loaded (and its rig), for reports
    #: The file's `valves:` keys per valve, written over the valves' YAML in `rig` (a campaign
    #: writes its variants over them).
    valve_changes: Mapping[str, ValveChanges] = field(default_factory=dict)

    def setpoint_function(self) -> Callable[[float], float] | None:
        """The setpoint (m) as a function of time, or None when the scenario has none."""
        if not self.setpoint:
            return None
        return Profile(self.setpoint, initial=self.setpoint[0].at(0.0, 0.0))

    def next_setpoint_change(self, t: float) -> float:
        """The start of the first setpoint segment after t (the duration when none)."""
        return next((s.t for s in self.setpoint if s.t > t + 1e-12), self.duration + 1.0)

    def inputs(self, times: np.ndarray) -> dict[str, np.ndarray]:
        """The inputs the timeline gives at `times` that the rig does not sample: the external force
        (N, with force entries) and the valves' temperature inputs (`<valve>.oil_temperature`,
        `<valve>.ambient_temperature`, K: from the YAML's value on, wherever the option is on)."""
        out: dict[str, np.ndarray] = {}
        segs = [e["force"] for e in self.timeline if "force" in e]
        if segs:
            profile = Profile(sorted(segs, key=lambda s: s.t), initial=0.0)
            out["external force"] = np.array([profile(float(t)) for t in times])
        for v in self.rig.valves:
            layout_inputs = kernel.layout(v.params, "simplified").inputs[len(kernel.INPUTS):]
            for name, initial in zip(layout_inputs, kernel.option_inputs(v.params), strict=True):
                segs = [e[name][v.name] for e in self.timeline if name in e and v.name in e[name]]
                profile = Profile(sorted(segs, key=lambda s: s.t), initial=initial)
                out[f"{v.name}.{name}"] = np.array([profile(float(t)) for t in times])
        return out

    def events(self) -> list[tuple[float, str]]:
        """The timeline in words, in time order (SI values shown in engineering units)."""
        out = []
        for e in self.timeline:
            t = float(e["t"])
            if "duty" in e:
                out += [(t, f"duty {v}: {seg.describe()}") for v, seg in e["duty"].items()]
            elif "supply" in e:
                out += [(t, f"supply {v}: {seg.describe('bar', 1 / PA_PER_BAR)}") for v, seg in e["supply"].items()]
            elif "force" in e:
                out.append((t, f"external force: {e['force'].describe('N')}"))
            elif any(n in e for n in TEMPERATURE_INPUTS):
                name = next(n for n in TEMPERATURE_INPUTS if n in e)
                out += [(t, f"{name.replace('_', ' ')} {v}: {seg.describe('K')}") for v, seg in e[name].items()]
            elif "fault" in e:
                vals = []
                for key, v in e.items():
                    if key not in ("t", "fault", "target"):
                        kind, rate, difference = fault_value_kind(e["fault"], key, str(e["target"]))
                        vals.append(f"{key} {fmt(v, kind, difference=difference)}{'/s' if rate else ''}")
                out.append((t, f"fault {e['fault']} on {e['target']}" + (f": {', '.join(vals)}" if vals else "")))
            else:
                out.append((t, f"clear {e['clear']} on {e['target']}"))
        for k, seg in enumerate(self.setpoint):
            if (k or seg.t > 0.0) and seg.t <= self.duration:
                out.append((seg.t, f"setpoint: {seg.describe('mm', MM_PER_M)}"))
        return sorted(out, key=lambda x: x[0])


@dataclass
class ScenarioResult:
    name: str
    path: str
    passed: bool
    outcomes: list[Outcome]
    real_time_factor: float
    wall_time: float
    error: str | None = None
    run: RigRun | None = field(default=None, repr=False)
    events: list[tuple[float, str]] = field(default_factory=list)     # the timeline, in words
    notes: list[str] = field(default_factory=list)
    meta: dict[str, Any] = field(default_factory=dict)                # version, seed, config hash, date
    inputs: dict[str, np.ndarray] = field(default_factory=dict, repr=False)   # inputs not among the signals (SI)

    def summary(self) -> str:
        """One line per assertion, for a test's failure message."""
        lines = [f"{self.name}: {'passed' if self.passed else 'FAILED'}"]
        if self.error:
            lines.append(self.error)
        lines += [f"note: {n}" for n in self.notes]
        lines += [f"{'ok  ' if o.passed else 'FAIL'} {o.name}: {o.detail}" for o in self.outcomes]
        return "\n".join(lines)

    def to_dict(self) -> dict[str, Any]:
        def clean(o: Outcome) -> dict[str, Any]:
            d = {k: v for k, v in o.__dict__.items() if k != "draw"}
            return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in d.items()}
        return {"name": self.name, "path": self.path, "passed": self.passed, "error": self.error,
                "real_time_factor": self.real_time_factor, "wall_time_s": self.wall_time,
                "assertions": [clean(o) for o in self.outcomes], "notes": list(self.notes), "meta": dict(self.meta)}


# --- loading and validation ------------------------------------------------------------------------


def _signals(rig: RigParams) -> tuple[str, ...]:
    return (*rig_signals(rig), *(f"{v.name}.duty" for v in rig.valves), "setpoint")


def _segment(where: str, t: float, raw: Any, meta: Mapping[str, Any], base: Path | None,
             check: Check | None = None) -> Segment:
    """A profile of the declared quantity `meta` (its check, or `check` in force): a bare value
    read by its own declaration (its hint for a unit slip), else one of the shapes."""
    if not isinstance(raw, Mapping):
        return Segment(t, "value", value=check_value(where, meta, raw, check=check))
    return parse_segment(where, t, raw, meta["kind"], base=base, check=check or meta["check"])


_POSITION = declarations(SetpointKeys)["value"].metadata


def _check_setpoint(raw: list[Any] | None, base: Path | None) -> tuple[Segment, ...]:
    if raw is None:
        return ()
    last = -math.inf
    out = []
    for k, seg in enumerate(raw):
        where = f"setpoint[{k}]"
        check_mapping(SetpointKeys, seg, where, also=SHAPES[1:])
        t = read(SetpointKeys, seg, "t", where,
                 check=at_least(last, "a time after the previous segment's", strict=True) if k else None)
        last = t
        shape = {key: v for key, v in seg.items() if key != "t"}
        out.append(_segment(where, t, shape, _POSITION, base))
    return tuple(out)


def _check_timeline(raw: list[Any] | None, rig: RigParams, duration: float, base: Path | None
                    ) -> tuple[tuple[Mapping[str, Any], ...], list[str]]:
    """The timeline normalized (SI, profiles as segments) and notes on events dropped (after the
    duration: a run shortened from the file's)."""
    if raw is None:
        return (), []
    valves = tuple(v.name for v in rig.valves)
    signals = rig_signals(rig)
    supply = {v.name: v.params.circuit.supply_pressure for v in rig.valves}
    keys = declarations(TimelineKeys)
    out: list[Mapping[str, Any]] = []
    notes: list[str] = []
    for k, e in enumerate(raw):
        where = f"timeline[{k}]"
        t = read(TimelineKeys, e, "t", where)
        a = exactly_one(where, e, _ACTIONS)
        entry: dict[str, Any] = {"t": t}
        if a in ("duty", "supply"):
            check_keys(where, e, ("t", a))
            per = check_keys(f"{where}.{a}", check_value(f"{where}.{a}", keys[a].metadata, e[a]), valves)
            item = (_DUTY if a == "duty" else _SUPPLY).metadata
            entry[a] = {
                str(v): _segment(f"{where}.{a}.{v}", t, d, item, base, None if a == "duty" else
                                 between(0.0, supply[str(v)], "a supply pressure up to the configured one"))
                for v, d in per.items()}
        elif a in TEMPERATURE_INPUTS:
            check_keys(where, e, ("t", a))
            entry[a] = _temperatures(f"{where}.{a}", t, e[a], rig, a, base)
        elif a == "force":
            check_keys(where, e, ("t", "force"))
            entry["force"] = _segment(f"{where}.force", t, e["force"], keys["force"].metadata, base)
        else:
            values = {str(k): v for k, v in e.items() if k not in ("t", a, "target")}
            try:
                if a == "fault":
                    values = dict(parse_fault(e[a], e.get("target"), values, valves=valves, signals=signals,
                                              where=f"{where}.{a}", path=where).values)
                else:          # a clear names the fault by kind and target: its values are the fault's own
                    fault_kind(e[a], e.get("target"), valves=valves, signals=signals, where=f"{where}.{a}")
            except FaultError as err:
                raise ScenarioError(str(err)) from None
            if a == "clear" and values:
                raise ScenarioError(f"{where}: clear takes t, clear, target; unknown: {', '.join(values)}")
            entry.update({a: e[a], "target": e.get("target"), **values})
        if t > duration + 1e-12:
            notes.append(f"{where} ({a} at {t:g} s) is after the run's end ({duration:g} s): dropped")
            continue
        out.append(entry)
    return tuple(out), notes


def _temperatures(where: str, t: float, raw: Any, rig: RigParams, name: str, base: Path | None
                  ) -> dict[str, Segment]:
    """A temperature entry per valve: `{left: X, right: Y}`, or one profile X for every valve that
    has the input (the ambient and the oil are usually shared); each valve named must have it."""
    has = tuple(v.name for v in rig.valves if name in kernel.layout(v.params, "simplified").inputs)
    per_valve = isinstance(raw, Mapping) and bool(raw) and all(k in (v.name for v in rig.valves) for k in raw)
    wanted = dict(raw) if per_valve else dict.fromkeys(has, raw)
    without = [v for v in wanted if v not in has] if per_valve else ([] if has else [v.name for v in rig.valves])
    if without:
        raise ScenarioError(f"{where}: valve {', '.join(without)} has no {name.replace('_', ' ')} input; its valve "
                            f"YAML's {TEMPERATURE_INPUTS[name]} brings it")
    meta = _TEMPERATURE.metadata
    check = between(MIN_TEMPERATURE, MAX_TEMPERATURE, f"the {name.replace('_', ' ')} (K, or written in degC)")
    return {v: _segment(f"{where}.{v}" if per_valve else where, t, d, meta, base, check) for v, d in wanted.items()}


def _timeline_events(timeline: tuple[Mapping[str, Any], ...]) -> list[tuple[float, str, str]]:
    ev = []
    for e in timeline:
        a = next(x for x in _ACTIONS if x in e)
        ev.append((float(e["t"]), a, str(e[a]) if a in ("fault", "clear") else ""))
    return sorted(ev, key=lambda x: x[0])


def _check_assertions(raw: list[Any] | None, rig: RigParams, has_setpoint: bool,
                      timeline: tuple[Mapping[str, Any], ...], base: Path | None) -> tuple[Mapping[str, Any], ...]:
    if raw is None:
        return ()
    events, signals = _timeline_events(timeline), _signals(rig)
    return tuple(normalize(f"assertions[{k}]", a, signals=signals, has_setpoint=has_setpoint, events=events,
                           base=base) for k, a in enumerate(raw))


def _valve_changes(raw: Mapping[str, Any] | None, valves: tuple[str, ...]) -> dict[str, ValveChanges]:
    """The file's `valves:` as changes per valve: a section's keys for every valve, a valve's own
    (`{left: {solenoid: {...}}}`) over them."""
    if raw is None:
        return {}
    check_keys("valves", raw, (*VALVE_SECTIONS, *valves))
    clash = sorted(set(valves) & set(VALVE_SECTIONS))
    if clash:
        raise ScenarioError(f"valves: the rig has a valve named {clash[0]!r}, a section of the valve YAML too, so the "
                            "key is ambiguous; rename the valve")

    def section(where: str, keys: Any) -> dict[tuple[str, str], Any]:
        if not isinstance(keys, Mapping) or not keys:
            raise ScenarioError(f"{where}: got {keys!r}; accepted is a mapping key: value of the valve YAML's "
                                f"{where.rsplit('.', 1)[-1]} section")
        return {(where.rsplit(".", 1)[-1], str(k)): v for k, v in keys.items()}

    every: dict[tuple[str, str], Any] = {}
    own: dict[str, dict[tuple[str, str], Any]] = {}
    for key, value in raw.items():
        if key in VALVE_SECTIONS:
            every.update(section(f"valves.{key}", value))
        else:
            check_keys(f"valves.{key}", value, VALVE_SECTIONS)
            own[key] = {}
            for name, keys in value.items():
                own[key].update(section(f"valves.{key}.{name}", keys))
    return {v: {**every, **own.get(v, {})} for v in valves if every or own.get(v)}


def scenario_from_mapping(data: Any, *, path: Path | None = None, rig_params: RigParams | None = None) -> Scenario:
    """A validated Scenario (ScenarioError naming the key otherwise). `rig_params`, when given,
    stand in for the parameters of the file that `rig` names with the file's `valves:` keys
    written in (a campaign's variant of the rig)."""
    origin = str(path) if path else "scenario"
    try:
        if not isinstance(data, Mapping):
            raise ScenarioError(f"the top level must be a mapping with {', '.join(_TOP)}")
        check_mapping(ScenarioKeys, data, "scenario", "")
        base = path.parent if path else Path.cwd()
        rig_file = read(ScenarioKeys, data, "rig")
        try:
            rig = rig_params if rig_params is not None else load_rig(base / rig_file if rig_file else None)
        except PcvSimError as err:
            raise ScenarioError(f"rig: {err}") from None
        valve_changes = _valve_changes(read(ScenarioKeys, data, "valves"), tuple(v.name for v in rig.valves))
        if valve_changes and rig_params is None:
            try:
                rig = load_rig(base / rig_file if rig_file else None, valve_changes=valve_changes)
            except PcvSimError as err:
                raise ScenarioError(str(err)) from None
        duration = read(ScenarioKeys, data, "duration",
                        check=between(rig.timing.control_period, _MAX_DURATION, "a duration"))
        seed = read(ScenarioKeys, data, "seed")
        ctrl = read(ScenarioKeys, data, "controller")
        ros = None
        if isinstance(ctrl, Mapping):
            ros = ros_controller(ctrl)
            ctrl = None
        params = read(ScenarioKeys, data, "controller_params")
        if params is not None and ros is not None:
            raise ScenarioError("controller_params: for a Python callable; a ROS controller takes its ROS parameters "
                                "(in its command: --ros-args -p name:=value)")
        if params is not None and ctrl is None:
            raise ScenarioError("controller_params: given without a controller")
        if params is not None:                       # the callable the run will take (its base: the file's folder)
            _check_controller_params(ctrl, params, path.parent if path else None)
        if valve_changes and ros is not None:
            raise ScenarioError("valves: the rig node of a ROS controller loads the rig YAML itself (its rig_config); "
                                "accepted is a rig whose valve YAMLs hold these keys, named by `rig`")
        setpoint = _check_setpoint(read(ScenarioKeys, data, "setpoint"), base)
        timeline, notes = _check_timeline(read(ScenarioKeys, data, "timeline"), rig, duration, base)
        assertions = _check_assertions(read(ScenarioKeys, data, "assertions"), rig, bool(setpoint), timeline, base)
        name = read(ScenarioKeys, data, "name") or (path.stem if path else "scenario")
    except (ScenarioError, ParameterError) as err:
        raise ScenarioError(f"{origin}: {err}") from None
    digest = hashlib.sha256(json.dumps([data, repr(rig)], sort_keys=True, default=str).encode()).hexdigest()[:16]
    return Scenario(name, path, rig, duration, seed, ctrl, params, setpoint, timeline, assertions, ros,
                    (base / rig_file).resolve() if rig_file else None, tuple(notes), digest, valve_changes)


@refused_as(ScenarioError)
def ros_controller(raw: Any) -> RosController:
    """`{ros: {namespace, command, wait}}` validated (ScenarioError naming the key)."""
    if not isinstance(raw, Mapping) or set(raw) != {"ros"}:
        raise ScenarioError(f"controller: got {raw!r}; accepted is 'module:callable' or {{ros: {{namespace, command, "
                            "wait}}}")
    spec = raw["ros"] if raw["ros"] is not None else {}
    check_mapping(RosController, spec, "controller.ros")
    ns, cmd, wait = (read(RosController, spec, k, "controller.ros") for k in ("namespace", "command", "wait"))
    return RosController("" if ns == "/" else ns, tuple(cmd) if cmd is not None else None, wait)


def load_scenario(path: str | Path) -> Scenario:
    return scenario_from_mapping(read_yaml(path, "scenario", ScenarioError), path=Path(path))


def _check_controller_params(spec: str, params: Mapping[str, Any], base: Path | None) -> None:
    """On load: `controller_params` checked by the callable's own declarations when it has them (a
    `check_params(values)` that raises ParameterError, as `PositionController`), with their message.
    Its own: a subclass with other keywords does not inherit its base's check."""
    obj = controller_callable(spec, base)
    check = getattr(obj, "check_params", None) if "check_params" in getattr(obj, "__dict__", {}) else None
    if callable(check):
        try:
            check(params)
        except ParameterError as err:
            raise ScenarioError(f"controller_params: {err}") from None


def resolve_controller(spec: str, params: Mapping[str, Any] | None, base: Path | None) -> Controller:
    """The controller named `module:callable` (`controller_callable`): a class instantiated, a
    function called with `params` when given, to make it."""
    obj = controller_callable(spec, base)
    if inspect.isclass(obj) or params is not None:
        try:
            obj = obj(**dict(params or {}))
        except TypeError as err:
            raise ScenarioError(f"controller_params: {spec} does not take them: {err}") from None
        except ParameterError as err:                # refused by the controller's own declarations
            raise ScenarioError(f"controller_params: {err}") from None
    if not callable(obj):
        raise ScenarioError(f"controller: {spec} made a {type(obj).__name__}, not a callable (t, measurements)")
    controller: Controller = obj
    return controller


def controller_callable(spec: str, base: Path | None) -> Any:
    """The callable named `module:callable`: module.py beside the scenario (loaded from that file,
    so two folders' `steering.py` never mix), else an importable module."""
    module_name, attr = spec.split(":")
    beside = base / f"{module_name.replace('.', '/')}.py" if base is not None else None
    try:
        if beside is not None and beside.is_file():
            unique = f"pcv_sim_scenario_{abs(hash(str(beside.resolve())))}_{module_name.replace('.', '_')}"
            loader_spec = importlib.util.spec_from_file_location(unique, beside)
            assert loader_spec is not None and loader_spec.loader is not None
            module = importlib.util.module_from_spec(loader_spec)
            sys.path.insert(0, str(base))            # the module may import its own siblings
            try:
                loader_spec.loader.exec_module(module)
            finally:
                sys.path.remove(str(base))
        else:
            module = importlib.import_module(module_name)
    except ImportError as err:
        raise ScenarioError(f"controller: cannot import {module_name!r} ({err}); accepted is a module.py beside the "
                            "scenario or an importable module") from None
    obj = getattr(module, attr, None)
    if obj is None or not callable(obj):
        raise ScenarioError(f"controller: {module_name} has no callable {attr!r}")
    return obj


# --- running ---------------------------------------------------------------------------------------


def _profile_updates(T: float, t0: float, seg: Segment, before: float, until: float) -> list[tuple[float, float]]:
    """A segment on the rig as (time, value) updates: a value once at t0; any other shape at each
    control instant (period T) from t0 until it is constant or the next segment starts (held over
    the period), then its end value."""
    if seg.constant:
        return [(t0, seg.value)]
    out = []
    stop = min(until, t0 + seg.end())
    k = math.ceil(t0 / T - 1e-9)
    while k * T < stop - 1e-12:
        out.append((k * T, seg.at(k * T - t0, before)))
        k += 1
    if math.isfinite(stop) and stop < until:
        out.append((stop, seg.at(stop - t0, before)))
    return out


def schedule_timeline(rig: Rig, scenario: Scenario) -> None:
    """Put the scenario's timeline on the rig's schedule: events at their times, profiles as
    values at each control instant (zero-order hold over the control period); the external
    force is fed (`Rig.feed`: its values go into the model inside the compiled calls, at the
    steps `Rig.schedule` would give them)."""
    T = rig.params.timing.control_period
    end = scenario.duration + T
    channels: dict[tuple[str, str], list[Segment]] = {}
    for e in scenario.timeline:
        t = float(e["t"])
        if "duty" in e or "supply" in e:
            a = "duty" if "duty" in e else "supply"
            for valve, seg in e[a].items():
                channels.setdefault((a, valve), []).append(seg)
        elif "force" in e:
            channels.setdefault(("force", ""), []).append(e["force"])
        elif any(n in e for n in TEMPERATURE_INPUTS):
            name = next(n for n in TEMPERATURE_INPUTS if n in e)
            for valve, seg in e[name].items():
                channels.setdefault((name, valve), []).append(seg)
        elif "fault" in e:
            # checked (and its values made SI) when the timeline was read
            f = Fault(e["fault"], e["target"], {str(k): v for k, v in e.items() if k not in ("t", "fault", "target")})
            rig.schedule(t, functools.partial(rig.inject, f))
        else:
            rig.schedule(t, functools.partial(rig.clear, e["target"], e["clear"]))
    initial = {v.name: v for v in scenario.rig.valves}
    for (a, valve), segs in channels.items():
        if a == "duty":
            apply: Callable[[float], None] = functools.partial(_duty, rig, valve)
            x0 = initial[valve].initial_duty
        elif a == "force":
            apply, x0 = rig.set_external_force, 0.0
        elif a in TEMPERATURE_INPUTS:
            apply = functools.partial(rig.set_temperature, valve, a)
            x0 = rig.temperature(valve, a)
        else:
            apply = functools.partial(_supply, rig, valve)
            x0 = initial[valve].params.circuit.supply_pressure
        profile = Profile(sorted(segs, key=lambda s: s.t), initial=x0)
        updates: list[tuple[float, float]] = []
        for k, seg in enumerate(profile.segments):
            nxt = profile.segments[k + 1].t if k + 1 < len(profile.segments) else end
            updates += _profile_updates(T, seg.t, seg, profile(seg.t - 1e-9) if k else x0, nxt)
        if a == "force":
            rig.feed(EXTERNAL_FORCE, [max(rig.steps, math.ceil(t / rig.dt - 1e-9)) for t, _ in updates],
                     [v for _, v in updates])
        else:
            for t, v in updates:
                rig.schedule(t, functools.partial(apply, v))


def _duty(rig: Rig, valve: str, duty: float) -> None:
    rig.set_duty(valve, duty)


def _supply(rig: Rig, valve: str, pressure: float) -> None:
    """The supply as the supply_drop fault with this pressure (the configured one: cleared); one
    event in the log per profile change, not one per control period."""
    nominal = next(v.params.circuit.supply_pressure for v in rig.params.valves if v.name == valve)
    active = (valve, "supply_drop") in rig.faults
    n = len(rig.log)
    if pressure >= nominal:
        if active:
            rig.clear(valve, "supply_drop")
    else:
        rig.inject(Fault("supply_drop", valve, {"pressure": pressure}))
    if active and len(rig.log) > n:
        del rig.log[n:]          # a profile's next value: the events list shows the profile once


def run_scenario(scenario: Scenario, controller: Controller | None = None, *, rig: Rig | None = None) -> ScenarioResult:
    """Run `scenario` in lockstep (with `controller`, or the one the file names) and check its
    assertions. A run whose model runs away fails with the reason (no exception). A ROS
    controller (`scenario.ros`) runs over DDS with the rig node as host: that is
    `pcv_sim.node.scenario_host.run_ros_scenario`, a layer above this one."""
    if controller is None and scenario.ros is not None:
        raise ScenarioError(f"{scenario.name}: the controller is a ROS node; run it with "
                            "pcv_sim.node.scenario_host.run_ros_scenario (as `pcv-sim scenario run` does), "
                            "or pass a callable controller")
    if controller is None and scenario.controller is not None:
        controller = resolve_controller(scenario.controller, scenario.controller_params,
                                        scenario.path.parent if scenario.path else None)
    if rig is None:
        rig = Rig(scenario.rig, seed=scenario.seed)
    else:
        rig.reset()
    schedule_timeline(rig, scenario)
    wall0 = time.perf_counter()
    try:
        run = run_lockstep(rig, controller, scenario.duration, setpoint=scenario.setpoint_function())
    except RUN_STOPS as err:
        return scenario_stopped(scenario, rig, err, time.perf_counter() - wall0)
    return scenario_result(scenario, run)


#: What stops a scenario's run as a failed run with its reason (anything else the controller
#: raised propagates).
RUN_STOPS = (RigError, CommandError, FaultError)


def scenario_stopped(scenario: Scenario, rig: Rig, err: Exception, wall: float) -> ScenarioResult:
    """The result of a run that one of `RUN_STOPS` stopped (`err`) after `wall` s."""
    return ScenarioResult(scenario.name, str(scenario.path) if scenario.path else "", False, [],
                          scenario.duration / wall if wall else math.inf, wall,
                          f"the run stopped at t = {rig.time:.4f} s: {err}")


def scenario_result(scenario: Scenario, run: RigRun) -> ScenarioResult:
    """The assertions of `scenario` checked on `run`."""
    outcomes = check_assertions(run, scenario.assertions, next_change=scenario.next_setpoint_change)
    return ScenarioResult(scenario.name, str(scenario.path) if scenario.path else "", all(o.passed for o in outcomes),
                          outcomes, run.real_time_factor, run.wall_time, None, run, scenario.events(),
                          list(scenario.notes), run_metadata(scenario), scenario.inputs(run.times))


def run_metadata(scenario: Scenario) -> dict[str, Any]:
    """What a report names the run by: package version, seed, the config's hash, date (UTC)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        pkg = version("pcv_sim")
    except PackageNotFoundError:
        pkg = "unknown"
    return {"pcv_sim": pkg, "seed": scenario.seed, "config_hash": scenario.config_hash,
            "duration_s": scenario.duration,
            "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M:%S UTC")}
