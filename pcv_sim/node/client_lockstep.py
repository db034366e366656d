"""The device client's lockstep controller runner (`pcv_sim.node.client.DeviceClient.run`): a
controller answers each sample period the device publishes, once, with its duties (and flags),
over the per-valve topics or the lockstep channel; a period published again is answered again
with the same duties, one stamped before the last answered starts a new run.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from std_msgs.msg import Float64

from pcv_sim.io import topics
from pcv_sim.node.inputs import drain
from pcv_sim.node.lockstep_channel import DUTY_SUFFIX, FLAG_PREFIX, NamedVector
from pcv_sim.node.polling import Waiter

__all__ = ["FULL_POLL", "Controller", "LockstepRunner", "PartialPeriod", "Period"]

FULL_POLL = 1e-2        # s between polls of every topic while a lockstep waits for a period's last one
Controller = Callable[[float, Mapping[str, float]], Mapping[str, Any]]


@dataclass
class Period:
    """One answered sample period: the model time (ns), what was measured, what was commanded."""

    stamp_ns: int
    measured: dict[str, float]
    duties: dict[str, float]
    flags: dict[str, float] = field(default_factory=dict)


@dataclass
class PartialPeriod:
    """What has come of one sample period so far, by the device's names (`joint`: its last topic)."""

    values: dict[str, float] = field(default_factory=dict)


class LockstepRunner:
    """`run`: a controller in lockstep with the device (see the module docstring); what it reads
    is what the client's handlers took (`pcv_sim.node.client_messages.ClientMessages`)."""

    valves: tuple[str, ...]
    channel: bool
    cylinder: bool
    history: bool
    answered: int
    periods: list[Period]
    command_pub: Any
    duty_pubs: dict[str, Any]
    key: Callable[[str, str], str]
    poll: Callable[[], int]
    _currents: bool
    _fresh: dict[str, float]
    _samples: list[tuple[int, dict[str, float]]]
    _partial: dict[int, PartialPeriod]
    _completing: list[tuple[Any, Callable[..., None]]]
    _waiter: Waiter | None
    _answers: dict[int, dict[str, float]]
    _flags_sent: dict[str, float]
    _last_answered: int
    _commands: dict[tuple[str, ...], NamedVector]
    _duty_msg: Float64

    def _all_there(self, values: dict[str, float]) -> bool:
        return all(self.key(v, topics.PRESSURE) in values for v in self.valves) and (
            not self._currents or all(self.key(v, topics.CURRENT) in self._fresh for v in self.valves))

    def _take_complete(self) -> list[tuple[int, dict[str, float]]]:
        """The periods whose last topic arrived, oldest first, with what was published before it
        (taken once more when something is missing: it left the node before the last one); on the
        channel the samples taken."""
        if self.channel:
            out, self._samples = self._samples, []
            return out
        last = "joint" if self.cylinder else self.key(self.valves[-1], topics.PRESSURE)
        done = sorted(s for s, p in self._partial.items() if last in p.values)
        if not done:
            return []
        if not all(self._all_there(self._partial[s].values) for s in done):
            self.poll()
        out = []
        for stamp in done:
            values = self._partial.pop(stamp).values
            values.pop("joint", None)
            out.append((stamp, values))
        for stale in [s for s in self._partial if s < done[-1]]:
            del self._partial[stale]              # an incomplete period the node will not finish (lost joint)
        return out

    def run(self, controller: Controller, periods: int | None, *, timeout: float | None = 60.0,
            before: Callable[[int], None] | None = None, stop: Any = None,
            on_flags: Callable[[int, Mapping[str, float]], None] | None = None,
            rewind: Callable[[], Controller] | None = None,
            on_poll: Callable[[], None] | None = None) -> list[Period]:
        """Answer `periods` sample periods (None: until `stop.requested`) with
        `controller(t, measured) -> {valve: duty, "flags": {name: value}}`; `before(k)` runs
        before the k-th answer (e.g. to inject a fault), `on_flags(stamp_ns, flags)` before the
        duties are published, `on_poll()` at every poll of every topic (every FULL_POLL s, between
        two answers: a node's service requests). The answered periods (kept only with `history`).
        Needs `lockstep`."""
        if not self._completing or self._waiter is None:
            raise ValueError("run: the client was made without lockstep=True (or channel=True)")
        waiter = self._waiter
        end = math.inf if timeout is None else time.monotonic() + timeout
        answered = self.answered
        first = len(self.periods)
        goal = math.inf if periods is None else answered + periods
        next_full = 0.0
        while self.answered < goal and not (stop is not None and stop.requested):
            now = time.monotonic()
            if now > end:
                raise TimeoutError(f"lockstep: {self.answered - answered} of {periods} periods answered in "
                                   f"{timeout} s")
            # Waiting, for the period's last topic only, blocked in an rcl wait set (not polling: two
            # polling processes kept both cores busy, ~1 ms of CPU a period each, and the DDS threads
            # that deliver the messages waited for a core); every topic once it came, and every
            # FULL_POLL s whatever came.
            if not drain(self._completing) and now < next_full:
                waiter.wait(next_full - now)
                continue
            if now >= next_full or not self.channel:      # on the channel a sample is the whole period
                if on_poll is not None and now >= next_full:
                    on_poll()
                next_full = now + FULL_POLL
                if not self.poll() and not self._partial and not self._samples:
                    continue
            for stamp, values in self._take_complete():
                if self._currents and not self.channel:
                    values.update(self._fresh)
                    self._fresh.clear()
                again = self._answers.get(stamp)
                if again is not None:                 # published again by the node: same answer
                    self._send(again, stamp, self._flags_sent)
                    continue
                if stamp < self._last_answered:       # the node started again from 0: a new run
                    self._answers.clear()
                    if rewind is not None:
                        controller = rewind()
                if self.answered >= goal:
                    continue
                if before is not None:
                    before(self.answered)
                out = controller(stamp * 1e-9, values)
                flags = {str(k): float(f) for k, f in dict(out.get("flags") or {}).items()}
                duties = {v: float(d) for v, d in out.items() if v != "flags"}
                self._answers = {stamp: duties}
                self._flags_sent = flags
                self._last_answered = stamp
                self.answered += 1
                if self.history:
                    self.periods.append(Period(stamp, values, duties, flags))
                if flags and on_flags is not None:
                    on_flags(stamp, flags)
                self._send(duties, stamp, flags)
        return self.periods[first:]

    def _send(self, duties: Mapping[str, float], stamp: int, flags: Mapping[str, float]) -> None:
        if self.command_pub is not None:
            names = (*(v + DUTY_SUFFIX for v in duties), *(FLAG_PREFIX + f for f in flags))
            writer = self._commands.get(names)
            if writer is None:
                writer = self._commands[names] = NamedVector(names)
            self.command_pub.publish(writer.encode(stamp, (*duties.values(), *flags.values())))
            return
        msg = self._duty_msg                 # refilled: publish serializes it at once
        for v, d in duties.items():
            msg.data = d
            self.duty_pubs[v].publish(msg)
