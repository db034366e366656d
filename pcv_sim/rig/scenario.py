"""Scenarios: a rig, a timeline, a controller and assertions in one YAML file; run in lockstep.

    name: step                       # optional (default: the file name)
    rig: ../config/rig.yaml          # relative to this file (default: the shipped config/rig.yaml)
    duration: 2.0                    # s
    seed: 0                          # sensor noise
    controller: steering:PositionController   # `module:callable`; module.py beside this file or importable
    controller_params: {kp: 5.0}     # optional: a class is instantiated with them, a function called
                                     # with them to make the controller; without, a function is the controller
    # or a ROS 2 controller node (pcv_sim.node.scenario_host): the runner hosts the rig node
    # (`ros2 run pcv_sim rig`) in lockstep in `namespace` and waits up to `wait` s for the node
    # to answer; `command`, if given, is started by the runner (in a ROS domain of its own, cwd
    # this file's folder; `{namespace}` and `{python}` are replaced) and stopped after the run
    # controller: {ros: {namespace: /rig, wait: 30,
    #                    command: ["{python}", -m, pcv_sim.node.steering_controller, --ros-args, -r, "__ns:={namespace}"]}}
    setpoint:                        # optional, m: each segment holds from its t until the next one's
      - {t: 0.0, value: 0.0}
      - {t: 0.5, value: 0.02}
      - {t: 1.0, sine: {amplitude: 0.02, frequency: 1.0, offset: 0.0}}   # m, Hz, m; phase from t
    timeline:                        # at the first step at or after t (s)
      - {t: 0.1, duty: {left: 0.7}}                     # duty command(s), fraction
      - {t: 0.2, force: 500.0}                          # external force on the rod, N (+ extends)
      - {t: 0.5, fault: supply_drop, target: left, pressure: 8.0e+6}   # values of the fault (SI)
      - {t: 0.8, clear: supply_drop, target: left}
    assertions:                      # SI units, times in s; `measured: true` checks what the controller saw
      - {type: max_error, signal: cylinder.position, reference: setpoint, max: 0.002, after: 0.5}
      - {type: never_above, signal: left.pressure, max: 1.5e+7}
      - {type: never_below, signal: left.pressure, min: 0.0}
      - {type: flag_within, signal: controller.fault_detected, at: 0.5, within: 0.05}

With a ROS controller the setpoint is published each period on `<namespace>/setpoint`
(std_msgs/Float64, m) before the period's samples, and the node's flags are taken from
`<namespace>/controller/flags` (diagnostic_msgs/DiagnosticArray, header.stamp = the sample's model
time, KeyValue `name: value`); docs/interface.md. A controller that does not answer within `wait`
(or whose command exits) fails the run with that reason (the CLI exits 1, as for a model that ran
away; 2 stays for a file that is wrong as written).

Signals: `<valve>.pressure|current|spool_position|duty`, `cylinder.position|velocity|effort`,
`setpoint`, and the controller's flags `controller.<name>`. A bad file raises `ScenarioError`
naming the key and what is accepted (the CLI exits 2).
"""

from __future__ import annotations

import functools
import importlib
import importlib.util
import inspect
import math
import re
import sys
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from pcv_sim.errors import CommandError, PcvSimError
from pcv_sim.rig.faults import FaultError, parse_fault
from pcv_sim.rig.lockstep import Controller, RigRun, run_lockstep
from pcv_sim.rig.params import RigParams, load_rig
from pcv_sim.rig.rig import Rig, RigError, signal_names

__all__ = [
    "ASSERTION_TYPES",
    "Outcome",
    "RosController",
    "Scenario",
    "ScenarioError",
    "ScenarioResult",
    "load_scenario",
    "run_scenario",
    "scenario_result",
]

ASSERTION_TYPES = ("max_error", "never_above", "never_below", "flag_within")
_TOP = ("name", "rig", "duration", "seed", "controller", "controller_params", "setpoint", "timeline", "assertions")
_MAX_DURATION = 3600.0
_ROS_KEYS = ("namespace", "command", "wait")
_NAMESPACE = re.compile(r"^(/[A-Za-z_][A-Za-z0-9_]*)*$")


