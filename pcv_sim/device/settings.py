"""The emulator node's parameters: node settings and the model's parameters as ROS parameters.

No ROS here: values come in as plain Python (what rclpy's `Parameter.value` gives) and are
validated by the one mechanism of `pcv_sim.params`: each node setting is a `NodeSettings` field
declared once with `setting(default, unit, description, check, ...)`; a `SettingsSchema` over
a settings dataclass derives what a node declares (its --help), checks a value by name and makes and
changes the settings: every node's settings go through it (`SCHEMA` here, the rig node's in
`pcv_sim.rig.settings`).

Model parameters appear as `model.<section>.<key>` (e.g. `model.spool.mass`), every scalar and
vector field of the valve YAML; the matrix-valued curve fits (`solenoid.force`, `fits.*` tables)
are set through the YAML file named by `valve_config`. `null` in the YAML (e.g.
`calibration.net_area`) is the string "null" as a ROS parameter; "equivalent" stays a string.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

from pcv_sim.device.bag_layout import RECORDABLE, check_signals
from pcv_sim.errors import BagError, ParameterError
from pcv_sim.params import (
    ValveParams,
    accepted_words,
    any_value,
    check_value,
    int_range,
    non_negative,
    one_of,
    params_from_mapping,
    params_to_mapping,
    positive,
    setting,
    watchdog_parameter,
)
from pcv_sim.params import fraction as _fraction
from pcv_sim.params import speed_factor as real_time_factor
from pcv_sim.simulation.clock import steps_per
from pcv_sim.simulation.duty import check_duty

__all__ = [
    "MODEL_PREFIX",
    "NODE_PARAMETERS",
    "RUNTIME_FIXED_MODEL",
    "SCHEMA",
    "CommonSettings",
    "ModelParameter",
    "NodeParameter",
    "NodeSettings",
    "SettingsSchema",
    "any_value",
    "check_node_value",
    "model_parameters",
    "model_value_from_ros",
    "non_negative",
    "one_of",
    "parameters_of",
    "params_with",
    "positive",
    "real_time_factor",
    "settings_with",
]

MODEL_PREFIX = "model."
S = TypeVar("S", bound="CommonSettings")
_NULL_WORDS = ("null", "none", "~", "")

#: Model parameters that cannot change while the node runs (the schedule is built on them).
RUNTIME_FIXED_MODEL = ("simulation.time_step",)


# --- node settings ---------------------------------------------------------------------------
# Checks in the pcv_sim.params style: value -> None when fine, else the text "what is accepted";
# the rig node's settings (pcv_sim.rig.settings) use them too.


_priority = int_range(0, 99, "an integer 0..99 (0 = normal scheduling)")


def bag_name_check(v: str) -> str | None:
    """record.name: '' or a plain directory name (the emulator and the rig node)."""
    if v and (v in (".", "..") or not all(c.isalnum() or c in "_-." for c in v)):
        return "'' (a timestamped name) or a plain directory name of letters, digits, '_', '-', '.'"
    return None


bag_name_check.accepted = "'' or a plain directory name"     # type: ignore[attr-defined]  # a descriptor's words


_seed = int_range(0, 2**32 - 1, "an integer 0 .. 2^32 - 1")


@dataclass(frozen=True)
class CommonSettings:
    """The settings every node has, declared once (each node's settings class extends it): the
    real-time loop, diagnostics, the rejection log, where a bag goes."""

    wake_period: float = setting(
        1e-3, "s", "real time: the loop wakes every wake_period of the monotonic clock and computes the steps "
        "due", positive, read_only=True)
    late_threshold: float = setting(
        1e-3, "s", "real time: a step is late when the wake that computes it comes more than this after its "
        "scheduled wake", non_negative)
    overrun: str = setting(
        "catch_up", "-", "real time, when the loop falls behind wall time: catch_up computes the backlog at "
        "once (continuous model, samples late by up to max_catchup); skip holds the model over any backlog "
        "beyond one wake period (samples on time, model state jumps)", one_of("catch_up", "skip"), "str")
    max_catchup: float = setting(
        0.05, "s", "real time, overrun catch_up: a backlog longer than this is skipped (model held), not "
        "computed", positive)
    realtime_priority: int = setting(
        0, "-", "real time: 1..99 runs the loop thread under SCHED_FIFO at this priority (needs root or an "
        "rtprio limit); 0 = normal scheduling", _priority, "int", read_only=True)
    diagnostics_period: float = setting(1.0, "s", "wall-clock period of /diagnostics", positive)
    diagnostics_late_fraction: float = setting(
        0.05, "-", "timing status WARN when more than this fraction of the steps of a diagnostics period were "
        "late. A loop sharing its machine with other jobs has 0.2-3 % of its steps late with nothing wrong "
        "(each such sample leaves a little over late_threshold late; a longer stall is diagnostics.max_lag's "
        "and a skip is always warned about); 5 % is above that noise and means the loop is short of CPU "
        "for a sustained part of the period", _fraction, name="diagnostics.late_fraction")
    diagnostics_max_lag: float = setting(
        0.01, "s", "timing status WARN when the model lagged wall time by more than this at a wake within the "
        "period (a sample then leaves that late)", positive, name="diagnostics.max_lag")
    reject_log_period: float = setting(
        1.0, "s", "at most one log line per input topic per this period for rejected inputs (all are counted)",
        non_negative)
    faults_enabled: bool = setting(
        False, "-", "take fault commands on the `faults` topic; off unless asked, since any node on the ROS "
        "domain could then break the bench (sensor and physical faults, pcv_sim.device.faults); each command is "
        "logged with its publisher's node name", any_value,
        "bool", name="faults.enabled", read_only=True)
    seed: int = setting(0, "-", "seed of the sensor-noise faults (a run repeats bit for bit)", _seed, "int",
                        read_only=True)
    frame_id: str = setting("load_port", "-", "header.frame_id of the valves' pressure samples", any_value, "str")
    lockstep: bool = setting(
        True, "-", "simulated time: publish the samples of a period, then wait for one duty_cycle command of every "
        "valve (or one lockstep/command) before computing the next period (deterministic bit for bit)", any_value,
        "bool", read_only=True)
    real_time_factor: float = setting(
        0.0, "-", "simulated time without lockstep: model seconds per wall second; 0 or inf = as fast as possible",
        convert=real_time_factor)
    allow_unknown_parameters: bool = setting(
        False, "-", "false: a parameter name nobody declares (a typo, a key of another node in a shared params "
        "file) stops the node at start (exit 2); true: warn and ignore it", any_value, "bool", read_only=True)
    record_enabled: bool = setting(
        False, "-", "record the device's inputs (on change, at the step they act) and outputs to a rosbag2/MCAP bag "
        "from the start (the device at rest) until SIGINT/SIGTERM; the rig's: every valve under its namespace, the "
        "cylinder, the fault commands and its events", any_value, "bool", name="record.enabled", read_only=True)
    record_name: str = setting(
        "", "-", "bag directory name; '' = <node name>[_<namespace>]_YYYYmmdd-HHMMSS; an existing bag is never "
        "overwritten", bag_name_check, "str", name="record.name", read_only=True)
    record_directory: str = setting(
        ".", "-", "directory the bag is created in (made if missing; ~ expanded)", any_value, "str",
        name="record.directory", read_only=True)
    record_split_size_mb: float = setting(
        0.0, "MB", "start a new .mcap file of the bag at this size (10^6 bytes); 0 = one file", non_negative,
        name="record.split_size_mb", read_only=True)

    def check_loop(self) -> None:
        """max_catchup against wake_period (ParameterError)."""
        if self.max_catchup < self.wake_period:
            raise ParameterError(f"max_catchup: got {self.max_catchup!r}; accepted is a number >= wake_period "
                                 f"({self.wake_period:g} s)")

    @property
    def catchup_bound(self) -> float:
        """s of backlog the real-time loop computes rather than skips (see `overrun`)."""
        return self.max_catchup if self.overrun == "catch_up" else self.wake_period


def _record_signals(name: str, v: Any) -> tuple[str, ...]:
    if isinstance(v, str):                    # -p record.signals:=pressure,duty_cycle
        v = [x.strip() for x in v.split(",") if x.strip()]
    if not isinstance(v, (list, tuple)) or not all(isinstance(x, str) for x in v):
        raise ParameterError(f"{name}: got {v!r}; accepted is a list of signal names, e.g. "
                             f"[{', '.join(RECORDABLE)}]")
    try:
        return check_signals(v)
    except BagError as err:
        raise ParameterError(f"{name}: {err}") from None


@dataclass(frozen=True)
class NodeSettings(CommonSettings):
    """The emulator's parameters: each declared once, with default, unit, description, check, read-only."""

    time_mode: str = setting(
        "real", "-", "real: model time follows the wall clock (hardware in the loop), or an external /clock "
        "with use_sim_time; simulated: model time decoupled, /clock published (controller CI)",
        one_of("real", "simulated"), "str", read_only=True)
    publish_rate: float = setting(
        1000.0, "Hz", "rate of pressure/current/spool_position samples (in model time); its period must be a "
        "whole multiple of the model step", positive)
    watchdog_timeout: float = watchdog_parameter("watchdog_timeout")
    safe_duty: float = watchdog_parameter("safe_duty")
    valve_config: str = setting(
        "", "-", "valve model YAML; '' = the shipped config/valve.yaml", any_value, "str", read_only=True)
    record_signals: tuple[str, ...] = setting(
        RECORDABLE, "-", "signals to record: inputs on change (the duty as the model used it), outputs at "
        "record.rate_hz", name="record.signals", read_only=True, convert=_record_signals)
    record_rate_hz: float = setting(
        1000.0, "Hz", "output samples in the bag (model time); 10000 = every 0.1 ms model step; the period must "
        "be a whole multiple of the model step", positive, name="record.rate_hz", read_only=True)

    def check(self, params: ValveParams) -> NodeSettings:
        """Cross-checks against the model (step multiples, duty range); returns self or raises."""
        dt = params.simulation.time_step
        try:
            steps_per(1.0 / self.publish_rate, dt, what=f"publish period 1/publish_rate = 1/{self.publish_rate:g}")
            steps_per(self.wake_period, dt, what="wake_period")
            steps_per(1.0 / self.record_rate_hz, dt, what=f"record.rate_hz {self.record_rate_hz:g}: record period")
        except ValueError as err:
            raise ParameterError(str(err)) from None
        self.check_loop()
        try:
            check_duty(self.safe_duty, params.command.duty_range)
        except ValueError as err:
            raise ParameterError(f"safe_duty: {err}") from None
        return self

    def sample_every(self, dt: float) -> int:
        """Model steps per published sample."""
        return steps_per(1.0 / self.publish_rate, dt, what="publish period")

    def record_every(self, dt: float) -> int:
        """Model steps per recorded output sample."""
        return steps_per(1.0 / self.record_rate_hz, dt, what="record period")


@dataclass(frozen=True)
class NodeParameter:
    """One node parameter as the node declares it (derived from its settings dataclass' field)."""

    name: str
    attr: str            # the settings field
    default: Any         # as a ROS parameter value (lists, not tuples)
    unit: str
    description: str
    read_only: bool
    meta: Mapping[str, Any]

    def check(self, name: str, value: Any) -> Any:
        return check_value(name, self.meta, value)

    @property
    def is_float(self) -> bool:
        return bool(self.meta["kind"] == "float")

    @property
    def described(self) -> str:
        """Its doc and the range it accepts, from its declaration ("...; accepted 0 .. 60"), as a
        node's parameter descriptor and --help say it."""
        accepted = accepted_words(self.meta).replace("\\|", "|")      # a table's escaped bar
        return f"{self.description}; accepted {accepted}" if accepted else self.description


def parameters_of(settings: type) -> tuple[NodeParameter, ...]:
    """The parameters a node declares, one per field of its settings dataclass (`setting(...)`): the
    node's own first, then those every node has (`CommonSettings`)."""
    common = {f.name for f in dataclasses.fields(CommonSettings)}
    return tuple(
        NodeParameter(f.metadata["name"] or f.name, f.name, list(f.default) if isinstance(f.default, tuple)
                      else f.default, f.metadata["unit"], f.metadata["description"], f.metadata["read_only"],
                      f.metadata)
        for f in sorted(dataclasses.fields(settings), key=lambda f: f.name in common))


class SettingsSchema(Generic[S]):
    """Every node's settings the one way: the parameters derived from a settings dataclass (what the
    node declares, its --help), one value checked by name, the settings made from checked values and
    changed at run time. `more` ends the unknown-name message (what else the node accepts)."""

    def __init__(self, settings: type[S], more: str = "") -> None:
        self.settings = settings
        self.parameters = parameters_of(settings)
        self.by_name = {p.name: p for p in self.parameters}
        self.more = more

    def check(self, name: str, value: Any) -> Any:
        """Convert and check one parameter; ParameterError naming it if refused."""
        spec = self.by_name.get(name)
        if spec is None:
            raise ParameterError(f"unknown parameter {name!r}; accepted are: {', '.join(self.by_name)}{self.more}")
        return spec.check(name, value)

    def settings_from(self, values: Mapping[str, Any]) -> S:
        """Settings from checked values keyed by parameter name (record.rate_hz, ...)."""
        return self.settings(**{self.by_name[k].attr: v for k, v in values.items()})

    def with_changes(self, settings: S, changes: Mapping[str, Any]) -> S:
        """A copy of settings with parameters changed, each checked (not yet cross-checked)."""
        return dataclasses.replace(settings, **{self.by_name[k].attr if k in self.by_name else k:  # type: ignore[type-var]
                                                self.check(k, v) for k, v in changes.items()})


SCHEMA = SettingsSchema(NodeSettings, f" and {MODEL_PREFIX}<section>.<key>")
NODE_PARAMETERS = SCHEMA.parameters
check_node_value = SCHEMA.check
settings_with = SCHEMA.with_changes


# --- model parameters ------------------------------------------------------------------------


@dataclass(frozen=True)
class ModelParameter:
    name: str            # model.<section>.<key>
    section: str
    key: str
    kind: str            # pcv_sim.params field kind: float, int, str, float_or_null, vectorN, ...
    unit: str
    source: str
    value: Any           # as a ROS parameter value


_EXPOSED_KINDS = ("float", "int", "str", "float_or_null", "float_or_equivalent")


def _exposed(kind: str) -> bool:
    return kind in _EXPOSED_KINDS or kind.startswith("vector")


def model_value_to_ros(value: Any) -> Any:
    if value is None:
        return "null"
    if isinstance(value, (tuple, list)):
        return [float(v) for v in value]
    return value


def model_value_from_ros(kind: str, value: Any) -> Any:
    """A ROS parameter value in the model's YAML form (validation is params_from_mapping's job)."""
    if kind == "float_or_null" and (value is None or (isinstance(value, str) and value.strip().lower() in _NULL_WORDS)):
        return None
    if kind.startswith("vector") and not isinstance(value, (str, bytes)) and hasattr(value, "__iter__"):
        return list(value)
    return value


def model_parameters(params: ValveParams) -> list[ModelParameter]:
    """Every model parameter exposed as a ROS parameter, with its present value."""
    out = []
    mapping = params_to_mapping(params)
    for sec_field in dataclasses.fields(params):
        section = sec_field.name
        for f in dataclasses.fields(getattr(params, section)):
            kind = f.metadata.get("kind", "float")
            if not _exposed(kind):
                continue
            out.append(ModelParameter(
                f"{MODEL_PREFIX}{section}.{f.name}", section, f.name, kind, f.metadata.get("unit", ""),
                f.metadata.get("source", ""), model_value_to_ros(mapping[section][f.name])))
    return out


def params_with(params: ValveParams, changes: Mapping[str, Any], *, runtime: bool = False) -> ValveParams:
    """params with `model.<section>.<key>` values changed, validated as a whole (so that related
    values, e.g. both spool areas, can change together). ParameterError names what is wrong."""
    kinds = {p.name: p.kind for p in model_parameters(params)}
    mapping = params_to_mapping(params)
    for name, value in changes.items():
        if name not in kinds:
            raise ParameterError(f"unknown model parameter {name!r}; accepted are {MODEL_PREFIX}<section>.<key> "
                                 f"for the scalar and vector keys of the valve YAML (e.g. {MODEL_PREFIX}spool.mass)")
        dotted = name[len(MODEL_PREFIX):]
        if runtime and dotted in RUNTIME_FIXED_MODEL:
            raise ParameterError(f"{name} is fixed while the node runs (the real-time schedule is built on it): "
                                 "restart the node with the new value")
        section, key = dotted.split(".", 1)
        mapping[section][key] = model_value_from_ros(kinds[name], value)
    # Keys are named as the ROS parameters (model.spool.mass); cross-field rules name section.key.
    return params_from_mapping(mapping, origin=None, prefix=MODEL_PREFIX)
