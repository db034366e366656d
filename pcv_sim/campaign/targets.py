"""What a campaign varies, and how a variant's values land in the scenario it runs.

A varied key names one of:

    left.spool.spring_preload        a valve YAML key (section.key) of the valve `left`
    valves.spool.spring_preload      the same key of every valve of the rig (one column per valve)
    cylinder.mass, rig.safe_duty     a key of the rig YAML (the plant, the rig's timing)
    scenario.timeline[2].t           a value of the scenario file (a fault's onset, target or value,
    scenario.setpoint[1].value       a setpoint, an external force, controller_params...), by its
                                     path in the file; it must be there in the scenario as written

A variant is a mapping column -> value (SI, as the YAML holds it); `Base.scenario(values)` writes
the values into copies of the scenario's, the rig's and the valves' YAML mappings and validates
them with the loaders of those files (`pcv_sim.params`, `pcv_sim.rig.params`,
`pcv_sim.rig.scenario`), so a variant runs exactly what those files, edited by hand, would run.
"""

from __future__ import annotations

import copy
import dataclasses
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pcv_sim.errors import PcvSimError
from pcv_sim.params import ValveParams, read_yaml, validate_section_value
from pcv_sim.plant.params import CylinderParams
from pcv_sim.rig.params import DEFAULT_RIG, TimingParams, read_rig_files, rig_from_mapping, valve_data_with, valve_with
from pcv_sim.rig.scenario import Scenario, scenario_from_mapping

__all__ = ["ALL_VALVES", "FAULT_COLUMNS", "Base", "CampaignError", "Target", "load_base", "parse_target"]

ALL_VALVES = "valves"
#: The columns of a fault matrix's variant: the fault kind, its target and its onset (s).
FAULT_COLUMNS = ("fault.kind", "fault.target", "fault.onset")
_TOKEN = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)|\[(\d+)\]")
_RIG_SECTIONS = {"cylinder": CylinderParams, "rig": TimingParams}


class CampaignError(PcvSimError, ValueError):
    """A campaign file that cannot be run as written (the CLI exits 2)."""


def scenario_path(text: str) -> tuple[str | int, ...]:
    """`timeline[2].t` -> ('timeline', 2, 't'); CampaignError when it is not such a path."""
    out: list[str | int] = []
    pos = 0
    while pos < len(text):
        if out and text[pos] == ".":
            pos += 1
        m = _TOKEN.match(text, pos)
        if m is None:
            raise CampaignError(f"scenario.{text}: not a path into the scenario; accepted is e.g. "
                                "scenario.timeline[0].t, scenario.setpoint[1].value, scenario.controller_params.kp")
        out.append(m.group(1) if m.group(1) is not None else int(m.group(2)))
        pos = m.end()
    if not out or not isinstance(out[0], str):
        raise CampaignError(f"scenario.{text}: accepted is a path starting with a top-level key of the scenario")
    return tuple(out)


def get_path(data: Any, path: tuple[str | int, ...], where: str) -> Any:
    node = data
    for p in path:
        ok = (isinstance(p, int) and isinstance(node, list) and p < len(node)) or (
            isinstance(p, str) and isinstance(node, Mapping) and p in node)
        if not ok:
            raise CampaignError(f"{where}: the scenario has no such value; accepted is the path of a value the "
                                "scenario file holds (e.g. scenario.timeline[0].t)")
        node = node[p]
    return node


def set_path(data: Any, path: tuple[str | int, ...], value: Any) -> None:
    node = data
    for p in path[:-1]:
        node = node[p]
    node[path[-1]] = value


@dataclass(frozen=True)
class Target:
    """A varied key: `kind` valve | plant | scenario; `columns` the concrete keys it sets (a key
    for every valve expands to one per valve) and `nominals` their values in the base files."""

    key: str
    kind: str
    columns: tuple[str, ...]
    nominals: tuple[Any, ...]


