"""The campaign file: a scenario and what varies over it, validated before any variant runs.

    name: step_tolerances            # optional (default: the file name)
    scenario: step.yaml              # relative to this file, or the scenario inline (a mapping)
    sweep:                           # a grid: each key's values as a list or {from, to, steps}
      parameters:
        left.spool.spring_preload: [1.9, 2.0, 2.1]          # N
        cylinder.mass: {from: 40.0, to: 60.0, steps: 3}     # kg
      combine: product               # product (default: every combination) or zip (same lengths)
    monte_carlo:
      samples: 500
      seed: 1
      sampling: random               # random (default) or latin_hypercube (scipy.stats.qmc)
      parameters:                    # mean: the nominal value unless given; sd / tolerance in SI or "N%"
        valves.spool.spring_preload: {distribution: normal, sd: 2.5%, truncate: 5%}
        valves.solenoid.coil_resistance: {distribution: uniform, tolerance: 3%}
        valves.fluid.bulk_modulus: {distribution: uniform, low: 9.0e+8, high: 1.1e+9, tied: true}
    faults:                          # a matrix: every kind x target x onset
      kinds: [coil_open, supply_drop]
      targets: [left, right]
      onsets: [0.5, 1.0]             # s
      values: {supply_drop: {pressure: 8.0e+6}}   # the values a kind takes (SI)
      clear_after: 0.3               # optional: the fault is cleared this long after its onset (s)
      at_onset: [scenario.assertions[0].at]       # scenario values that follow the onset
    sensitivity: {...}               # alone: SALib's Sobol or Morris design (pcv_sim.campaign.sensitivity)
    gate: {pass_rate: 0.99}          # exit 0 when at least this fraction of variants passes (default 1.0)
    worst: 5                         # the worst variants whose own scenario reports the report links

Varied keys: `pcv_sim.campaign.targets`. A nominal value written with a unit (a scenario's
`20 mm`) is taken in SI, and the other numbers of its distribution may carry a unit of the same
kind; the variants' values are SI. A normal distribution is truncated at `truncate`
(+-N% of the nominal, +-x in SI, or [low, high]); `tied: true` draws one value for every valve of
a `valves.` key (default: each valve its own). Every combination of the sections present is a
variant (faults outermost, Monte Carlo innermost), and variant k's values are a pure function of
(file, k). A bad file raises `CampaignError` naming the key and what is accepted.
"""

from __future__ import annotations

import hashlib
import json
import math
import pickle
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pcv_sim.campaign.sensitivity import METHODS, Dimension, Sensitivity
from pcv_sim.campaign.sensitivity import size as sensitivity_size
from pcv_sim.campaign.targets import Base, CampaignError, Target, load_base, parse_target, scenario_path
from pcv_sim.device.faults import CYLINDER, CYLINDER_FAULTS, SENSOR_FAULTS, VALVE_FAULTS
from pcv_sim.errors import ParameterError, PcvSimError
from pcv_sim.keys import check_keys
from pcv_sim.params import (
    at_least,
    between,
    check_mapping,
    check_si,
    check_value,
    int_range,
    non_empty,
    one_of,
    parameter,
    read,
    read_yaml,
)
from pcv_sim.units import UnitError, quantity, value_kind

__all__ = ["Campaign", "CampaignKeys", "Distribution", "DistributionKeys", "FaultMatrix", "FaultsKeys", "GateKeys",
           "MonteCarlo", "MonteCarloKeys", "RangeKeys", "SensitivityKeys", "SensitivityParameterKeys", "Sweep",
           "SweepKeys", "campaign_from_mapping", "load_campaign"]

_MAX_VARIANTS = 1_000_000
DISTRIBUTIONS = ("normal", "uniform")
SAMPLINGS = ("random", "latin_hypercube")
_FAULT_KINDS = (*VALVE_FAULTS, *CYLINDER_FAULTS, *SENSOR_FAULTS)
_SI_OR_UNIT = "SI, or with a unit of the nominal value's kind"
_RELATIVE = "SI, with a unit, or N% of the nominal value"


