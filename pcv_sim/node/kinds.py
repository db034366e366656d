"""What differs between the package's executables, as data: the `emulator` (one valve on its own
load volume, `pcv_sim.device.valve.ValveDevice`) and the `rig` (valves on the steering cylinder,
`pcv_sim.rig.Rig`) are one node class (`pcv_sim.node.device_node.DeviceNode`) over a `NodeKind`:
the node's name, its settings schema, how the device is made from them, where its parameters come
from (the valve YAML and `model.*` parameters; the rig YAML), its bag recorder and the start-up log
line (the diagnostics are every device's: `pcv_sim.device.diagnostics`). Topics, inputs and
signals are the device's own names (`pcv_sim.io.topics`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from typing import Any

from pcv_sim.device.recording import BagLayout, DeviceRecorder
from pcv_sim.device.settings import MODEL_PREFIX, NodeSettings, SettingsSchema, model_parameters, params_with
from pcv_sim.device.settings import SCHEMA as EMULATOR_SCHEMA
from pcv_sim.device.valve import ValveDevice
from pcv_sim.errors import CommandError, ParameterError
from pcv_sim.params import ValveParams, accepted_words, check_value, load_params
from pcv_sim.rig import Rig, load_rig
from pcv_sim.rig.params import RigParams, TimingParams
from pcv_sim.rig.settings import SCHEMA as RIG_SCHEMA
from pcv_sim.rig.settings import RigNodeSettings
from pcv_sim.simulation.duty import check_duty

__all__ = ["EMULATOR", "RIG", "RIG_PREFIX", "RIG_RUNTIME", "NodeKind"]


@dataclass(frozen=True)
class NodeKind:
    """One executable's node: see the module docstring. The callables take the node (`DeviceNode`),
    its settings, the device or the device's parameters; none holds state."""

    name: str                                                 # the node's name
    schema: SettingsSchema[Any]                               # its settings
    unknown_hint: str                                         # what the unknown-parameter message adds
    clock_advice: str                                         # what to do instead of a second /clock
    device_parameters: Callable[[Any, Any], Any]              # (node, settings) -> the device's parameters
    make_device: Callable[[Any, Any], Any]                    # (settings, parameters) -> the device
    with_changes: Callable[[Any, dict[str, Any]], Any]        # (parameters, run-time changes) -> parameters
    prepare: Callable[[Any, Any], Any]                        # (device, parameters) -> what install needs (worker)
    install: Callable[[Any, Any], str]                        # (device, prepared) -> what changed (the loop)
    apply_settings: Callable[[Any, Any], None]                # (device, settings): changed settings into it
    chambers: Callable[[Any], dict[str, str]]                 # device -> valve: chamber (a | b)
    recorder: Callable[[Any], Callable[..., Any]]             # node -> the recorder's maker (`open_recorder`)
    describe: Callable[[Any], str]                            # node -> the start-up log line


def _mode(node: Any) -> str:
    s = node.settings
    if node.simulated:
        return f"simulated time, {'lockstep' if s.lockstep else f'free running (factor {s.real_time_factor:g})'}"
    return "time from an external /clock (use_sim_time)" if node.external_clock else "real time"


def _faults(s: Any) -> str:
    return f"fault topic {'on (faults.enabled)' if s.faults_enabled else 'off (faults.enabled: false)'}"


# --- the emulator ------------------------------------------------------------------------------------


def _valve_parameters(node: Any, settings: NodeSettings) -> ValveParams:
    """The valve YAML (valve_config), with the model parameters declared from it (model.<section>.<key>)
    applied."""
    params = load_params(settings.valve_config or None)
    changes = {}
    for mp in model_parameters(params):
        value = node.declare(mp.name, mp.value, f"[{mp.unit}] {mp.source}", is_float=mp.kind.startswith("float"))
        if value != mp.value:
            changes[mp.name] = value
    return params_with(params, changes) if changes else params


def _valve_device(s: NodeSettings, params: ValveParams) -> ValveDevice:
    return ValveDevice(params, safe_duty=s.safe_duty, watchdog_timeout=s.watchdog_timeout,
                       sample_every=s.sample_every(params.simulation.time_step), seed=s.seed)


def _valve_settings(dev: ValveDevice, s: NodeSettings) -> None:
    dev.set_watchdog_timeout(s.watchdog_timeout)
    dev.set_safe_duty(s.safe_duty)
    dev.sample_every = s.sample_every(dev.dt)
    dev.sensors.period = dev.sample_every * dev.dt      # a delay fault counts samples


def _valve_recorder(node: Any) -> Callable[..., Any]:
    """The emulator's bag: the selected roles at model steps (record.rate_hz), the fault commands with faults.enabled."""
    s, dev = node.settings, node.device
    return partial(_device_recorder, dev, every=s.record_every(dev.dt), record=s.record_signals, frame_id=s.frame_id,
                   faults=s.faults_enabled, events=False)


def _device_recorder(dev: Any, directory: str, *, namespace: str, name: str | None, writing: Any,
                     **layout: Any) -> DeviceRecorder:
    """`open_recorder`'s maker: the device's bag layout in the node's namespace, and its recorder."""
    return DeviceRecorder(directory, BagLayout.of(dev, namespace=namespace, **layout), name=name, dt_ns=dev.dt_ns,
                          namespace=namespace, writing=writing)