@dataclass(frozen=True)
class Base:
    """The scenario as written: its YAML mapping and those of its rig and valves (picklable: a
    worker, local or on a Dask cluster, builds its variants from this)."""

    scenario_data: Mapping[str, Any]
    scenario_file: Path                    # relative paths of the scenario (rig, controller) from here
    rig_data: Mapping[str, Any]
    rig_file: Path
    valve_data: Mapping[str, Mapping[str, Any]]
    scenario: Scenario                     # the base scenario, validated

    @property
    def valves(self) -> tuple[str, ...]:
        return tuple(v.name for v in self.scenario.rig.valves)

    def scenario_for(self, values: Mapping[str, Any], timeline: Sequence[Mapping[str, Any]] = (),
                     at: Mapping[tuple[str | int, ...], Any] | None = None) -> Scenario:
        """The scenario with `values` (column -> value) written into its files, `timeline`
        entries (a fault matrix's) appended to its timeline and `at` (path -> value) written into
        it; PcvSimError naming the key if a loader refuses it."""
        valve_values: dict[str, dict[tuple[str, str], Any]] = {}
        rig_values: dict[tuple[str, str], Any] = {}
        scenario_values: list[tuple[tuple[str | int, ...], Any]] = []
        for column, v in values.items():
            head, _, rest = column.partition(".")
            if head == "scenario":
                scenario_values.append((scenario_path(rest), v))
            elif head in _RIG_SECTIONS:
                rig_values[(head, rest)] = v
            elif head in self.valve_data:
                section, _, key = rest.partition(".")
                valve_values.setdefault(head, {})[(section, key)] = v
            else:
                raise CampaignError(f"{column}: not a column of this campaign")
        rig = self.scenario.rig
        if valve_values or rig_values:
            # the valves the scenario's `valves:` changed (in valve_data) stand in for their files too
            params: dict[str, ValveParams] = {
                name: valve_with(self.valve_data[name], valve_values.get(name, {}), origin=f"valve {name}",
                                 prefix=f"{name}.")
                for name in self.valve_data if name in valve_values or name in self.scenario.valve_changes}
            rig_data = dict(self.rig_data)
            for (section, key), v in rig_values.items():
                rig_data[section] = {**rig_data[section], key: v}
            rig = rig_from_mapping(rig_data, origin=str(self.rig_file), base=self.rig_file.parent, valve_params=params)
        if not scenario_values and not timeline and not at:
            return dataclasses.replace(self.scenario, rig=rig) if rig is not self.scenario.rig else self.scenario
        data = copy.deepcopy(dict(self.scenario_data))
        for path, v in scenario_values:
            set_path(data, path, v)
        if timeline:
            data["timeline"] = [*(data.get("timeline") or []), *(dict(e) for e in timeline)]
        for path, v in (at or {}).items():
            set_path(data, path, v)
        return scenario_from_mapping(data, path=self.scenario_file, rig_params=rig)


def load_base(scenario: Any, campaign_file: Path) -> Base:
    """The campaign's `scenario` (a path relative to the campaign file, or the scenario inline)."""
    if isinstance(scenario, str):
        file = campaign_file.parent / scenario
        data = read_yaml(file, "scenario", CampaignError, unique=True)
    elif isinstance(scenario, Mapping):
        file, data = campaign_file, dict(scenario)
    else:
        raise CampaignError(f"scenario: got {scenario!r}; accepted is the path of a scenario file (relative to the "
                            "campaign file) or the scenario inline (a mapping)")
    try:
        sc = scenario_from_mapping(data, path=file)
    except PcvSimError as err:
        raise CampaignError(f"scenario: {err}") from None
    if sc.ros is not None:
        raise CampaignError("scenario.controller: a ROS controller node; a campaign runs a Python controller "
                            "('module:callable') in each worker: accepted is module:callable")
    rig_file, rig_data, valve_data = read_rig_files((file.parent / data["rig"]) if data.get("rig") else DEFAULT_RIG,
                                                    error=CampaignError)
    valve_data = {name: valve_data_with(d, sc.valve_changes.get(name, {})) for name, d in valve_data.items()}
    return Base(data, file, rig_data, rig_file, valve_data, sc)


def parse_target(key: Any, base: Base, where: str) -> Target:
    """The varied key `key` checked against the base scenario (CampaignError naming `where`)."""
    accepted = ("accepted is <valve>.<section>.<key> (a valve YAML key; valves: "
                f"{', '.join(base.valves)}), {ALL_VALVES}.<section>.<key> (every valve), cylinder.<key>, rig.<key> "
                "or scenario.<path>")
    if not isinstance(key, str) or "." not in key:
        raise CampaignError(f"{where}: key {key!r}; {accepted}")
    head, _, rest = key.partition(".")
    if head == "scenario":
        path = scenario_path(rest)
        nominal = get_path(base.scenario_data, path, f"{where}: {key}")
        if isinstance(nominal, (Mapping, list)):
            raise CampaignError(f"{where}: {key} is a {type(nominal).__name__}; accepted is the path of one value")
        return Target(key, "scenario", (key,), (nominal,))
    if head in _RIG_SECTIONS:
        fields = [f.name for f in dataclasses.fields(_RIG_SECTIONS[head])]
        if rest not in fields:
            raise CampaignError(f"{where}: {key}: unknown key; accepted in {head}: {', '.join(fields)}")
        params = base.scenario.rig.cylinder if head == "cylinder" else base.scenario.rig.timing
        return Target(key, "plant", (key,), (getattr(params, rest),))
    if head == ALL_VALVES and head in base.valves:
        raise CampaignError(f"{where}: {key}: the rig has a valve named {ALL_VALVES!r}, so '{ALL_VALVES}.' is "
                            "ambiguous; rename the valve")
    valves = base.valves if head == ALL_VALVES else (head,) if head in base.valves else None
    if valves is None:
        raise CampaignError(f"{where}: key {key!r}: {head!r} is no valve of the rig; {accepted}")
    section, _, name = rest.partition(".")
    try:
        validate_section_value(section, name, _nominal(base, valves[0], section, name))
    except PcvSimError as err:
        raise CampaignError(f"{where}: {key}: {err}") from None
    return Target(key, "valve", tuple(f"{v}.{rest}" for v in valves),
                  tuple(_nominal(base, v, section, name) for v in valves))


def _nominal(base: Base, valve: str, section: str, name: str) -> Any:
    try:
        return getattr(getattr(base.scenario.rig.valve(valve).params, section), name)
    except AttributeError:
        # an unknown section or key: validate_section_value names what is accepted
        return None