# --- the keys of a campaign file, declared once (pcv_sim.params); the loader below reads them -----


@dataclass(frozen=True, kw_only=True)
class SweepKeys:
    parameters: Mapping[str, Any] = parameter("-", "key -> values (a list or {from, to, steps})", non_empty,
                                              kind="mapping")
    combine: str = parameter("-", "product (every combination) or zip (lists of one length)",
                             one_of("product", "zip"), kind="str", default="product")


@dataclass(frozen=True, kw_only=True)
class RangeKeys:
    """A sweep's values as a grid: `steps` values from `from` to `to`."""

    start: float = parameter("-", "the first value (SI)", kind="float", name="from")
    stop: float = parameter("-", "the last value (SI)", kind="float", name="to")
    steps: int = parameter("-", "the number of values", int_range(1, 100_000), kind="int")


@dataclass(frozen=True, kw_only=True)
class MonteCarloKeys:
    samples: int = parameter("-", "the number of variants", int_range(1, _MAX_VARIANTS), kind="int")
    seed: int = parameter("-", "the draws' seed", int_range(0, 2**63 - 1), kind="int", default=0)
    sampling: str = parameter("-", "random, or latin_hypercube (scipy.stats.qmc)", one_of(*SAMPLINGS), kind="str",
                              default="random")
    parameters: Mapping[str, Any] = parameter("-", "key -> {distribution, ...}", non_empty, kind="mapping")


@dataclass(frozen=True, kw_only=True)
class DistributionKeys:
    """A Monte Carlo parameter's distribution (normal: mean, sd, truncate; uniform: low and high,
    or tolerance)."""

    distribution: str = parameter("-", "normal or uniform", one_of(*DISTRIBUTIONS), kind="str")
    mean: Any = parameter("-", f"normal: the mean ({_SI_OR_UNIT}; default: the nominal value)", kind="any",
                          default=None)
    sd: Any = parameter("-", f"normal: the standard deviation > 0 ({_RELATIVE})", kind="any", default=None)
    truncate: Any = parameter("-", f"normal: truncated at mean +- this ({_RELATIVE}) or at [low, high]", kind="any",
                              default=None)
    low: Any = parameter("-", f"uniform: the lower bound ({_SI_OR_UNIT})", kind="any", default=None)
    high: Any = parameter("-", f"uniform: the upper bound ({_SI_OR_UNIT})", kind="any", default=None)
    tolerance: Any = parameter("-", f"uniform: the nominal value +- this ({_RELATIVE})", kind="any", default=None)
    tied: bool = parameter("-", "one draw for every valve of a valves.<section>.<key> (default: each its own)",
                           kind="bool", default=False)


@dataclass(frozen=True, kw_only=True)
class FaultsKeys:
    kinds: list[str] = parameter("-", "of fault kinds (pcv_sim.device.faults)", non_empty, kind="list",
                                 item=parameter("-", "a fault's kind", one_of(*_FAULT_KINDS), kind="str"))
    targets: list[str] = parameter("-", "of targets: valves, cylinder, measured signals (left.pressure)", non_empty,
                                   kind="list")
    onsets: list[float] = parameter("s", "of onsets within the scenario's duration", non_empty, kind="list",
                                    item=parameter("s", "an onset", kind="time"))
    values: Mapping[str, Any] | None = parameter("-", "kind -> {key: value}: the values a kind takes (SI, or with a unit)",
                                                 kind="mapping", default=None)
    clear_after: float | None = parameter("s", "the fault is cleared this long after its onset",
                                          at_least(0.0, "a time", strict=True), kind="time", default=None)
    at_onset: list[str] | None = parameter("-", "of scenario values that follow the onset (scenario.<path>)",
                                           kind="list", default=None)


