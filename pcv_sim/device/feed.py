"""A device's fed inputs: a plain model input (a plant's, a valve's load flow on its own volume,
the duty of a valve without a fall-rate limiter) given as values at steps (`feed`: a profile of a
timeline sampled at the control instants, a recorded timeline), put into the model inside the
compiled calls, one row per step at which any of them changes; and the offline run of such a
timeline (`sample_at`: the signals at given steps, the whole stretch between two queued inputs
in one compiled call). No ROS.
"""

from __future__ import annotations

import math
from bisect import bisect_left
from collections.abc import Callable, Sequence

import numpy as np

from pcv_sim.device.composition import Composition
from pcv_sim.device.spec import ModelFault, Sample
from pcv_sim.errors import CommandError
from pcv_sim.io.topics import DUTY_CYCLE, LOAD_FLOW

__all__ = ["FedInputs"]


class FedInputs(Composition):
    """The fed inputs of a device (see the module docstring)."""

    # What the device's other parts offer (`Device`, `Outputs`): the offline run calls them.
    _due: Callable[[], None]
    _due_step: Callable[..., int]
    _run_rows: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]
    _check_rows: Callable[[np.ndarray, np.ndarray], None]

    def feed(self, name: str, steps: Sequence[int] | np.ndarray, values: Sequence[float] | np.ndarray) -> None:
        """The input `name` (a plant's input, a valve's load flow on its own volume, or the duty of
        a valve without a fall-rate limiter: its commands) takes `values[j]` from step `steps[j]`
        on (increasing steps; one before the present step acts at the present step), in place of
        any earlier feed of it; CommandError for a value `submit` refuses. The values are put into
        the model inside the compiled calls (a profile of the timeline, sampled at the control
        instants); `on_input` hears each one as it acts. A fed duty is a valid command at its step
        (the watchdog hears it, as from `submit`)."""
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
        """The inputs `feed` takes (plain model inputs: nothing happens on a change but the value,
        a duty's command and watchdog bookkeeping aside)."""
        out = dict(self._plant_i)
        for k, name in enumerate(self.valve_names):
            if self._flow_i[k] >= 0:
                out[f"{self._prefix[name]}{LOAD_FLOW}"] = self._flow_i[k]
            if k not in self._limited:              # a limited duty ramps step by step: `submit` it
                out[f"{self._prefix[name]}{DUTY_CYCLE}"] = self._duty_i[k]
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
                i = int(self._feed_i[j])
                u[i] = v
                self._fed(i, v, step)
                if hook is not None:
                    hook(step, name, v)
        self._feed_next = r + 1

    def _fed(self, i: int, value: float, step: int) -> None:
        """The device's account of a fed value of model input i from `step` on (in the model already)."""
        if i in self._flow_i:
            self._load_flow[self._flow_i.index(i)] = value
        elif i in self._duty_i:
            valve = self.valve_names[self._duty_i.index(i)]
            self.commands[valve] = self.duties[valve] = value
            if self.watchdogs[valve].command(step):
                self.log.append((step * self.dt, f"{valve}: watchdog cleared by a valid command"))

    # --- the offline run of a fed timeline ---------------------------------------------------

    def sample_at(self, steps: Sequence[int] | np.ndarray) -> np.ndarray:
        """The true values of `signals` (rows, SI) at each of `steps` (increasing, from the present
        step on), each with the inputs due at its step in force (right-continuous, as `run_to`'s
        samples); the device is then at the last of them. Queued inputs and actions, fault
        commands, a ramping duty and the watchdogs act at their steps as in `run_to`; fed inputs
        go in inside the compiled calls, so a recorded timeline fed whole runs between two queued
        inputs in one compiled call (an offline run: replay). The recorder is not called.
        ModelFault (and `fault` set) when the model runs away or a sample is none a valve can
        show (`PhysicalLimits`), also when it stands in the fault state already."""
        sim = self.sim
        want = np.ascontiguousarray(steps, dtype=np.int64)
        if want.ndim != 1 or (want.size and (want[0] < sim.steps or np.any(np.diff(want) <= 0))):
            raise ValueError(f"sample_at: accepted are steps increasing from the present one ({sim.steps}) on")
        if self.fault is not None:
            raise ModelFault(self.fault)
        out = np.empty((len(want), len(self.signal_outputs)))
        j, n = 0, len(want)
        last = int(want[-1]) if n else sim.steps
        while j < n:
            self._due()
            # The stretch to the next step at which anything but a fed value falls due. Fed values
            # too while a physical fault holds (it acts on the inputs in Python) or a watchdog with a
            # timeout holds (a fed duty would arm it within the stretch, its deadline unseen).
            stops_at_feed = any(not f.sensor for f in self.faults.values()) or any(
                w.holds and w.timeout_steps for w in self.watchdogs.values())
            stop = max(self._due_step(feed=stops_at_feed), sim.steps + 1)
            end = int(np.searchsorted(want, stop, "left")) if stop <= last else n
            targets = want[j:end] if stop > last else np.append(want[j:end], stop)
            r0 = self._feed_next
            r1 = bisect_left(self._feed_steps, stop if stop <= last else last + 1, lo=r0)
            rows = self._run_rows(np.asarray(self._feed_steps[r0:r1], dtype=np.int64), self._feed_rows(r0, r1), targets)
            self._feed_taken(r0, r1)
            got = rows[:end - j, self.signal_outputs]
            if end > j:
                self._check_rows(got, targets)
            self._check_finite()
            out[j:end] = got
            j = end
        if n:
            self.shown = max(self.shown, last)
            self.last_sample = Sample(last, out[-1].copy())
        return out

    def _feed_rows(self, r0: int, r1: int) -> np.ndarray:
        """Rows r0 .. r1 of the feed as whole input vectors of the model (`Simulator.run`'s): the
        inputs in force now, each fed one from its row on."""
        rows = np.repeat(self.sim.u[None, :], r1 - r0, axis=0)
        for j, i in enumerate(self._feed_i.tolist()):
            col = self._feed_v[r0:r1, j]
            given = ~np.isnan(col)
            at = np.maximum.accumulate(np.where(given, np.arange(r1 - r0), -1))   # its last row at or before
            rows[at >= 0, i] = col[at[at >= 0]]
        return rows

    def _feed_taken(self, r0: int, r1: int) -> None:
        """Rows r0 .. r1 of the feed acted in a compiled call (the model has the last of each): the
        device's account of them, and the hook hears each."""
        if r1 <= r0:
            return
        if self.on_input is not None:
            for r in range(r0, r1):
                self._feed_row(r, self._feed_steps[r])
            return
        for j, i in enumerate(self._feed_i.tolist()):
            given = np.flatnonzero(~np.isnan(self._feed_v[r0:r1, j]))
            if given.size:
                if i in self._duty_i:   # the watchdog hears the first (it may clear a firing) and the last
                    self._fed(i, float(self._feed_v[r0 + given[0], j]), self._feed_steps[r0 + given[0]])
                r = r0 + int(given[-1])
                self._fed(i, float(self._feed_v[r, j]), self._feed_steps[r])
        self._feed_next = r1