def _describe_valve(node: Any) -> str:
    s, dev = node.settings, node.device
    return (f"{_mode(node)}, samples at {s.publish_rate:g} Hz, model step {dev.dt * 1e3:g} ms "
            f"({dev.sim.integrator}), watchdog {s.watchdog_timeout:g} s -> duty {s.safe_duty:g}, valve config "
            f"{s.valve_config or 'shipped default'}, {_faults(s)}")


EMULATOR = NodeKind(
    name="emulator",
    schema=EMULATOR_SCHEMA,
    unknown_hint=(f"; model parameters are {MODEL_PREFIX}<section>.<key> for the scalar and vector keys of the valve "
                  "YAML (matrix fits: use valve_config); allow_unknown_parameters: true ignores unknown names"),
    clock_advice=("run this emulator with use_sim_time:=true (time_mode real) to follow the other clock, or simulate "
                  "several valves in one process (the multi-valve rig)"),
    device_parameters=_valve_parameters,
    make_device=_valve_device,
    with_changes=partial(params_with, runtime=True),
    prepare=lambda dev, params: dev.prepare(params),
    install=lambda dev, ready: f"model restarted at rest at the present operating point: {dev.install(ready)}",
    apply_settings=_valve_settings,
    chambers=lambda dev: {},
    recorder=_valve_recorder,
    describe=_describe_valve,
)


# --- the rig -----------------------------------------------------------------------------------------


#: The rig YAML's keys the rig takes while it runs, declared as `rig.<key>` from their one declaration
#: (`pcv_sim.rig.params.TimingParams`), the YAML's value their default.
RIG_RUNTIME = ("watchdog_timeout", "safe_duty")
RIG_PREFIX = "rig."
_TIMING = {f.name: f for f in dataclasses.fields(TimingParams)}


def _rig_parameters(node: Any, settings: RigNodeSettings) -> RigParams:
    """The rig YAML (rig_config) with this node's control_period (when set) and its `rig.<key>` parameters."""
    rig = settings.rig_params(load_rig(settings.rig_config or None))
    changes = {}
    for key in RIG_RUNTIME:
        f, value = _TIMING[key], getattr(rig.timing, key)
        got = node.declare(f"{RIG_PREFIX}{key}", value, f"{f.metadata['description']}; accepted {accepted_words(f.metadata)} "
                           f"[{f.metadata['unit']}] (default: the rig YAML's rig.{key})", is_float=True)
        if got != value:
            changes[f"{RIG_PREFIX}{key}"] = got
    return _rig_with(rig, changes) if changes else rig


def _rig_with(rig: RigParams, changes: dict[str, Any]) -> RigParams:
    """`rig` with `rig.<key>` values (RIG_RUNTIME), each checked by its declaration and the duty
    ranges of the valves; ParameterError naming what is wrong."""
    values = {}
    for name, value in changes.items():
        key = name.removeprefix(RIG_PREFIX)
        if key not in RIG_RUNTIME:
            raise ParameterError(f"{name}: the rig takes {', '.join(RIG_PREFIX + k for k in RIG_RUNTIME)} while it "
                                 "runs; its physics is set in the rig YAML at start")
        values[key] = check_value(name, _TIMING[key].metadata, value)
    rig = dataclasses.replace(rig, timing=dataclasses.replace(rig.timing, **values))
    for v in rig.valves:
        try:
            check_duty(rig.timing.safe_duty, v.params.command.duty_range)
        except CommandError as err:
            raise ParameterError(f"{RIG_PREFIX}safe_duty: {err} (valve {v.name})") from None
    return rig


def _rig_install(rig: Rig, params: RigParams) -> str:
    rig.set_watchdog_timeout(params.timing.watchdog_timeout)
    rig.set_safe_duty(params.timing.safe_duty)
    rig.params = params
    return (f"watchdog {params.timing.watchdog_timeout:g} s (0 = off) -> duty {params.timing.safe_duty:g}, from the "
            "present step on")


def _rig_recorder(node: Any) -> Callable[..., Any]:
    """The rig's bag: every sample as published, the chambers, the fault commands and the rig's events."""
    rig = node.device
    return partial(_device_recorder, rig, chambers=node.kind.chambers(rig))


def _describe_rig(node: Any) -> str:
    s, rig = node.settings, node.device
    p = rig.params
    return (f"rig: valves {', '.join(f'{v.name} (chamber {v.chamber})' for v in p.valves)} + cylinder, "
            f"step {rig.dt * 1e3:g} ms, {_mode(node)}, samples and commands every "
            f"{p.timing.control_period * 1e3:g} ms, watchdog {p.timing.watchdog_timeout:g} s, "
            f"rig config {s.rig_config or 'shipped default'}, {_faults(s)}")


RIG = NodeKind(
    name="rig",
    schema=RIG_SCHEMA,
    unknown_hint=(f"; {', '.join(RIG_PREFIX + k for k in RIG_RUNTIME)} override the rig YAML's, the rest of the "
                  "physics is set in the rig YAML (rig_config)"),
    clock_advice="stop the other simulation, or run this rig with time_mode real",
    device_parameters=_rig_parameters,
    make_device=lambda s, params: Rig(params, seed=s.seed),
    with_changes=_rig_with,
    prepare=lambda rig, params: params,
    install=_rig_install,
    apply_settings=lambda dev, s: None,
    chambers=lambda rig: {v.name: v.chamber for v in rig.params.valves if v.chamber in ("a", "b")},
    recorder=_rig_recorder,
    describe=_describe_rig,
)