@dataclass(frozen=True, kw_only=True)
class SensitivityKeys:
    method: str = parameter("-", "sobol or morris (SALib)", one_of(*METHODS), kind="str")
    samples: int = parameter("-", "N: sobol N (D + 2) variants (N a power of 2), morris N (D + 1)",
                             int_range(2, 1 << 16), kind="int")
    seed: int = parameter("-", "the design's seed", int_range(0, 2**32 - 1), kind="int", default=0)
    levels: int = parameter("-", "morris: the grid's levels", int_range(2, 100), kind="int", default=4)
    parameters: Mapping[str, Any] = parameter("-", "key -> {low, high} or {tolerance}", non_empty, kind="mapping")


@dataclass(frozen=True, kw_only=True)
class SensitivityParameterKeys:
    low: Any = parameter("-", f"the lower bound ({_SI_OR_UNIT})", kind="any", default=None)
    high: Any = parameter("-", f"the upper bound ({_SI_OR_UNIT})", kind="any", default=None)
    tolerance: Any = parameter("-", f"the nominal value +- this ({_RELATIVE})", kind="any", default=None)
    tied: bool = parameter("-", "one dimension for every valve of a valves.<section>.<key>", kind="bool",
                           default=False)


@dataclass(frozen=True, kw_only=True)
class GateKeys:
    pass_rate: float = parameter("-", "exit 0 when at least this fraction of the variants passes",
                                 between(0.0, 1.0, "a fraction"), kind="fraction", default=1.0)


@dataclass(frozen=True, kw_only=True)
class CampaignKeys:
    """The top level of a campaign file."""

    name: str | None = parameter("-", "the campaign's name (default: the file name)", non_empty, kind="str",
                                 default=None)
    scenario: Any = parameter("-", "the scenario: its file, relative to this one, or inline (a mapping)", kind="any")
    sweep: SweepKeys | None = parameter("-", "a grid of values", kind="section", section=SweepKeys, default=None)
    monte_carlo: MonteCarloKeys | None = parameter("-", "tolerances drawn from distributions", kind="section",
                                                   section=MonteCarloKeys, default=None)
    faults: FaultsKeys | None = parameter("-", "a matrix: every kind x target x onset", kind="section",
                                          section=FaultsKeys, default=None)
    sensitivity: SensitivityKeys | None = parameter("-", "alone: SALib's Sobol or Morris design", kind="section",
                                                    section=SensitivityKeys, default=None)
    gate: GateKeys | None = parameter("-", "when the campaign passes", kind="section", section=GateKeys,
                                      default=None)
    worst: int = parameter("-", "the worst variants whose own scenario reports the report links",
                           int_range(0, 1000), kind="int", default=5)


@dataclass(frozen=True)
class Sweep:
    parameters: tuple[tuple[Target, tuple[Any, ...]], ...]
    combine: str                           # product | zip


@dataclass(frozen=True)
class Distribution:
    kind: str                              # normal | uniform
    mean: float                            # normal
    sd: float
    low: float                             # uniform: its bounds; normal: the truncation (-inf, inf: none)
    high: float
    tied: bool


@dataclass(frozen=True)
class MonteCarlo:
    samples: int
    seed: int
    sampling: str
    parameters: tuple[tuple[Target, tuple[Distribution, ...]], ...]   # one distribution per column


@dataclass(frozen=True)
class FaultMatrix:
    cells: tuple[tuple[str, str, float], ...]    # (kind, target, onset): the kinds x targets that fit x onsets
    values: Mapping[str, Mapping[str, float]]
    clear_after: float | None
    at_onset: tuple[tuple[str | int, ...], ...]


