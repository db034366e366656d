"""The rig's parameters (`config/rig.yaml`): its timing, its valves (each from its own valve YAML)
and the steering cylinder, validated on load like the valve YAML.

    rig:       time_step (s), control_period (s), watchdog_timeout (s, 0 = off; default 2),
               safe_duty (0..1; default 0): the watchdog's, declared once for every device
               (`pcv_sim.params.WatchdogParams`), so a rig and the emulator agree
    valves:    name -> {config: valve YAML (relative to the rig file; '' = the shipped one),
                        chamber: a | b | none, initial_duty: 0..1}
               exactly one valve per cylinder chamber; any number with `chamber: none` (a valve
               on its own dead-ended load volume, circuit.load_volume, no load flow)
    cylinder:  `pcv_sim.plant.params.CylinderParams`

Unknown keys, wrong types and values outside their range are refused with a `ParameterError`
naming the key and what is accepted.

A valve's keys can be changed over its YAML without editing the file (`ValveChanges`, as a
scenario's `valves:` overlay and a campaign's variants do): `valve_with` writes them into the
file's mapping and validates the result as the file itself would be, `load_rig(valve_changes=)`
builds the rig with them.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeAlias

from pcv_sim.errors import ParameterError, PcvSimError
from pcv_sim.params import (
    DEFAULT_CONFIG,
    ValveParams,
    fraction,
    load_params,
    one_of,
    parameter,
    params_from_mapping,
    plausible_range,
    read_yaml,
    section_from_mapping,
    watchdog_parameter,
)
from pcv_sim.plant.params import CylinderParams

__all__ = ["DEFAULT_RIG", "RigParams", "SlotSettings", "TimingParams", "ValveChanges", "ValveSlot", "load_rig",
           "read_rig_files", "rig_from_mapping", "valve_data_with", "valve_with"]

DEFAULT_RIG = Path(__file__).resolve().parents[2] / "config" / "rig.yaml"
CHAMBERS = ("a", "b")
NO_CHAMBER = "none"
#: Keys of a valve YAML changed over the file: (section, key) -> the value as the YAML would hold it.
ValveChanges: TypeAlias = Mapping[tuple[str, str], Any]


@dataclass(frozen=True)
class TimingParams:
    time_step: float = parameter("s", "the fixed integration step of the whole rig (valves + cylinder)",
                                 plausible_range(1e-6, 1e-3))
    control_period: float = parameter("s", "samples to the controller and its commands, every period", plausible_range(1e-4, 1.0))
    watchdog_timeout: float = watchdog_parameter("watchdog_timeout")       # every device's (and its default)
    safe_duty: float = watchdog_parameter("safe_duty")


@dataclass(frozen=True, kw_only=True)
class SlotSettings:
    """One entry of `valves:` as written in the rig YAML."""

    config: str = parameter("-", "valve YAML, relative to the rig file ('' = the shipped one)", kind="str", default="")
    chamber: str = parameter("-", "the cylinder chamber its load port feeds; none: its own dead-ended load volume",
                             one_of(*CHAMBERS, NO_CHAMBER), kind="str")
    initial_duty: float = parameter("-", "duty fraction at the start", fraction, default=0.0)


@dataclass(frozen=True)
class ValveSlot:
    """One valve of the rig: its name (the namespace), its parameters and the chamber it feeds."""

    name: str
    params: ValveParams
    chamber: str
    initial_duty: float
    config: str


@dataclass(frozen=True)
class RigParams:
    timing: TimingParams
    valves: tuple[ValveSlot, ...]
    cylinder: CylinderParams

    @property
    def steps_per_period(self) -> int:
        return round(self.timing.control_period / self.timing.time_step)

    def valve(self, name: str) -> ValveSlot:
        for v in self.valves:
            if v.name == name:
                return v
        raise ParameterError(f"no valve {name!r} in the rig; valves: {', '.join(v.name for v in self.valves)}")


def _slot(name: Any, raw: Any, base: Path, params: ValveParams | None = None) -> ValveSlot:
    path = f"valves.{name}"
    if not isinstance(name, str) or not name.isidentifier():
        raise ParameterError(f"valves: name {name!r}; accepted is an identifier (letters, digits, _), "
                             "the valve's namespace (left, right)")
    slot = section_from_mapping(SlotSettings, raw, path, defaults=True)
    config = slot.config
    if params is None:
        params = load_params(base / config if config else None)
    return ValveSlot(name, params, slot.chamber, slot.initial_duty, config)


def rig_from_mapping(data: Any, *, origin: str = "rig", base: Path | None = None,
                     valve_params: Mapping[str, ValveParams] | None = None) -> RigParams:
    """Build RigParams from a nested mapping (as loaded from YAML); valve configs relative to `base`.
    `valve_params` (valve name -> parameters) stand in for those valves' config files, checked
    against the rig like a loaded file (a campaign's variant of a valve)."""
    base = base or DEFAULT_RIG.parent
    sections = ("rig", "valves", "cylinder")
    try:
        if not isinstance(data, Mapping):
            raise ParameterError(f"the top level must be a mapping of sections ({', '.join(sections)})")
        unknown = sorted(str(k) for k in data if k not in sections)
        if unknown:
            raise ParameterError(f"unknown section(s) {unknown}; accepted are: {', '.join(sections)}")
        missing = [s for s in sections if s not in data]
        if missing:
            raise ParameterError(f"missing section(s) {missing}")
        timing = section_from_mapping(TimingParams, data["rig"], "rig", defaults=True)
        steps = timing.control_period / timing.time_step
        if abs(steps - round(steps)) > 1e-9 * steps:
            raise ParameterError(f"rig.control_period={timing.control_period} s: accepted is a whole number of "
                                 f"rig.time_step={timing.time_step} s")
        raw_valves = data["valves"]
        if not isinstance(raw_valves, Mapping) or not raw_valves:
            raise ParameterError(f"valves: got {raw_valves!r}; accepted is a mapping name -> "
                                 "{config, chamber, initial_duty}")
        valves = tuple(_slot(k, v, base, (valve_params or {}).get(k)) for k, v in raw_valves.items())
        for chamber in CHAMBERS:
            feeding = [v.name for v in valves if v.chamber == chamber]
            if len(feeding) != 1:
                raise ParameterError(f"valves: chamber {chamber} is fed by {feeding or 'no valve'}; accepted is "
                                     "exactly one valve per cylinder chamber")
        for v in valves:
            if abs(v.params.simulation.time_step - timing.time_step) > 1e-15:
                raise ParameterError(f"valves.{v.name}: its simulation.time_step {v.params.simulation.time_step} s "
                                     f"differs from rig.time_step {timing.time_step} s; accepted is the same step")
        if len({v.params.simulation.model for v in valves}) != 1:
            raise ParameterError("valves: all valves must run the same simulation.model (one integrator for the rig)")
        cylinder = section_from_mapping(CylinderParams, data["cylinder"], "cylinder")
    except ParameterError as err:
        raise ParameterError(f"{origin}: {err}") from None
    return RigParams(timing, valves, cylinder)


def _installed_default() -> Path:
    """The shipped rig YAML, from the source tree or an ament install (share/pcv_sim/config)."""
    if DEFAULT_RIG.is_file():
        return DEFAULT_RIG
    try:
        from ament_index_python.packages import get_package_share_directory

        return Path(get_package_share_directory("pcv_sim")) / "config" / "rig.yaml"
    except Exception:
        return DEFAULT_RIG


def valve_data_with(data: Mapping[str, Any], changes: ValveChanges) -> dict[str, Any]:
    """A valve YAML's mapping with `changes` written in (only the sections written to are copied;
    a section the file lacks is made, for the loader to name)."""
    out = dict(data)
    for (section, key), value in changes.items():
        old = out.get(section)
        out[section] = {**(old if isinstance(old, Mapping) else {}), key: value}
    return out


def valve_with(data: Mapping[str, Any], changes: ValveChanges, *, origin: str | None,
               prefix: str = "") -> ValveParams:
    """The parameters of a valve YAML's mapping with `changes` written in, validated as the file
    itself would be (ParameterError naming `<prefix>section.key`)."""
    return params_from_mapping(valve_data_with(data, changes), origin=origin, prefix=prefix)


def read_rig_files(path: str | Path | None = None, *, error: type[PcvSimError] = ParameterError
                   ) -> tuple[Path, Any, dict[str, Any]]:
    """The rig YAML (default: config/rig.yaml) as written: its path, its mapping and each valve's
    YAML mapping by valve name (the entries `rig_from_mapping` would refuse are left to it); a
    file that cannot be read, is not YAML or holds a key twice raises `error`."""
    p = Path(path) if path is not None else _installed_default()
    data = read_yaml(p, "rig file", error, unique=True)
    valves = data.get("valves") if isinstance(data, Mapping) else None
    valve_data: dict[str, Any] = {}
    for name, slot in (valves.items() if isinstance(valves, Mapping) else ()):
        config = slot.get("config") if isinstance(slot, Mapping) else None
        if config is None or isinstance(config, str):
            valve_data[str(name)] = read_yaml(p.parent / config if config else DEFAULT_CONFIG,
                                              f"valve {name}'s YAML", error, unique=True)
    return p, data, valve_data


def load_rig(path: str | Path | None = None, *, valve_changes: Mapping[str, ValveChanges] | None = None,
             where: str = "valves") -> RigParams:
    """Load and validate a rig YAML file (default: config/rig.yaml); `valve_changes` (valve name ->
    its changes) are written over those valves' YAML, and a refused one is named
    `<where>.<valve>: section.key`."""
    if not valve_changes:
        p = Path(path) if path is not None else _installed_default()
        return rig_from_mapping(read_yaml(p, "rig file"), origin=str(p), base=p.parent)
    p, data, valve_data = read_rig_files(path)
    unknown = sorted(set(valve_changes) - set(valve_data))
    if unknown:
        raise ParameterError(f"{where}: no valve {', '.join(map(repr, unknown))} in the rig {p}; valves: "
                             f"{', '.join(valve_data)}")
    params = {name: valve_with(valve_data[name], changes, origin=f"{where}.{name}")
              for name, changes in valve_changes.items() if changes}
    return rig_from_mapping(data, origin=str(p), base=p.parent, valve_params=params)