class ScenarioError(PcvSimError, ValueError):
    """A scenario file that cannot be run as written."""


@dataclass(frozen=True)
class RosController:
    """A controller that is a ROS 2 node: in `namespace` ('' = the root), started by the runner
    with `command` (None: the user starts it), answering within `wait` s."""

    namespace: str = ""
    command: tuple[str, ...] | None = None
    wait: float = 30.0

    def argv(self, python: str) -> list[str]:
        """The command with `{namespace}` and `{python}` replaced."""
        return [c.format(namespace=self.namespace or "/", python=python) for c in self.command or ()]


@dataclass(frozen=True)
class Scenario:
    name: str
    path: Path | None
    rig: RigParams
    duration: float
    seed: int
    controller: str | None
    controller_params: Mapping[str, Any] | None
    setpoint: tuple[Mapping[str, Any], ...]
    timeline: tuple[Mapping[str, Any], ...]
    assertions: tuple[Mapping[str, Any], ...]
    ros: RosController | None = None       # the controller is a ROS node (then `controller` is None)
    rig_file: Path | None = None            # the rig YAML (None: the shipped one), for the rig node

    def setpoint_function(self) -> Callable[[float], float] | None:
        """The setpoint (m) as a function of time, or None when the scenario has none."""
        segs = self.setpoint
        if not segs:
            return None
        starts = [float(s["t"]) for s in segs]

        def value(t: float) -> float:
            k = 0
            for j, t0 in enumerate(starts):
                if t0 <= t + 1e-12:
                    k = j
            s = segs[k]
            if "value" in s:
                return float(s["value"])
            sine = s["sine"]
            return float(sine.get("offset", 0.0) + sine["amplitude"] * math.sin(
                2.0 * math.pi * sine["frequency"] * (t - starts[k])))

        return value


@dataclass(frozen=True)
class Outcome:
    """One assertion's result: `value` is what was found, `limit` what was asked (SI)."""

    name: str
    passed: bool
    value: float
    limit: float
    detail: str


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

    def summary(self) -> str:
        """One line per assertion, for a test's failure message."""
        lines = [f"{self.name}: {'passed' if self.passed else 'FAILED'}"]
        if self.error:
            lines.append(self.error)
        lines += [f"{'ok  ' if o.passed else 'FAIL'} {o.name}: {o.detail}" for o in self.outcomes]
        return "\n".join(lines)

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "path": self.path, "passed": self.passed, "error": self.error,
                "real_time_factor": self.real_time_factor, "wall_time_s": self.wall_time,
                "assertions": [o.__dict__ for o in self.outcomes]}


# --- loading and validation ------------------------------------------------------------------------


def _num(where: str, v: Any, *, lo: float = -math.inf, hi: float = math.inf, what: str = "a finite number") -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not lo <= v <= hi:
        rng = "" if (lo, hi) == (-math.inf, math.inf) else f" in {lo:g} .. {hi:g}"
        raise ScenarioError(f"{where}: got {v!r}; accepted is {what}{rng}")
    return float(v)


def _mapping(where: str, v: Any, keys: tuple[str, ...]) -> Mapping[str, Any]:
    if not isinstance(v, Mapping):
        raise ScenarioError(f"{where}: got {v!r}; accepted is a mapping with {', '.join(keys)}")
    return v


def _unknown(where: str, v: Mapping[str, Any], keys: tuple[str, ...]) -> None:
    bad = sorted(str(k) for k in v if k not in keys)
    if bad:
        raise ScenarioError(f"{where}: unknown key(s) {', '.join(bad)}; accepted: {', '.join(keys)}")


def _signals(rig: RigParams) -> tuple[str, ...]:
    names = [v.name for v in rig.valves]
    return (*signal_names(names), *(f"{n}.duty" for n in names), "setpoint")