@dataclass(frozen=True)
class Campaign:
    name: str
    path: Path
    base: Base
    sweep: Sweep | None
    monte_carlo: MonteCarlo | None
    faults: FaultMatrix | None
    pass_rate: float                       # the gate
    worst: int
    digest: str                            # of everything a variant depends on (for --resume)
    sensitivity: Sensitivity | None = None  # alone: no sweep, monte_carlo or faults beside it

    @property
    def size(self) -> int:
        return self.faults_size * self.sweep_size * self.monte_carlo_size

    @property
    def faults_size(self) -> int:
        return len(self.faults.cells) if self.faults else 1

    @property
    def sweep_size(self) -> int:
        s = self.sweep
        if s is None:
            return 1
        lengths = [len(v) for _, v in s.parameters]
        return lengths[0] if s.combine == "zip" else math.prod(lengths)

    @property
    def monte_carlo_size(self) -> int:
        """The variants of the innermost design: Monte Carlo samples, or the sensitivity's."""
        if self.sensitivity is not None:
            return sensitivity_size(self.sensitivity)
        return self.monte_carlo.samples if self.monte_carlo else 1


_VALUE = parameter("-", "a number in SI or a value with its unit (e.g. 20 mm)", kind="value").metadata


def _si(where: str, v: Any, kind: str) -> float:
    """A number (SI) or a value with a unit of `kind` ("20 mm"; any unit when `kind` is "number",
    the nominal value having been written without one) in SI."""
    return float(check_value(where, _VALUE, v, of=value_kind(v) or "number" if kind == "number" else kind))


def _nominal(where: str, target: Target, nominal: Any) -> tuple[float, str]:
    """The nominal value of a varied key in SI, and the kind its unit names ("number": none)."""
    kind = value_kind(nominal) or "number"
    if not isinstance(nominal, bool) and isinstance(nominal, (int, float, str)):
        try:
            return quantity(nominal, kind, where), kind
        except UnitError:
            pass
    raise CampaignError(f"{where}: the nominal value of {target.key} is {nominal!r}; accepted is a numeric key (a "
                        "number, or a value with its unit such as 20 mm)")


def _relative(where: str, v: Any, nominal: float, kind: str = "number") -> float:
    """A number in SI, a value with a unit of `kind`, or 'N%' of the nominal value (its magnitude)."""
    if isinstance(v, str) and v.strip().endswith("%"):
        try:
            pct = float(v.strip()[:-1])
        except ValueError:
            pct = math.nan
        if not math.isfinite(pct) or pct < 0:
            raise CampaignError(f"{where}: got {v!r}; accepted is a percentage >= 0 of the nominal value (e.g. 5%)")
        return abs(nominal) * pct / 100.0
    return _si(where, v, kind)


def _values(where: str, raw: Any) -> tuple[Any, ...]:
    if isinstance(raw, Mapping):
        spec = check_mapping(RangeKeys, raw, where)
        lo, hi, n = (read(RangeKeys, spec, k, where) for k in ("from", "to", "steps"))
        if n == 1:
            return (lo,)
        return tuple(lo + (hi - lo) * k / (n - 1) for k in range(n))
    if not isinstance(raw, list) or not raw:
        raise CampaignError(f"{where}: got {raw!r}; accepted is a non-empty list of values or {{from, to, steps}}")
    for k, v in enumerate(raw):
        if isinstance(v, (Mapping, list)) or v is None:
            raise CampaignError(f"{where}[{k}]: got {v!r}; accepted is a number (SI) or a name")
    return tuple(raw)


def _check_value(base: Base, column: str, value: Any, where: str) -> None:
    """The loaders' own validation of one value (range, type, what the rest of the file allows)."""
    try:
        base.scenario_for({column: value})
    except PcvSimError as err:
        raise CampaignError(f"{where}: {column} = {value!r}: {err}") from None


