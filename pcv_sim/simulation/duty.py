"""Duty-cycle inputs: validation, the fall-rate limiter (Sec. 3.2) and step profiles."""

from __future__ import annotations

import math
from dataclasses import dataclass

from pcv_sim.errors import CommandError

__all__ = ["DutyProfile", "FallRateLimiter", "check_duty"]


def check_duty(value: float, duty_range: tuple[float, ...] = (0.0, 1.0)) -> float:
    """A duty command as a fraction within `duty_range` (default 0..1), or CommandError saying
    what is accepted (and, for 2..100, that 70 means 0.7: the command is a fraction, not percent)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise CommandError(f"duty cycle {value!r}: accepted is a number, a fraction 0..1")
    v = float(value)
    if not math.isfinite(v):
        raise CommandError(f"duty cycle {value!r} is not finite: accepted is a fraction 0..1")
    if 2.0 <= v <= 100.0:  # reads as percent; 1..2 is more likely a typo than 1-2 %
        raise CommandError(f"duty cycle {v:g} > 1: the command is a fraction 0..1, not percent (did you mean {v / 100:g}?)")
    lo, hi = duty_range
    if not lo <= v <= hi:
        raise CommandError(f"duty cycle {v:g} is out of range: accepted is a fraction {lo:g}..{hi:g}")
    return v


class FallRateLimiter:
    """Limits how fast the duty may fall (1/s); rises pass unchanged. None = off.

    The paper's rig limited decreasing steps so that core and spool stay in contact (Sec. 3.2).
    """

    def __init__(self, rate: float | None, initial: float = 0.0) -> None:
        self.rate = rate
        self.value = initial

    def peek(self, command: float, dt: float) -> float:
        """The duty for the next step of length dt toward `command`, from the last step's `value`."""
        if self.rate is None or command >= self.value:
            return command
        return max(command, self.value - self.rate * dt)

    def update(self, command: float, dt: float) -> float:
        self.value = self.peek(command, dt)
        return self.value


@dataclass(frozen=True)
class DutyProfile:
    """A piecewise-constant duty command: `values[k]` holds from `times[k]` (s) on.

    `effective(t)` applies the fall-rate limiter in continuous time (piecewise linear), the
    input a stiff reference solver sees; `breakpoints` are where that input has kinks.
    """

    times: tuple[float, ...]
    values: tuple[float, ...]
    fall_rate_limit: float | None = None

    def __post_init__(self) -> None:
        if len(self.times) != len(self.values) or not self.times:
            raise CommandError("a duty profile needs as many times as values, at least one")
        if any(b <= a for a, b in zip(self.times, self.times[1:])):
            raise CommandError("duty profile times must increase strictly")
        for v in self.values:
            check_duty(v)

    @classmethod
    def step(cls, start: float, end: float, at: float, fall_rate_limit: float | None = None) -> DutyProfile:
        return cls((0.0, at), (start, end), fall_rate_limit)

    def command(self, t: float) -> float:
        value = self.values[0]
        for tk, vk in zip(self.times, self.values):
            if t >= tk:
                value = vk
        return value

    def _segments(self) -> list[tuple[float, float, float, float]]:
        """(t_start, value_at_start, target, rate) per segment of the limited input."""
        segs = []
        y = self.values[0]
        bounds = [*list(self.times[1:]), math.inf]
        for tk, vk, t_next in zip(self.times, self.values, bounds):
            if self.fall_rate_limit is None or vk >= y:
                segs.append((tk, vk, vk, 0.0))
                y = vk
            else:
                segs.append((tk, y, vk, self.fall_rate_limit))
                y = max(vk, y - self.fall_rate_limit * (t_next - tk)) if math.isfinite(t_next) else vk
        return segs

    def effective(self, t: float) -> float:
        out = self.values[0]
        for tk, y0, target, rate in self._segments():
            if t >= tk:
                out = y0 if rate == 0.0 else max(target, y0 - rate * (t - tk))
        return out

    def breakpoints(self, t_end: float) -> list[float]:
        pts = {0.0, t_end}
        for tk, y0, target, rate in self._segments():
            if tk < t_end:
                pts.add(tk)
                if rate > 0.0:
                    t_done = tk + (y0 - target) / rate
                    if t_done < t_end:
                        pts.add(t_done)
        return sorted(pts)