def _check_setpoint(raw: Any) -> tuple[Mapping[str, Any], ...]:
    if raw is None:
        return ()
    if not isinstance(raw, list) or not raw:
        raise ScenarioError("setpoint: accepted is a list of {t, value} or {t, sine: {amplitude, frequency, offset}}")
    last = -math.inf
    for k, seg in enumerate(raw):
        where = f"setpoint[{k}]"
        _mapping(where, seg, ("t", "value", "sine"))
        _unknown(where, seg, ("t", "value", "sine"))
        t = _num(f"{where}.t", seg.get("t"), lo=0.0, what="a time in s")
        if t <= last:
            raise ScenarioError(f"{where}.t: {t:g} s; accepted is a time after the previous segment's ({last:g} s)")
        last = t
        if ("value" in seg) == ("sine" in seg):
            raise ScenarioError(f"{where}: accepted is exactly one of value (m) or sine")
        if "value" in seg:
            _num(f"{where}.value", seg["value"], lo=-1.0, hi=1.0, what="a position in m")
        else:
            sine = _mapping(f"{where}.sine", seg["sine"], ("amplitude", "frequency", "offset"))
            _unknown(f"{where}.sine", sine, ("amplitude", "frequency", "offset"))
            _num(f"{where}.sine.amplitude", sine.get("amplitude"), lo=0.0, hi=1.0, what="an amplitude in m")
            _num(f"{where}.sine.frequency", sine.get("frequency"), lo=0.0, hi=1000.0, what="a frequency in Hz")
            _num(f"{where}.sine.offset", sine.get("offset", 0.0), lo=-1.0, hi=1.0, what="an offset in m")
    return tuple(raw)


def _check_timeline(raw: Any, rig: RigParams, duration: float) -> tuple[Mapping[str, Any], ...]:
    if raw is None:
        return ()
    if not isinstance(raw, list):
        raise ScenarioError("timeline: accepted is a list of entries {t, duty | force | fault | clear, ...}")
    valves = tuple(v.name for v in rig.valves)
    signals = tuple(f"{v}.{s}" for v in valves for s in ("pressure", "current", "spool_position")) + tuple(
        f"cylinder.{s}" for s in ("position", "velocity", "effort"))
    for k, e in enumerate(raw):
        where = f"timeline[{k}]"
        _mapping(where, e, ("t",))
        _num(f"{where}.t", e.get("t"), lo=0.0, hi=duration, what="a time in s within the duration")
        actions = [a for a in ("duty", "force", "fault", "clear") if a in e]
        if len(actions) != 1:
            raise ScenarioError(f"{where}: accepted is exactly one of duty, force, fault, clear (got {actions or 'none'})")
        a = actions[0]
        if a == "duty":
            _unknown(where, e, ("t", "duty"))
            duties = _mapping(f"{where}.duty", e["duty"], valves)
            _unknown(f"{where}.duty", duties, valves)
            for v, d in duties.items():
                _num(f"{where}.duty.{v}", d, lo=0.0, hi=1.0, what="a duty fraction")
        elif a == "force":
            _unknown(where, e, ("t", "force"))
            _num(f"{where}.force", e["force"], lo=-1e6, hi=1e6, what="a force in N")
        else:
            values = {str(key): v for key, v in e.items() if key not in ("t", a, "target")}
            try:
                parse_fault(e[a], e.get("target"), values if a == "fault" else None, valves=valves, signals=signals,
                            where=f"{where}.{a}")
            except FaultError as err:
                raise ScenarioError(str(err)) from None
            if a == "clear" and values:
                raise ScenarioError(f"{where}: clear takes t, clear, target; unknown: {', '.join(values)}")
    return tuple(raw)