def _sweep(raw: Any, base: Base) -> Sweep:
    spec = check_mapping(SweepKeys, raw, "sweep")
    combine = read(SweepKeys, spec, "combine", "sweep")
    out = []
    for key, raw_values in read(SweepKeys, spec, "parameters", "sweep").items():
        where = f"sweep.parameters.{key}"
        target = parse_target(key, base, "sweep.parameters")
        values = _values(where, raw_values)
        for v in sorted(set(values), key=repr):
            for column in target.columns:
                _check_value(base, column, v, where)
        out.append((target, values))
    if combine == "zip" and len({len(v) for _, v in out}) > 1:
        raise CampaignError("sweep.combine: zip needs lists of one length; got "
                            + ", ".join(f"{t.key}: {len(v)}" for t, v in out))
    return Sweep(tuple(out), combine)


def _distribution(where: str, raw: Any, target: Target, nominal: Any) -> Distribution:
    spec = check_mapping(DistributionKeys, raw, where)
    kind = read(DistributionKeys, spec, "distribution", where)
    nominal, unit_kind = _nominal(where, target, nominal)
    tied = read(DistributionKeys, spec, "tied", where)
    if tied and target.kind != "valve":
        raise CampaignError(f"{where}.tied: only for a key of every valve (valves.<section>.<key>)")
    if kind == "normal":
        for k in ("low", "high", "tolerance"):
            if k in spec:
                raise CampaignError(f"{where}.{k}: not for a normal distribution; accepted: mean, sd, truncate, tied")
        if "sd" not in spec:
            raise CampaignError(f"{where}: normal needs sd (SI, or a percentage of the nominal value)")
        mean = _si(f"{where}.mean", spec.get("mean", nominal), unit_kind)
        sd = _relative(f"{where}.sd", spec["sd"], mean, unit_kind)
        if sd <= 0:
            raise CampaignError(f"{where}.sd: got {spec['sd']!r}; accepted is a standard deviation > 0")
        lo, hi = -math.inf, math.inf
        t = spec.get("truncate")
        if isinstance(t, list):
            if len(t) != 2:
                raise CampaignError(f"{where}.truncate: got {t!r}; accepted is [low, high] (SI) or +-x / N%")
            lo, hi = _si(f"{where}.truncate[0]", t[0], unit_kind), _si(f"{where}.truncate[1]", t[1], unit_kind)
        elif t is not None:
            half = _relative(f"{where}.truncate", t, mean, unit_kind)
            lo, hi = mean - half, mean + half
        if not lo < mean < hi:
            raise CampaignError(f"{where}.truncate: bounds {lo:g} .. {hi:g}; accepted are bounds with the mean "
                                f"{mean:g} strictly between them (low < high)")
        return Distribution(kind, mean, sd, lo, hi, tied)
    for k in ("mean", "sd", "truncate"):
        if k in spec:
            raise CampaignError(f"{where}.{k}: not for a uniform distribution; accepted: low and high, or tolerance")
    lo, hi = _bounds(where, spec, nominal, unit_kind)
    return Distribution(kind, (lo + hi) / 2, 0.0, lo, hi, tied)


def _bounds(where: str, spec: Mapping[str, Any], nominal: float, kind: str) -> tuple[float, float]:
    """A range as `low` and `high`, or as the nominal value +- `tolerance`."""
    if "tolerance" in spec:
        if "low" in spec or "high" in spec:
            raise CampaignError(f"{where}: accepted is tolerance or low and high, not both")
        half = _relative(f"{where}.tolerance", spec["tolerance"], nominal, kind)
        lo, hi = nominal - half, nominal + half
    else:
        if "low" not in spec or "high" not in spec:
            raise CampaignError(f"{where}: accepted are low and high (SI, or with a unit), or tolerance (SI, with a "
                                "unit, or N% of the nominal value)")
        lo, hi = _si(f"{where}.low", spec["low"], kind), _si(f"{where}.high", spec["high"], kind)
    if not lo < hi:
        raise CampaignError(f"{where}: bounds {lo:g} .. {hi:g}; accepted is low < high")
    return lo, hi


