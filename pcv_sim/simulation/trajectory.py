"""A simulated or recorded time series of the valve's signals (SI units)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Trajectory"]


@dataclass(frozen=True)
class Trajectory:
    t: np.ndarray               # s
    duty: np.ndarray            # duty seen by the model (after the rate limiter), 0..1
    current: np.ndarray         # A
    pressure: np.ndarray        # Pa
    spool_position: np.ndarray  # m

    def at(self, t: float) -> dict[str, float]:
        """Signals linearly interpolated at time t."""
        return {
            name: float(np.interp(t, self.t, getattr(self, name)))
            for name in ("duty", "current", "pressure", "spool_position")
        }

    def resample(self, t: np.ndarray) -> Trajectory:
        return Trajectory(
            t,
            *(np.interp(t, self.t, getattr(self, n)) for n in ("duty", "current", "pressure", "spool_position")),
        )