def _check_assertions(raw: Any, rig: RigParams, has_setpoint: bool) -> tuple[Mapping[str, Any], ...]:
    if raw is None:
        return ()
    if not isinstance(raw, list):
        raise ScenarioError(f"assertions: accepted is a list of {{type: {' | '.join(ASSERTION_TYPES)}, ...}}")
    known = _signals(rig)
    keys = {
        "max_error": ("type", "name", "signal", "reference", "max", "after", "before", "measured"),
        "never_above": ("type", "name", "signal", "max", "after", "before", "measured"),
        "never_below": ("type", "name", "signal", "min", "after", "before", "measured"),
        "flag_within": ("type", "name", "signal", "at", "within"),
    }
    for k, a in enumerate(raw):
        where = f"assertions[{k}]"
        _mapping(where, a, ("type",))
        kind = a.get("type")
        if kind not in keys:
            raise ScenarioError(f"{where}.type: got {kind!r}; accepted are {', '.join(ASSERTION_TYPES)}")
        _unknown(where, a, keys[kind])
        sig = a.get("signal")
        ok = isinstance(sig, str) and (sig in known or sig.startswith("controller."))
        if not ok:
            raise ScenarioError(f"{where}.signal: got {sig!r}; accepted are {', '.join(known)} and, for flag_within, "
                                "controller.<flag>")
        if sig == "setpoint" and not has_setpoint:
            raise ScenarioError(f"{where}.signal: the scenario has no setpoint")
        for key in ("max", "min", "after", "before", "at", "within"):
            if key in a:
                _num(f"{where}.{key}", a[key])
        need = {"max_error": ("reference", "max"), "never_above": ("max",), "never_below": ("min",),
                "flag_within": ("at", "within")}[kind]
        for key in need:
            if key not in a:
                raise ScenarioError(f"{where}: {kind} needs {key}")
        if kind == "max_error":
            ref = a["reference"]
            if not (ref in known and (ref != "setpoint" or has_setpoint)) and not isinstance(ref, (int, float)):
                raise ScenarioError(f"{where}.reference: got {ref!r}; accepted is a number or a signal "
                                    f"({', '.join(known if has_setpoint else known[:-1])})")
        if "measured" in a and not isinstance(a["measured"], bool):
            raise ScenarioError(f"{where}.measured: got {a['measured']!r}; accepted is true or false")
    return tuple(raw)


def scenario_from_mapping(data: Any, *, path: Path | None = None) -> Scenario:
    """A validated Scenario (ScenarioError naming the key otherwise)."""
    origin = str(path) if path else "scenario"
    try:
        if not isinstance(data, Mapping):
            raise ScenarioError(f"the top level must be a mapping with {', '.join(_TOP)}")
        _unknown("scenario", data, _TOP)
        base = path.parent if path else Path.cwd()
        rig_file = data.get("rig")
        if rig_file is not None and not isinstance(rig_file, str):
            raise ScenarioError(f"rig: got {rig_file!r}; accepted is the path of a rig YAML (relative to the scenario)")
        try:
            rig = load_rig(base / rig_file if rig_file else None)
        except PcvSimError as err:
            raise ScenarioError(f"rig: {err}") from None
        if "duration" not in data:
            raise ScenarioError("duration: missing; accepted is the run's length in s")
        duration = _num("duration", data["duration"], lo=rig.timing.control_period, hi=_MAX_DURATION,
                        what="a duration in s")
        seed = data.get("seed", 0)
        if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
            raise ScenarioError(f"seed: got {seed!r}; accepted is an integer >= 0")
        ctrl = data.get("controller")
        ros = None
        if isinstance(ctrl, Mapping):
            ros = ros_controller(ctrl)
            ctrl = None
        elif ctrl is not None and (not isinstance(ctrl, str) or ctrl.count(":") != 1 or not all(ctrl.split(":"))):
            raise ScenarioError(f"controller: got {ctrl!r}; accepted is 'module:callable' (e.g. steering:controller) "
                                "or {ros: {namespace, command, wait}}")
        params = data.get("controller_params")
        if params is not None and not isinstance(params, Mapping):
            raise ScenarioError(f"controller_params: got {params!r}; accepted is a mapping of keyword arguments")
        if params is not None and ros is not None:
            raise ScenarioError("controller_params: for a Python callable; a ROS controller takes its ROS parameters "
                                "(in its command: --ros-args -p name:=value)")
        if params is not None and ctrl is None:
            raise ScenarioError("controller_params: given without a controller")
        setpoint = _check_setpoint(data.get("setpoint"))
        timeline = _check_timeline(data.get("timeline"), rig, duration)
        assertions = _check_assertions(data.get("assertions"), rig, bool(setpoint))
        name = data.get("name", path.stem if path else "scenario")
        if not isinstance(name, str) or not name:
            raise ScenarioError(f"name: got {name!r}; accepted is a non-empty string")
    except ScenarioError as err:
        raise ScenarioError(f"{origin}: {err}") from None
    return Scenario(name, path, rig, duration, seed, ctrl, params, setpoint, timeline, assertions, ros,
                    (base / rig_file).resolve() if rig_file else None)