def _monte_carlo(raw: Any, base: Base) -> MonteCarlo:
    spec = check_mapping(MonteCarloKeys, raw, "monte_carlo")
    samples, seed, sampling, params = (read(MonteCarloKeys, spec, k, "monte_carlo")
                                       for k in ("samples", "seed", "sampling", "parameters"))
    out = []
    for key, raw_d in params.items():
        where = f"monte_carlo.parameters.{key}"
        target = parse_target(key, base, "monte_carlo.parameters")
        dists = tuple(_distribution(where, raw_d, target, n) for n in target.nominals)
        out.append((target, dists))
    return MonteCarlo(samples, seed, sampling, tuple(out))


_ONSET = FaultsKeys.__dataclass_fields__["onsets"].metadata["item"]


def _faults(raw: Any, base: Base) -> FaultMatrix:
    spec = check_mapping(FaultsKeys, raw, "faults")
    kinds, targets, raw_onsets, values, clear, at_onset_raw = (
        read(FaultsKeys, spec, k, "faults") for k in ("kinds", "targets", "onsets", "values", "clear_after", "at_onset"))
    duration = base.scenario.duration
    onsets = tuple(check_si(f"faults.onsets[{j}]", _ONSET, t, check=between(
        0.0, duration, "a time within the scenario's duration")) for j, t in enumerate(raw_onsets))
    values = check_keys("faults.values", values or {}, _FAULT_KINDS)
    at_onset = []
    for j, key in enumerate(at_onset_raw or ()):
        if not isinstance(key, str) or not key.startswith("scenario."):
            raise CampaignError(f"faults.at_onset[{j}]: got {key!r}; accepted is scenario.<path> (e.g. "
                                "scenario.assertions[0].at)")
        parse_target(key, base, f"faults.at_onset[{j}]")
        at_onset.append(scenario_path(key.partition(".")[2]))
    for j, target in enumerate(targets):
        if not any(fault_applies(kind, target, base.valves) for kind in kinds):
            raise CampaignError(f"faults.targets[{j}]: {target!r} takes none of the kinds listed; accepted are the "
                                f"valves ({', '.join(base.valves)}) for valve faults, {CYLINDER} for "
                                f"{', '.join(CYLINDER_FAULTS)}, a measured signal (left.pressure...) for sensor faults")
    cells = tuple((kind, target, t) for kind in kinds for target in targets
                  if fault_applies(kind, target, base.valves) for t in onsets)
    matrix = FaultMatrix(cells, {str(k): dict(v) for k, v in values.items()}, clear, tuple(at_onset))
    # every kind on every target, through the scenario's own validation (fault values, targets)
    for kind, target, t in cells:
        if t in (onsets[0], onsets[-1]):
            try:
                base.scenario_for({}, fault_entries(matrix, kind, target, t, duration),
                                  dict.fromkeys(matrix.at_onset, t))
            except PcvSimError as err:
                raise CampaignError(f"faults: {kind} on {target} at {t:g} s: {err}") from None
    return matrix


def fault_entries(matrix: FaultMatrix, kind: str, target: str, onset: float, duration: float) -> list[dict[str, Any]]:
    """The timeline entries of a matrix cell, as the scenario file would hold them: the fault and,
    with clear_after, its clearing (when that falls within the duration)."""
    out: list[dict[str, Any]] = [{"t": onset, "fault": kind, "target": target, **matrix.values.get(kind, {})}]
    if matrix.clear_after is not None and onset + matrix.clear_after <= duration:
        out.append({"t": onset + matrix.clear_after, "clear": kind, "target": target})
    return out


def fault_applies(kind: str, target: str, valves: tuple[str, ...]) -> bool:
    """Whether a matrix cell is a fault at all: valve kinds on valves, cylinder kinds on the
    cylinder, sensor kinds on a measured signal (`left.pressure`)."""
    if kind in VALVE_FAULTS:
        return target in valves
    if kind in CYLINDER_FAULTS:
        return target == CYLINDER
    return isinstance(target, str) and "." in target


