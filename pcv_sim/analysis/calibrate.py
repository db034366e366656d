"""Working points: the model against the paper's table, and the fit of the shipped calibration.

`pcv-sim working-points` reports; `pcv-sim working-points --fit [--kind ...] [--write]` refits.

The table gives (i, x, p) at two points on the 70 % curve but not their load flows, so each
point is compared in two ways: the model's pressure with the spool at the table's x, and the
model's x (on the table point's branch) at the table's pressure.

Coil current: the table prints 1.50 A at P1 and 1.49 A at P2 at the same 70 % duty, and Sec. 6.1
says the coil resistance was calculated at the stationary points to compensate for its variation
(the coil warms). With ``coil="table"`` (the default) each point runs with its own resistance
R_k = D V / i_k (5.600 ohm at P1, 5.638 ohm at P2), so the model drives the table's current; with
``coil="config"`` both run at the config's resistance (1.500 A).

Which constant closes the balance (`CalibrationKind`): at each point the imbalance can be
expressed as a solenoid-force offset or as the net area that would make the table's (i, x, p) an
equilibrium; `required_constants` computes both per point. ``net_area`` fits
``calibration.net_area`` (the spring preload stays as printed); ``force_offset`` keeps the net
area as printed and carries a constant force offset F (toward +x) in the spring preload
(f_0 - F: Eq. 14's only constant force); ``both`` fits the two, which makes both table pressures
exact. The fits minimise the squared pressure errors at the table's x.
"""

from __future__ import annotations

import dataclasses
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from scipy.optimize import brentq, least_squares

from pcv_sim.analysis.in_force import TABLE1_SPRING_PRELOAD
from pcv_sim.analysis.paper import WORKING_POINT_DUTY, WORKING_POINTS, WorkingPoint
from pcv_sim.analysis.static import balance_pressure, static_point
from pcv_sim.errors import ParameterError
from pcv_sim.model.valve import ValveModel
from pcv_sim.params import ValveParams, replace_param
from pcv_sim.units import MM_PER_M, PA_PER_BAR, bar, lpm

__all__ = [
    "CALIBRATION_KINDS",
    "CalibrationFit",
    "CalibrationKind",
    "CoilMode",
    "WorkingPointResult",
    "compare_working_points",
    "fit_calibration",
    "fit_net_area",
    "point_params",
    "report",
    "required_constants",
    "write_calibration",
]

CalibrationKind = Literal["net_area", "force_offset", "both"]
CALIBRATION_KINDS: tuple[str, ...] = ("net_area", "force_offset", "both")
CoilMode = Literal["table", "config"]


@dataclass(frozen=True)
class WorkingPointResult:
    name: str
    table_current: float
    table_spool_position: float
    table_pressure: float
    model_current: float               # A, steady state at 70 % duty
    model_pressure_at_table_x: float   # Pa
    model_x_at_table_p: float          # m, on the table point's branch (nan if the curve never reaches p)
    load_flow_at_table_x: float        # m^3/s, the load flow that holds the table's x
    branch: str                        # falling or rising, as the model's curve has it at the table x

    @property
    def pressure_error(self) -> float:
        return self.model_pressure_at_table_x - self.table_pressure

    @property
    def position_error(self) -> float:
        return self.model_x_at_table_p - self.table_spool_position

    @property
    def current_error(self) -> float:
        return self.model_current - self.table_current

    def as_dict(self) -> dict[str, float | str]:
        d = dataclasses.asdict(self)
        d.update(pressure_error=self.pressure_error, position_error=self.position_error, current_error=self.current_error)
        return d


def _branch(model: ValveModel, x: float) -> str:
    """Does the pressure fall (falling) or rise (rising) with load flow at x on the 70 % curve?"""
    h = 2e-6
    lo, hi = static_point(model, WORKING_POINT_DUTY, x - h), static_point(model, WORKING_POINT_DUTY, x + h)
    slope = (hi.pressure - lo.pressure) / (hi.load_flow - lo.load_flow)
    return "rising" if slope > 0 else "falling"