def ros_controller(raw: Any) -> RosController:
    """`{ros: {namespace, command, wait}}` validated (ScenarioError naming the key)."""
    if not isinstance(raw, Mapping) or set(raw) != {"ros"}:
        raise ScenarioError(f"controller: got {raw!r}; accepted is 'module:callable' or {{ros: {{namespace, command, "
                            "wait}}}")
    spec = raw["ros"] if raw["ros"] is not None else {}
    _mapping("controller.ros", spec, _ROS_KEYS)
    _unknown("controller.ros", spec, _ROS_KEYS)
    ns = spec.get("namespace", "")
    if not isinstance(ns, str) or not _NAMESPACE.match("" if ns == "/" else ns):
        raise ScenarioError(f"controller.ros.namespace: got {ns!r}; accepted is a ROS namespace such as /rig ('' or / "
                            "for the root)")
    cmd = spec.get("command")
    if cmd is not None:
        if not isinstance(cmd, list) or not cmd or not all(isinstance(c, str) and c for c in cmd):
            raise ScenarioError(f"controller.ros.command: got {cmd!r}; accepted is a list of non-empty strings, e.g. "
                                "[ros2, run, pcv_sim, steering_controller, --ros-args, -r, \"__ns:={namespace}\"]")
        for c in cmd:
            try:
                c.format(namespace="", python="")
            except (KeyError, IndexError, ValueError) as err:
                raise ScenarioError(f"controller.ros.command: {c!r}: {err!r}; accepted placeholders are {{namespace}} "
                                    "and {python}") from None
    wait = _num("controller.ros.wait", spec.get("wait", 30.0), lo=0.1, hi=_MAX_DURATION, what="a time in s")
    return RosController("" if ns == "/" else ns, tuple(cmd) if cmd is not None else None, wait)


def load_scenario(path: str | Path) -> Scenario:
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as err:
        raise ScenarioError(f"cannot read scenario {p}: {err.strerror}") from err
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as err:
        raise ScenarioError(f"{p}: not valid YAML: {err}") from err
    return scenario_from_mapping(data, path=p)


def resolve_controller(spec: str, params: Mapping[str, Any] | None, base: Path | None) -> Controller:
    """The controller named `module:callable`: module.py beside the scenario (loaded from that
    file, so two folders' `steering.py` never mix), else an importable module."""
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
    if inspect.isclass(obj) or params is not None:
        try:
            obj = obj(**dict(params or {}))
        except TypeError as err:
            raise ScenarioError(f"controller_params: {spec} does not take them: {err}") from None
    if not callable(obj):
        raise ScenarioError(f"controller: {spec} made a {type(obj).__name__}, not a callable (t, measurements)")
    controller: Controller = obj
    return controller


# --- running ---------------------------------------------------------------------------------------


def schedule_timeline(rig: Rig, scenario: Scenario) -> None:
    signals = rig.signals
    for e in scenario.timeline:
        t = float(e["t"])
        if "duty" in e:
            for valve, d in e["duty"].items():
                rig.schedule(t, functools.partial(rig.set_duty, valve, d))
        elif "force" in e:
            rig.schedule(t, functools.partial(rig.set_external_force, e["force"]))
        elif "fault" in e:
            values = {str(k): v for k, v in e.items() if k not in ("t", "fault", "target")}
            f = parse_fault(e["fault"], e["target"], values, valves=rig.valve_names, signals=signals)
            rig.schedule(t, functools.partial(rig.inject, f))
        else:
            rig.schedule(t, functools.partial(rig.clear, e["target"], e["clear"]))


