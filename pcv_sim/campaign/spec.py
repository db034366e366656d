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
from pcv_sim.errors import PcvSimError
from pcv_sim.keys import check_keys
from pcv_sim.params import read_yaml
from pcv_sim.rig.faults import CYLINDER, CYLINDER_FAULTS, SENSOR_FAULTS, VALVE_FAULTS
from pcv_sim.units import UnitError, quantity, value_kind

__all__ = ["Campaign", "Distribution", "FaultMatrix", "MonteCarlo", "Sweep", "campaign_from_mapping", "load_campaign"]

_TOP = ("name", "scenario", "sweep", "monte_carlo", "faults", "sensitivity", "gate", "worst")
_MAX_VARIANTS = 1_000_000
DISTRIBUTIONS = ("normal", "uniform")
SAMPLINGS = ("random", "latin_hypercube")


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


def _num(where: str, v: Any, what: str = "a finite number") -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise CampaignError(f"{where}: got {v!r}; accepted is {what}")
    return float(v)


def _int(where: str, v: Any, lo: int, hi: int) -> int:
    if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
        raise CampaignError(f"{where}: got {v!r}; accepted is an integer {lo} .. {hi}")
    return v


def _keys(where: str, v: Any, accepted: tuple[str, ...], required: tuple[str, ...] = ()) -> Mapping[str, Any]:
    return check_keys(where, v, accepted, required, CampaignError)


def _si(where: str, v: Any, kind: str) -> float:
    """A number (SI) or a value with a unit of `kind` ("20 mm"; any unit when `kind` is "number",
    the nominal value having been written without one) in SI."""
    if not isinstance(v, str):
        return _num(where, v, "a number in SI or a value with its unit (e.g. 20 mm)")
    try:
        return quantity(v, kind if kind != "number" else value_kind(v) or "number", where)
    except UnitError as err:
        raise CampaignError(str(err)) from None


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
    if isinstance(v, str):
        return _si(where, v, kind)
    return _num(where, v, "a number in SI, a value with its unit or a percentage of the nominal value (e.g. 5%)")


def _values(where: str, raw: Any) -> tuple[Any, ...]:
    if isinstance(raw, Mapping):
        spec = _keys(where, raw, ("from", "to", "steps"), ("from", "to", "steps"))
        lo, hi = _num(f"{where}.from", spec["from"]), _num(f"{where}.to", spec["to"])
        n = _int(f"{where}.steps", spec["steps"], 1, 100_000)
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


def _parameters(section: str, spec: Mapping[str, Any], accepted: str) -> Mapping[str, Any]:
    """A section's `parameters`: a non-empty mapping key -> `accepted`, or CampaignError saying so."""
    params = spec["parameters"]
    if not isinstance(params, Mapping) or not params:
        raise CampaignError(f"{section}.parameters: accepted is a mapping key -> {accepted}")
    return params


def _sweep(raw: Any, base: Base) -> Sweep:
    spec = _keys("sweep", raw, ("parameters", "combine"), ("parameters",))
    combine = spec.get("combine", "product")
    if combine not in ("product", "zip"):
        raise CampaignError(f"sweep.combine: got {combine!r}; accepted is product or zip")
    params = _parameters("sweep", spec, "values (a list or {from, to, steps})")
    out = []
    for key, raw_values in params.items():
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
    spec = _keys(where, raw, ("distribution", "mean", "sd", "truncate", "low", "high", "tolerance", "tied"),
                 ("distribution",))
    kind = spec["distribution"]
    if kind not in DISTRIBUTIONS:
        raise CampaignError(f"{where}.distribution: got {kind!r}; accepted is {' or '.join(DISTRIBUTIONS)}")
    nominal, unit_kind = _nominal(where, target, nominal)
    tied = spec.get("tied", False)
    if not isinstance(tied, bool):
        raise CampaignError(f"{where}.tied: got {tied!r}; accepted is true or false")
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
    spec = _keys("monte_carlo", raw, ("samples", "seed", "sampling", "parameters"), ("samples", "parameters"))
    samples = _int("monte_carlo.samples", spec["samples"], 1, _MAX_VARIANTS)
    seed = _int("monte_carlo.seed", spec.get("seed", 0), 0, 2**63 - 1)
    sampling = spec.get("sampling", "random")
    if sampling not in SAMPLINGS:
        raise CampaignError(f"monte_carlo.sampling: got {sampling!r}; accepted is {' or '.join(SAMPLINGS)}")
    params = _parameters("monte_carlo", spec, "{distribution, ...}")
    out = []
    for key, raw_d in params.items():
        where = f"monte_carlo.parameters.{key}"
        target = parse_target(key, base, "monte_carlo.parameters")
        dists = tuple(_distribution(where, raw_d, target, n) for n in target.nominals)
        out.append((target, dists))
    return MonteCarlo(samples, seed, sampling, tuple(out))


