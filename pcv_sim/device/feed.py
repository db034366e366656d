"""A device's fed inputs: a plain model input (a plant's, a valve's load flow on its own volume)
given as values at steps (`feed`: a profile of a timeline sampled at the control instants),
put into the model inside the compiled calls, one row per step at which any of them changes.
No ROS.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from pcv_sim.device.composition import Composition
from pcv_sim.errors import CommandError

__all__ = ["FedInputs"]


class FedInputs(Composition):
    """The fed inputs of a device (see the module docstring)."""

    def feed(self, name: str, steps: Sequence[int], values: Sequence[float]) -> None:
        """The input `name` (a plant's input, or a valve's load flow on its own volume) takes
        `values[j]` from step `steps[j]` on (increasing steps; one before the present step acts at
        the present step), in place of any earlier feed of it; CommandError for a value `submit`
        refuses. The values are put into the model inside the compiled calls (a profile of the
        timeline, sampled at the control instants); `on_input` hears each one as it acts."""
        fed = self._feedable()
        if name not in fed:
            raise CommandError(f"feed {name!r}: accepted {'is' if len(fed) == 1 else 'are'} {', '.join(fed) or 'none'}")
        st = np.asarray(steps, dtype=np.int64)
        vs = np.asarray(values, dtype=np.float64)
        if st.ndim != 1 or st.shape != vs.shape or np.any(np.diff(st) < 0):
            raise CommandError(f"feed {name}: accepted are as many values as steps, the steps increasing")
        check = self.inputs[name].check
        for v in vs:
            check(float(v))                         # raises, naming the value
        pending = self._pending_feed()
        now = self.sim.steps
        pending[name] = {int(k): float(v) for k, v in zip(np.maximum(st, now), vs)}   # a later value at a step wins
        self._set_feed(pending)

    def _feedable(self) -> dict[str, int]:
        """The inputs `feed` takes (plain model inputs: nothing happens on a change but the value)."""
        out = dict(self._plant_i)
        for k, name in enumerate(self.valve_names):
            if self._flow_i[k] >= 0:
                out[f"{self._prefix[name]}load_flow"] = self._flow_i[k]
        return out

    def _pending_feed(self) -> dict[str, dict[int, float]]:
        """The feed's rows not yet applied, per input: step -> value."""
        out: dict[str, dict[int, float]] = {n: {} for n in self._feed_names}
        for r in range(self._feed_next, len(self._feed_steps)):
            for j, n in enumerate(self._feed_names):
                v = float(self._feed_v[r, j])
                if not math.isnan(v):
                    out[n][self._feed_steps[r]] = v
        return out

    def _set_feed(self, tracks: dict[str, dict[int, float]]) -> None:
        tracks = {n: t for n, t in tracks.items() if t}
        fed = self._feedable()
        self._feed_names = tuple(tracks)
        self._feed_i = np.array([fed[n] for n in tracks], dtype=np.int64)
        self._feed_steps = sorted({k for t in tracks.values() for k in t})
        v = np.full((len(self._feed_steps), len(tracks)), np.nan)
        where = {k: r for r, k in enumerate(self._feed_steps)}
        for j, t in enumerate(tracks.values()):
            for k, x in t.items():
                v[where[k], j] = x
        self._feed_v = np.ascontiguousarray(v)
        self._feed_next = 0

    def _feed_row(self, r: int, step: int) -> None:
        """Row r of the feed is in force from `step` (it is put into the model by the caller or here)."""
        u, hook = self.sim.u, self.on_input
        for j, name in enumerate(self._feed_names):
            v = float(self._feed_v[r, j])
            if not math.isnan(v):
                u[self._feed_i[j]] = v
                if name.endswith("load_flow"):
                    self._load_flow[self._flow_i.index(int(self._feed_i[j]))] = v
                if hook is not None:
                    hook(step, name, v)
        self._feed_next = r + 1
