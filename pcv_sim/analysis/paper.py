"""Numbers printed in the paper that the model is checked against (not parameters)."""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["WORKING_POINTS", "WORKING_POINT_DUTY", "WorkingPoint"]


@dataclass(frozen=True)
class WorkingPoint:
    name: str
    current: float         # A
    spool_position: float  # m
    pressure: float        # Pa
    branch: str            # where it lies on the 70 % reducing curve (Sec. 5)


# The paper's table "working points for frequency analysis" (Sec. 4.2/5), on the 70 % duty
# pressure-flow curve: point 1 where pressure falls with flow, point 2 where it rises.
WORKING_POINT_DUTY = 0.7
WORKING_POINTS = (
    WorkingPoint("P1", 1.5, -0.0326e-3, 120.4e5, "falling"),
    WorkingPoint("P2", 1.49, 0.2482e-3, 109.6e5, "rising"),
)
