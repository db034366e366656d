"""Sensor faults: what the controller and the recording see of each measured signal.

The physics is never touched here: `Sensors.measure` maps the true samples of one control period
to the measured ones (`pcv_sim.device.faults` lists the kinds). A dropped sample is NaN in the
array and absent from the controller's measurement; no non-finite value is ever handed out as a
measurement. Noise comes from a seeded generator, so a run repeats bit for bit.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from pcv_sim.device.faults import Fault

__all__ = ["Sensors"]


class Sensors:
    """Sensor faults on `signals`, sampled every `period` s."""

    def __init__(self, signals: tuple[str, ...], period: float, seed: int = 0) -> None:
        self.signals = signals
        self.period = period
        self.seed = seed
        self.reset()

    def reset(self) -> None:
        self._rng = np.random.default_rng(self.seed)
        #: signal index -> kind -> (fault, start time, value at start)
        self._active: dict[int, dict[str, tuple[Fault, float, float]]] = {}
        self._history: deque[np.ndarray] = deque(maxlen=1)
        #: Whether `_history` keeps more than the last sample (a delay fault was active).
        self._keeps = False
        self._last: np.ndarray | None = None

    @property
    def active(self) -> bool:
        return bool(self._active)

    @property
    def keeps_history(self) -> bool:
        """A delay fault has been active: `measure` keeps the samples it needs (call it every period)."""
        return self._keeps

    def add(self, fault: Fault, t: float) -> None:
        j = self.signals.index(fault.target)
        start_value = float(self._last[j]) if self._last is not None else math.nan
        self._active.setdefault(j, {})[fault.kind] = (fault, t, start_value)
        if fault.kind == "delay":
            n = self.delay_periods(fault.values["delay"])
            if self._history.maxlen is None or self._history.maxlen < n + 1:
                self._history = deque(self._history, maxlen=n + 1)
                self._keeps = True

    def clear(self, target: str, kind: str) -> bool:
        j = self.signals.index(target)
        found = self._active.get(j, {}).pop(kind, None) is not None
        if j in self._active and not self._active[j]:
            del self._active[j]
        return found

    def delay_periods(self, delay: float) -> int:
        """A delay in whole control periods (rounded up: a sample is never seen early)."""
        return max(1, math.ceil(delay / self.period - 1e-9))

    def measure(self, t: float, true: np.ndarray) -> np.ndarray:
        """The measured samples at time t for the true samples `true` (not modified)."""
        self._last = true
        if not self._active:
            if self._keeps:
                self._history.append(true.copy())
            return true
        self._history.append(true.copy())
        out = true.copy()
        for j, kinds in self._active.items():
            v = float(true[j])
            if "delay" in kinds:
                n = self.delay_periods(kinds["delay"][0].values["delay"])
                v = float(self._history[max(0, len(self._history) - 1 - n)][j])
            if "freeze" in kinds:
                fault, t0, start = kinds["freeze"]
                if not math.isfinite(start):       # injected before any sample: freeze the first one seen
                    kinds["freeze"] = (fault, t0, v)
                    start = v
                v = start
            if "bias" in kinds:
                v += kinds["bias"][0].values["value"]
            if "drift" in kinds:
                fault, t0, _ = kinds["drift"]
                v += fault.values["rate"] * (t - t0)
            if "noise" in kinds:
                v += float(self._rng.normal(0.0, kinds["noise"][0].values["std"]))
            if "dropout" in kinds or not math.isfinite(v):
                v = math.nan
            out[j] = v
        return out