def _faults(raw: Any, base: Base) -> FaultMatrix:
    spec = _keys("faults", raw, ("kinds", "targets", "onsets", "values", "clear_after", "at_onset"),
                 ("kinds", "targets", "onsets"))
    known = (*VALVE_FAULTS, *CYLINDER_FAULTS, *SENSOR_FAULTS)
    lists = {}
    for k in ("kinds", "targets", "onsets"):
        v = spec[k]
        if not isinstance(v, list) or not v:
            raise CampaignError(f"faults.{k}: got {v!r}; accepted is a non-empty list")
        lists[k] = v
    for j, kind in enumerate(lists["kinds"]):
        if kind not in known:
            raise CampaignError(f"faults.kinds[{j}]: got {kind!r}; accepted are {', '.join(known)}")
    duration = base.scenario.duration
    onsets = tuple(_num(f"faults.onsets[{j}]", t, "a time in s") for j, t in enumerate(lists["onsets"]))
    for j, t in enumerate(onsets):
        if not 0.0 <= t <= duration:
            raise CampaignError(f"faults.onsets[{j}]: {t:g} s; accepted is a time in 0 .. {duration:g} s (the "
                                "scenario's duration)")
    values = spec.get("values", {})
    _keys("faults.values", values, known)
    clear = spec.get("clear_after")
    if clear is not None:
        clear = _num("faults.clear_after", clear, "a time in s > 0")
        if clear <= 0:
            raise CampaignError(f"faults.clear_after: got {clear!r}; accepted is a time in s > 0")
    at_onset_raw = spec.get("at_onset", [])
    if not isinstance(at_onset_raw, list):
        raise CampaignError("faults.at_onset: accepted is a list of scenario values (scenario.<path>)")
    at_onset = []
    for j, key in enumerate(at_onset_raw):
        if not isinstance(key, str) or not key.startswith("scenario."):
            raise CampaignError(f"faults.at_onset[{j}]: got {key!r}; accepted is scenario.<path> (e.g. "
                                "scenario.assertions[0].at)")
        parse_target(key, base, f"faults.at_onset[{j}]")
        at_onset.append(scenario_path(key.partition(".")[2]))
    for j, target in enumerate(lists["targets"]):
        if not any(fault_applies(kind, target, base.valves) for kind in lists["kinds"]):
            raise CampaignError(f"faults.targets[{j}]: {target!r} takes none of the kinds listed; accepted are the "
                                f"valves ({', '.join(base.valves)}) for valve faults, {CYLINDER} for "
                                f"{', '.join(CYLINDER_FAULTS)}, a measured signal (left.pressure...) for sensor faults")
    cells = tuple((kind, target, t) for kind in lists["kinds"] for target in lists["targets"]
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
    spec = _keys("sensitivity", raw, ("method", "samples", "seed", "levels", "parameters"), ("method", "samples",
                                                                                            "parameters"))
    method = spec["method"]
    if method not in METHODS:
        raise CampaignError(f"sensitivity.method: got {method!r}; accepted is {' or '.join(METHODS)} (SALib)")
    samples = _int("sensitivity.samples", spec["samples"], 2, 1 << 16)
    if method == "sobol" and samples & (samples - 1):
        raise CampaignError(f"sensitivity.samples: got {samples}; accepted for sobol is a power of 2 (Sobol' "
                            "sequences keep their balance only then), e.g. 64")
    seed = _int("sensitivity.seed", spec.get("seed", 0), 0, 2**32 - 1)
    levels = _int("sensitivity.levels", spec.get("levels", 4), 2, 100)
    params = _parameters("sensitivity", spec, "{low, high} or {tolerance}")
    dims: list[Dimension] = []
    for key, raw_p in params.items():
        where = f"sensitivity.parameters.{key}"
        target = parse_target(key, base, "sensitivity.parameters")
        p = _keys(where, raw_p, ("low", "high", "tolerance", "tied"))
        tied = p.get("tied", False)
        if not isinstance(tied, bool) or (tied and target.kind != "valve"):
            raise CampaignError(f"{where}.tied: accepted is true or false, true only for a key of every valve")
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
        _keys("campaign", data, _TOP, ("scenario",))
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
        gate = _keys("gate", data.get("gate", {}), ("pass_rate",))
        pass_rate = _num("gate.pass_rate", gate.get("pass_rate", 1.0), "a fraction 0 .. 1")
        if not 0.0 <= pass_rate <= 1.0:
            raise CampaignError(f"gate.pass_rate: got {pass_rate!r}; accepted is a fraction 0 .. 1")
        worst = _int("worst", data.get("worst", 5), 0, 1000)
        name = data.get("name", path.stem)
        if not isinstance(name, str) or not name:
            raise CampaignError(f"name: got {name!r}; accepted is a non-empty string")
    except CampaignError as err:
        raise CampaignError(f"{path}: {err}") from None
    digest = hashlib.sha256(pickle.dumps((json.dumps(data, sort_keys=True, default=str), base.scenario_data,
                                          base.rig_data, base.valve_data))).hexdigest()[:16]
    c = Campaign(name, path, base, sweep, mc, faults, pass_rate, worst, digest, sens)
    if c.size > _MAX_VARIANTS:
        raise CampaignError(f"{path}: {c.size} variants; accepted is at most {_MAX_VARIANTS}")
    return c


def load_campaign(path: str | Path) -> Campaign:
    return campaign_from_mapping(read_yaml(path, "campaign", CampaignError), Path(path))