def _window(run: RigRun, a: Mapping[str, Any]) -> np.ndarray:
    t = run.times
    mask = np.ones(len(t), bool)
    if "after" in a:
        mask &= t >= float(a["after"]) - 1e-12
    if "before" in a:
        mask &= t <= float(a["before"]) + 1e-12
    return mask


def check_assertion(run: RigRun, a: Mapping[str, Any]) -> Outcome:
    """One assertion on a run (see the module docstring)."""
    kind, sig = a["type"], a["signal"]
    measured = bool(a.get("measured", False))
    name = a.get("name") or f"{kind} {sig}"
    t = run.times
    if kind == "flag_within":
        flag = run.flags.get(sig)
        at, within = float(a["at"]), float(a["within"])
        if flag is None:
            return Outcome(name, False, math.nan, within, f"the controller never reported {sig}")
        raised = np.nan_to_num(flag, nan=0.0) != 0.0
        early = raised & (t < at - 1e-12)
        if np.any(early):
            return Outcome(name, False, float(t[np.argmax(early)] - at), within,
                           f"{sig} raised at {t[np.argmax(early)]:.4f} s, before the event at {at:g} s")
        late = raised & (t >= at - 1e-12)
        if not np.any(late):
            return Outcome(name, False, math.inf, within, f"{sig} never raised after {at:g} s")
        delay = float(t[np.argmax(late)] - at)
        return Outcome(name, delay <= within + 1e-12, delay, within,
                       f"{sig} raised {delay * 1e3:.1f} ms after {at:g} s (limit {within * 1e3:g} ms)")
    try:
        y = run.signal(sig, measured=measured)
    except KeyError:
        return Outcome(name, False, math.nan, math.nan, f"no signal {sig} in the run (a flag the controller never reported)")
    mask = _window(run, a) & np.isfinite(y)
    if not np.any(mask):
        return Outcome(name, False, math.nan, math.nan, "no samples in the window")
    if kind == "max_error":
        ref = a["reference"]
        r = np.full(len(t), float(ref)) if isinstance(ref, (int, float)) else run.signal(ref, measured=measured)
        err = np.abs(y - r)[mask]
        worst = float(np.max(err))
        k = int(np.flatnonzero(mask)[np.argmax(err)])
        return Outcome(name, worst <= float(a["max"]), worst, float(a["max"]),
                       f"|{sig} - {ref}| at most {worst:.6g} (at {t[k]:.4f} s), limit {float(a['max']):g}")
    if kind == "never_above":
        worst = float(np.max(y[mask]))
        return Outcome(name, worst <= float(a["max"]), worst, float(a["max"]),
                       f"{sig} at most {worst:.6g}, limit {float(a['max']):g}")
    worst = float(np.min(y[mask]))
    return Outcome(name, worst >= float(a["min"]), worst, float(a["min"]),
                   f"{sig} at least {worst:.6g}, limit {float(a['min']):g}")


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
    path = str(scenario.path) if scenario.path else ""
    wall0 = time.perf_counter()
    try:
        run = run_lockstep(rig, controller, scenario.duration, setpoint=scenario.setpoint_function())
    except (RigError, CommandError, FaultError) as err:
        wall = time.perf_counter() - wall0
        return ScenarioResult(scenario.name, path, False, [], scenario.duration / wall if wall else math.inf, wall,
                              f"the run stopped at t = {rig.time:.4f} s: {err}")
    return scenario_result(scenario, run)


def scenario_result(scenario: Scenario, run: RigRun) -> ScenarioResult:
    """The assertions of `scenario` checked on `run`."""
    outcomes = [check_assertion(run, a) for a in scenario.assertions]
    return ScenarioResult(scenario.name, str(scenario.path) if scenario.path else "", all(o.passed for o in outcomes),
                          outcomes, run.real_time_factor, run.wall_time, None, run)
