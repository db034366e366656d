"""A simulated or recorded time series of the valve's signals (SI units)."""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

__all__ = ["Trajectory"]


@dataclass(frozen=True)
class Trajectory:
    t: np.ndarray               # s
    duty: np.ndarray            # duty seen by the model (after the rate limiter), 0..1
    current: np.ndarray         # A
    pressure: np.ndarray        # Pa
    spool_position: np.ndarray  # m

    @staticmethod
    def signals() -> tuple[str, ...]:
        """The signals' names (the fields after the time), in order."""
        return tuple(f.name for f in fields(Trajectory))[1:]

    def at(self, t: float) -> dict[str, float]:
        """Signals linearly interpolated at time t."""
        return {name: float(np.interp(t, self.t, getattr(self, name))) for name in self.signals()}

    def resample(self, t: np.ndarray) -> Trajectory:
        return Trajectory(t, *(np.interp(t, self.t, getattr(self, n)) for n in self.signals()))
