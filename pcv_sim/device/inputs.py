"""The devices' one timing rule and their watchdog, written once (the emulator's valve and the rig).

- `InputQueue`: inputs wait for the model step they act from. The caller gives that step (the
  first step at or after the input's reception that has not been shown); inputs due at one step
  act in the order they were queued. Deterministic: the same (step, input) pairs in the same order
  act the same way.
- `InputTiming`: the rule in wall terms, the step an input acts from: the first step stamped at or
  after its reception, never one already shown, two inputs under one name never at one step.
- `Watchdog`: one per valve, in model time. "waiting" until the first valid duty command (no
  controller yet: it never fires), "ok" while commands come, "fired" once `timeout_steps` have
  passed since the last one took effect, "off" when the timeout is 0. What duty a state means
  (the safe duty, or the rest state's) is the device's to say.
"""

from __future__ import annotations

import heapq
from typing import Generic, TypeVar

__all__ = ["InputQueue", "InputTiming", "Watchdog", "WatchdogState"]

T = TypeVar("T")

#: A step later than any a device reaches: "nothing due".
NEVER = 1 << 62


class InputQueue(Generic[T]):
    """Items by the step they act from, then by arrival."""

    def __init__(self) -> None:
        self._heap: list[tuple[int, int, T]] = []
        self._seq = 0

    def push(self, step: int, item: T) -> None:
        heapq.heappush(self._heap, (step, self._seq, item))
        self._seq += 1

    def pop_due(self, step: int) -> T | None:
        """The next item due at or before `step` (removed), or None."""
        heap = self._heap
        if heap and heap[0][0] <= step:
            return heapq.heappop(heap)[2]
        return None

    @property
    def next_step(self) -> int:
        """The step of the first item (NEVER when empty)."""
        return self._heap[0][0] if self._heap else NEVER

    def clear(self) -> None:
        self._heap.clear()

    def __len__(self) -> int:
        return len(self._heap)


class InputTiming:
    """The step an input acts from (every device's, every time mode's).

    The first step stamped at or after its reception (`received_ns`, the DDS reception time on the
    stamps' clock; `origin_ns` is the stamp of step 0), never later than the step the wall clock
    had reached when it was taken (`elapsed` s since step 0's slot on the monotonic clock: a system
    clock stepped forward cannot delay it), never a step already shown (`first`), and two inputs of
    one name never at one step (a starved DDS thread can receive several at once: the later acts
    one step after the earlier, so none is lost unseen). Without a wall clock (simulated time, an
    external clock: `elapsed` None) an input acts from `first`."""

    def __init__(self, dt_ns: int) -> None:
        self.dt_ns = dt_ns
        self._last: dict[str, int] = {}       # per name: the step its last accepted input acts from

    def step(self, name: str, first: int, *, received_ns: int = 0, origin_ns: int = 0,
             elapsed: float | None = None) -> int:
        """The step an input of `name` acts from (see the class docstring); `took` records it."""
        at = first
        if elapsed is not None:
            dt_ns = self.dt_ns
            taken = -(-round(elapsed * 1e9) // dt_ns)          # ceil: the first step at or after now
            at = max(at, min(-(-(received_ns - origin_ns) // dt_ns), taken) if received_ns else taken)
        return max(at, self.last(name) + 1)

    def took(self, name: str, step: int) -> None:
        """An input of `name` was accepted to act from `step`: the next one acts later."""
        self._last[name] = step

    def last(self, name: str) -> int:
        """The step the last accepted input of `name` acts from (-1: none yet)."""
        return self._last.get(name, -1)


class WatchdogState:
    OFF = "off"            # timeout 0
    WAITING = "waiting"    # no valid duty command yet
    OK = "ok"              # commands arriving
    FIRED = "fired"        # no valid command for the timeout


class Watchdog:
    """One valve's watchdog (see the module docstring); steps are model steps."""

    def __init__(self, timeout_steps: int) -> None:
        self.timeout_steps = timeout_steps
        self.state = WatchdogState.WAITING
        self.command_step: int | None = None      # step the last valid command took effect at
        self.fired_step: int | None = None
        self.fired = 0                            # how often it fired

    @property
    def holds(self) -> bool:
        """True while the duty is not the controller's (waiting, or fired)."""
        return self.state in (WatchdogState.WAITING, WatchdogState.FIRED)

    def command(self, step: int) -> bool:
        """A valid duty command took effect at `step`; True if it ended a firing."""
        was_fired = self.state == WatchdogState.FIRED
        self.command_step = step
        self.state = WatchdogState.OK if self.timeout_steps else WatchdogState.OFF
        return was_fired

    @property
    def deadline(self) -> int:
        """The step it fires at if no command comes (NEVER when it cannot fire)."""
        if self.state == WatchdogState.OK and self.timeout_steps and self.command_step is not None:
            return self.command_step + self.timeout_steps
        return NEVER

    def check(self, step: int) -> bool:
        """Fire if the deadline is reached at `step`; True if it fired now."""
        if step >= self.deadline:
            self.state = WatchdogState.FIRED
            self.fired_step = step
            self.fired += 1
            return True
        return False

    def set_timeout(self, timeout_steps: int) -> bool:
        """A new timeout (0 = off); True if that ended a firing (the controller's duty is back)."""
        self.timeout_steps = timeout_steps
        was_fired = self.state == WatchdogState.FIRED
        if timeout_steps == 0:
            self.state = WatchdogState.OFF if self.command_step is not None else WatchdogState.WAITING
        elif self.state == WatchdogState.OFF:
            self.state = WatchdogState.OK
        return was_fired and timeout_steps == 0

    def restart(self) -> None:
        """Back to waiting for a first command (a reset: a fresh start's)."""
        self.state = WatchdogState.WAITING
        self.command_step = None