def _x_at_pressure(model: ValveModel, wp: WorkingPoint) -> float:
    """x on the table point's branch where the 70 % curve has the table's pressure (nan if none)."""
    def excess(x: float) -> float:
        return static_point(model, WORKING_POINT_DUTY, x).pressure - wp.pressure

    # Search outward from the table's x along its branch: the falling branch lies toward -x,
    # the rising one toward +x of the pressure minimum.
    step = 0.005e-3
    x0 = wp.spool_position
    direction = -1.0 if wp.branch == "falling" else 1.0
    e0 = excess(x0)
    # Move toward higher pressure if the model is low, lower if high.
    if e0 > 0:
        direction = -direction
    x1 = x0
    for _ in range(400):
        x1 = x0 + direction * step
        if not model.x_min <= x1 <= model.x_max:
            return math.nan
        if excess(x1) * e0 <= 0:
            return float(brentq(excess, min(x0, x1), max(x0, x1), xtol=1e-12))
        x0 = x1
    return math.nan


def point_params(params: ValveParams, wp: WorkingPoint, coil: CoilMode = "table") -> ValveParams:
    """The parameters at working point ``wp``: with ``coil="table"`` the coil resistance is the
    one that gives the table's current at the point's duty, R = D V / i (Sec. 6.1)."""
    if coil == "config":
        return params
    if coil != "table":
        msg = f"coil {coil!r}: accepted are 'table' (R = D V / i per point) and 'config'"
        raise ParameterError(msg)
    r = WORKING_POINT_DUTY * params.solenoid.supply_voltage / wp.current
    return replace_param(params, "solenoid.coil_resistance", r)


def compare_working_points(params: ValveParams, coil: CoilMode = "table") -> list[WorkingPointResult]:
    """The model at each of the paper's working points (see the module docstring)."""
    out = []
    for wp in WORKING_POINTS:
        model = ValveModel(point_params(params, wp, coil))
        pt = static_point(model, WORKING_POINT_DUTY, wp.spool_position)
        out.append(WorkingPointResult(
            wp.name, wp.current, wp.spool_position, wp.pressure, pt.current, pt.pressure,
            _x_at_pressure(model, wp), pt.load_flow, _branch(model, wp.spool_position),
        ))
    return out


def required_constants(params: ValveParams, coil: CoilMode = "table") -> list[dict[str, float | str]]:
    """Per working point: the solenoid-force offset (N, toward +x) and the net area (m^2) that
    would each, alone, make the table's (i, x, p) an equilibrium of Eq. 14."""
    rows: list[dict[str, float | str]] = []
    for wp in WORKING_POINTS:
        pp = point_params(params, wp, coil)
        model = ValveModel(pp)
        i = model.steady_current(WORKING_POINT_DUTY)
        offset = -model.static_force(i, wp.spool_position, wp.pressure, model.p_supply)

        def imbalance(area: float, wp: WorkingPoint = wp, pp: ValveParams = pp, i: float = i) -> float:
            m = ValveModel(replace_param(pp, "calibration.net_area", area))
            return m.static_force(i, wp.spool_position, wp.pressure, m.p_supply)

        area = brentq(imbalance, 0.5 * model.a_net, 1.5 * model.a_net, xtol=1e-15)
        rows.append({"name": wp.name, "current_A": i, "force_offset_N": offset, "net_area_m2": area})
    return rows


@dataclass(frozen=True)
class CalibrationFit:
    """A working-point fit: the calibration kind, the fitted values by YAML key, the result."""

    kind: str
    coil: str
    values: dict[str, float | None]        # YAML key -> value (None: null, as printed)
    force_offset_N: float                  # toward +x, 0 unless fitted
    results: list[WorkingPointResult]

    def as_dict(self) -> dict[str, object]:
        return {"kind": self.kind, "coil": self.coil, "values": self.values,
                "force_offset_N": self.force_offset_N, "points": [r.as_dict() for r in self.results]}


def _with(params: ValveParams, area: float | None, offset: float) -> ValveParams:
    p = replace_param(params, "calibration.net_area", area)
    return replace_param(p, "spool.spring_preload", TABLE1_SPRING_PRELOAD - offset)


