"""Controllers for the valve-option scenarios: Python callables `controller(t, measurements)`.

`DutyHold` commands fixed duties (open loop: a valve whose coil heats draws less current at
the same duty, so its pressure falls, docs/model.md R33). `PressureHold` closes a PI loop on each
valve's measured pressure (the duty rises as the coil's resistance does and holds the pressure).

Values take units (`160 bar`, `90 %`); a bare number is SI. Measurements (SI): `left.pressure`
(Pa), ... A missing key is a dropped sample: the controller holds its last duty.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from pcv_sim.units import quantity

__all__ = ["DutyHold", "PressureHold"]


class DutyHold:
    """Each valve named at its duty, every period (`DutyHold(left="90 %", right="90 %")`)."""

    def __init__(self, **duties: Any) -> None:
        if not duties:
            raise ValueError("DutyHold: no valve given; accepted is valve=duty, e.g. left='90 %'")
        self.duties = {v: quantity(d, "fraction", f"controller_params.{v}") for v, d in duties.items()}

    def __call__(self, t: float, m: Mapping[str, float]) -> dict[str, float]:
        return dict(self.duties)


class PressureHold:
    """A PI per valve on its pressure: duty = start + kp e + ki integral(e dt), e = target - pressure
    in bar (gains per bar and per bar s), clamped to 0 .. 1 (the integral stops at the clamp)."""

    def __init__(self, target: Any, valves: tuple[str, ...] = ("left", "right"), start: Any = 0.9,
                 kp: float = 2e-3, ki: float = 0.05, period: float = 1e-3) -> None:
        self.target = quantity(target, "pressure", "controller_params.target", role="pressure")
        self.start = quantity(start, "fraction", "controller_params.start")
        self.valves, self.kp, self.ki, self.period = tuple(valves), kp, ki, period
        self.integral = dict.fromkeys(self.valves, 0.0)
        self.duty = dict.fromkeys(self.valves, self.start)

    def __call__(self, t: float, m: Mapping[str, float]) -> dict[str, float]:
        for v in self.valves:
            p = m.get(f"{v}.pressure")
            if p is None:
                continue
            e = (self.target - p) / 1e5
            i = self.integral[v] + self.ki * e * self.period
            duty = self.start + self.kp * e + i
            if 0.0 <= duty <= 1.0:
                self.integral[v] = i
            self.duty[v] = min(max(duty, 0.0), 1.0)
        return dict(self.duty)