def _sensitivity(raw: Any, base: Base) -> Sensitivity:
    spec = check_mapping(SensitivityKeys, raw, "sensitivity")
    method, samples, seed, levels, params = (read(SensitivityKeys, spec, k, "sensitivity")
                                             for k in ("method", "samples", "seed", "levels", "parameters"))
    if method == "sobol" and samples & (samples - 1):
        raise CampaignError(f"sensitivity.samples: got {samples}; accepted for sobol is a power of 2 (Sobol' "
                            "sequences keep their balance only then), e.g. 64")
    dims: list[Dimension] = []
    for key, raw_p in params.items():
        where = f"sensitivity.parameters.{key}"
        target = parse_target(key, base, "sensitivity.parameters")
        p = check_mapping(SensitivityParameterKeys, raw_p, where)
        tied = read(SensitivityParameterKeys, p, "tied", where)
        if tied and target.kind != "valve":
            raise CampaignError(f"{where}.tied: true only for a key of every valve (valves.<section>.<key>)")
        bounds = []
        for col, raw_nominal in zip(target.columns, target.nominals):
            nominal, unit_kind = _nominal(where, target, raw_nominal)
            lo, hi = _bounds(where, p, nominal, unit_kind)
            for v in (lo, hi):
                _check_value(base, col, v, where)
            bounds.append((lo, hi))
        if tied:
            dims.append(Dimension(key, target.columns, *bounds[0]))
        else:
            dims += [Dimension(col, (col,), lo, hi) for col, (lo, hi) in zip(target.columns, bounds)]
    return Sensitivity(method, samples, seed, levels, tuple(dims))


def campaign_from_mapping(data: Any, path: Path) -> Campaign:
    """A validated Campaign from the file's mapping (`path`: the file, for relative paths)."""
    try:
        check_mapping(CampaignKeys, data, "campaign", "")
        base = load_base(data["scenario"], path)
        sweep = _sweep(data["sweep"], base) if data.get("sweep") is not None else None
        mc = _monte_carlo(data["monte_carlo"], base) if data.get("monte_carlo") is not None else None
        faults = _faults(data["faults"], base) if data.get("faults") is not None else None
        sens = _sensitivity(data["sensitivity"], base) if data.get("sensitivity") is not None else None
        if sens is not None and (sweep or mc or faults):
            raise CampaignError("sensitivity: accepted alone (its design is SALib's: no sweep, monte_carlo or faults "
                                "beside it)")
        columns = [c for s in (sweep, mc) if s for t, _ in s.parameters for c in t.columns]
        twice = sorted({c for c in columns if columns.count(c) > 1})
        if twice:
            raise CampaignError(f"{', '.join(twice)}: varied in more than one place (sweep, monte_carlo); accepted "
                                "is each key once")
        gate = read(CampaignKeys, data, "gate")
        pass_rate = gate.pass_rate if gate is not None else GateKeys().pass_rate
        worst = read(CampaignKeys, data, "worst")
        name = read(CampaignKeys, data, "name") or path.stem
    except (CampaignError, ParameterError) as err:
        raise CampaignError(f"{path}: {err}") from None
    digest = hashlib.sha256(pickle.dumps((json.dumps(data, sort_keys=True, default=str), base.scenario_data,
                                          base.rig_data, base.valve_data))).hexdigest()[:16]
    c = Campaign(name, path, base, sweep, mc, faults, pass_rate, worst, digest, sens)
    if c.size > _MAX_VARIANTS:
        raise CampaignError(f"{path}: {c.size} variants; accepted is at most {_MAX_VARIANTS}")
    return c


def load_campaign(path: str | Path) -> Campaign:
    return campaign_from_mapping(read_yaml(path, "campaign", CampaignError), Path(path))