def fit_calibration(params: ValveParams, kind: CalibrationKind = "net_area", coil: CoilMode = "table") -> CalibrationFit:
    """Fit the calibration constant(s) of ``kind`` to the working-point table: least squares of
    the pressure errors at the table's x (both points). Starts from the printed model (net area
    A_c - A_cc, Table 1's preload); values are rounded to four significant digits, the table's
    own precision."""
    if kind not in CALIBRATION_KINDS:
        msg = f"calibration kind {kind!r}: accepted are {', '.join(CALIBRATION_KINDS)}"
        raise ParameterError(msg)
    printed = _with(params, None, 0.0)
    a0 = printed.net_area

    def residuals(z: np.ndarray) -> np.ndarray:
        area = a0 * z[0] if kind != "force_offset" else None
        offset = float(z[-1]) if kind != "net_area" else 0.0
        p = _with(printed, area, offset)
        out = []
        for wp in WORKING_POINTS:
            m = ValveModel(point_params(p, wp, coil))
            i = m.steady_current(WORKING_POINT_DUTY)
            out.append((balance_pressure(m, i, wp.spool_position, m.p_supply) - wp.pressure) / PA_PER_BAR)
        return np.array(out)

    z0 = {"net_area": [1.0], "force_offset": [0.0], "both": [1.0, 0.0]}[kind]
    lo = {"net_area": [0.8], "force_offset": [-10.0], "both": [0.8, -10.0]}[kind]
    hi = {"net_area": [1.2], "force_offset": [10.0], "both": [1.2, 10.0]}[kind]
    sol = least_squares(residuals, np.array(z0), bounds=(lo, hi), xtol=1e-12, ftol=1e-12, gtol=1e-12)
    area = float(f"{a0 * sol.x[0]:.4g}") if kind != "force_offset" else None
    offset = float(f"{sol.x[-1]:.4g}") if kind != "net_area" else 0.0
    fitted = _with(printed, area, offset)
    values: dict[str, float | None] = {"calibration.net_area": area,
                                       "spool.spring_preload": fitted.spool.spring_preload}
    return CalibrationFit(kind, coil, values, offset, compare_working_points(fitted, coil))


def fit_net_area(params: ValveParams, coil: CoilMode = "table") -> tuple[float, list[WorkingPointResult]]:
    """Least-squares net area over both points' pressure errors at the table's x."""
    fit = fit_calibration(params, "net_area", coil)
    area = fit.values["calibration.net_area"]
    assert area is not None
    return area, fit.results


def _yaml_value(v: float | None) -> str:
    if v is None:
        return "null"
    s = f"{v:.6g}"
    mant, e, exp = s.partition("e")
    return (mant if "." in mant else mant + ".0") + (e + exp if e else "")


def write_calibration(path: Path, values: dict[str, float | None]) -> None:
    """Write ``values`` (YAML key -> value) into the valve YAML at ``path``, keeping its comments."""
    text = path.read_text(encoding="utf-8")
    for key, value in values.items():
        section, _, name = key.partition(".")
        m = re.search(rf"(?ms)^{re.escape(section)}:\s*\n(.*?)(?=^\S|\Z)", text)
        if m is None:
            msg = f"{path}: no section {section!r} to write {key} into"
            raise ParameterError(msg)
        new = _yaml_value(value)
        block, n = re.subn(rf"(?m)^(\s+{re.escape(name)}:[ \t]*)[^#\n]*?([ \t]*(#.*)?)$",
                           lambda mm, new=new: f"{mm.group(1)}{new}{mm.group(2)}", m.group(1), count=1)
        if n != 1:
            msg = f"{path}: expected one '{name}:' line under {section}, found none"
            raise ParameterError(msg)
        text = text[:m.start(1)] + block + text[m.end(1):]
    path.write_text(text, encoding="utf-8")


def report(title: str, results: list[WorkingPointResult]) -> str:
    """The working-point comparison as text lines (bar, mm, L/min)."""
    lines = [title, "  point  i model/table [A]   p at table x: model/table [bar]   "
                    "x at table p: model/table [mm]   q_l [L/min]  branch"]
    for r in results:
        lines.append(
            f"  {r.name:5s}  {r.model_current:.3f}/{r.table_current:.3f}        "
            f"{bar(r.model_pressure_at_table_x):7.2f}/{bar(r.table_pressure):6.1f} ({bar(r.pressure_error):+.2f})     "
            f"{r.model_x_at_table_p * MM_PER_M:+.4f}/{r.table_spool_position * MM_PER_M:+.4f} "
            f"({r.position_error * MM_PER_M:+.4f})   "
            f"{lpm(r.load_flow_at_table_x):7.3f}     {r.branch}"
        )
    return "\n".join(lines)
