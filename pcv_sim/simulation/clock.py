"""Scheduling fixed model steps against a clock: which steps are due now, which are late.

Pure bookkeeping, no ROS and no sleeping: the caller passes the present time (seconds of a
monotonic clock, e.g. `time.monotonic()`), runs the steps it is told to, then sleeps until
`next_wake()`. Tests drive it with a fake clock.

Real time (`RealTimeSchedule`)
    Step k (0-based) covers model time [k dt, (k+1) dt]. It is *due* at wall time
    d_k = t0 + (k+1) dt: only then has wall time reached the end of its interval, so the model
    never runs ahead of wall time. At a wake-up at time `now` the steps due are
    [done, floor((now - t0) / dt)); model time is an integer count of steps, so it never drifts.

    The caller wakes on a fixed grid t0 + m P (P = `wake_period`, a multiple of dt): step k is
    *scheduled* for the first grid wake at or after its due time, m_k = ceil((k+1) dt / P).
    A step is *late* when the wake that computes it starts more than `late_threshold` after that
    scheduled wake (the OS woke the loop late, or the previous wake ran long). Late steps are a
    prefix of each batch, so they are counted in O(1).

    The lag `now - t0 - model time` is sampled before (`lag`, how stale the model was when the loop
    woke: normally P plus the wake-up jitter) and after a batch (`lag_after`, what a sample
    published right then shows: normally less than dt plus the batch's compute time).

    Far behind: when more than `max_catchup` seconds of steps are due at once (the process was
    stopped, starved or swapped), all but the most recent wake period's worth of them are
    *skipped*: the caller holds the model state over that interval instead of computing it
    (`Plan.skipped`), model time jumps to wall time, and the skip is counted. Less than that is
    caught up in one batch (a few microseconds per step).

    What the loop did in each wake (`WakeRecord`: its parts, its CPU time, the garbage collector's
    share, the sleep it asked for after it) goes to `note_wake`; the largest wake-to-wake gap of
    each diagnostics period is kept with the wake before it and the sleep between (`WakeGap`:
    whether the loop's own work, a garbage collection, time off the CPU inside the wake, or a
    wake-up the OS made late filled it).

Simulated time (`SimulatedSchedule`)
    Model time is decoupled from wall time: chunks of steps run back to back, paced at a
    real-time factor (chunk k may start once wall time reaches anchor + model time / factor), or
    as fast as possible (factor 0 or inf).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

__all__ = [
    "EXTERNAL_MAX_JUMP",
    "NO_CLOCK_YET",
    "SIM_TIME_CONFLICT",
    "ClockPlan",
    "ExternalClock",
    "Plan",
    "RealTimeSchedule",
    "SimulatedSchedule",
    "WakeGap",
    "WakeRecord",
    "steps_per",
]

Clock = Callable[[], float]


def steps_per(period: float, dt: float, *, what: str = "period") -> int:
    """The whole number of steps dt in `period`; ValueError unless period is a positive multiple of dt."""
    if not (math.isfinite(period) and period > 0.0):
        raise ValueError(f"{what} {period!r} s: accepted is a finite number > 0")
    n = round(period / dt)
    if n < 1 or abs(n * dt - period) > 1e-9 * max(1.0, period):
        raise ValueError(f"{what} {period:g} s is not a whole multiple of the model step {dt:g} s")
    return int(n)


@dataclass(frozen=True)
class Plan:
    """What one wake-up is to do: skip `skipped` steps (hold the model), then compute `steps`."""

    first: int          # index of the first step due (skipped ones come first)
    skipped: int        # steps too far behind to catch up: model held over them
    steps: int          # steps to compute now
    late: int           # of `steps`, how many start more than late_threshold after their scheduled wake
    lag: float          # s, now - t0 - model time, before this batch


class WakeRecord(NamedTuple):
    """One wake of a real-time loop (s of its monotonic clock; the loop thread's CPU time)."""

    start: float        # woken (the end of the sleep before)
    drain: float        # spent taking the inputs
    compute: float      # spent on the model steps due and their samples (published, recorded)
    diagnostics: float  # spent publishing diagnostics (0 in most wakes)
    end: float          # going to sleep
    cpu: float          # the loop thread's CPU time in the wake (garbage collection included)
    gc: float           # garbage collection inside the wake (wall time)
    steps: int          # model steps computed
    asked: float        # the sleep asked for after it (<= 0: none)


#: What filled a wake-to-wake gap most (`WakeGap.cause`).
GAP_CAUSES = ("work", "gc", "off_cpu", "late_wake")


@dataclass(frozen=True)
class WakeGap:
    """A wake-to-wake gap: the wake before it (`wake`) and the next wake's start."""

    gap: float          # s, next start - wake.start
    wake: WakeRecord
    next_start: float

    @property
    def parts(self) -> dict[str, float]:
        """The gap in four shares (s): the loop's own work (CPU time of the wake, collections
        excepted), garbage collection, time off the CPU inside the wake (another process or
        thread ran: the machine's load, the interpreter lock), and the sleep beyond what was asked
        (the OS woke the loop late) or the time until the grid's next wake when none was asked."""
        w = self.wake
        busy = w.end - w.start
        slept = self.next_start - w.end
        return {"work": max(w.cpu - w.gc, 0.0), "gc": w.gc, "off_cpu": max(busy - w.cpu, 0.0),
                "late_wake": max(slept - max(w.asked, 0.0), 0.0)}

    @property
    def cause(self) -> str:
        """The largest of `parts` (one of GAP_CAUSES)."""
        parts = self.parts
        return max(GAP_CAUSES, key=parts.__getitem__)

    def describe(self) -> str:
        w = self.wake
        ms = 1e3
        return (f"{self.gap * ms:.2f} ms: a wake of {(w.end - w.start) * ms:.2f} ms (CPU {w.cpu * ms:.2f} ms; inputs "
                f"{w.drain * ms:.2f}, {w.steps} steps and their samples {w.compute * ms:.2f}, diagnostics "
                f"{w.diagnostics * ms:.2f}, garbage collection {w.gc * ms:.2f} ms), then asleep "
                f"{(self.next_start - w.end) * ms:.2f} ms ({max(w.asked, 0.0) * ms:.2f} asked)")


class RealTimeSchedule:
    """Which fixed steps are due at a given wall time; late-step and lag accounting."""

    def __init__(
        self, dt: float, *, wake_period: float = 1e-3, late_threshold: float = 1e-3,
        max_catchup: float = 0.05, clock: Clock = time.monotonic,
    ) -> None:
        if not (math.isfinite(dt) and dt > 0.0):
            raise ValueError(f"model step {dt!r} s: accepted is a finite number > 0")
        self.dt = dt
        self.steps_per_wake = steps_per(wake_period, dt, what="wake_period")
        self.wake_period = self.steps_per_wake * dt
        if not (math.isfinite(late_threshold) and late_threshold >= 0.0):
            raise ValueError(f"late_threshold {late_threshold!r} s: accepted is a finite number >= 0")
        self.late_threshold = late_threshold
        if not (math.isfinite(max_catchup) and max_catchup >= self.wake_period):
            raise ValueError(f"max_catchup {max_catchup!r} s: accepted is a finite number >= wake_period "
                             f"({self.wake_period:g} s)")
        self.max_catchup_steps = int(max_catchup / dt)
        self.clock = clock
        self.t0 = math.nan
        self.slot = 0               # steps accounted for: computed + skipped
        self.computed_steps = 0
        self.late_steps = 0
        self.skipped_steps = 0
        self.skips = 0              # how many times the schedule jumped
        self.wakes = 0
        self.max_lag = 0.0
        self.max_lag_after = 0.0
        self.lag_after = 0.0
        self.period_max_lag = 0.0       # maxima since the last `take_period_max()` (diagnostics)
        self.period_max_lag_after = 0.0
        self.max_wake_cpu = 0.0         # s, the most CPU time the loop thread spent in one wake
        self.period_max_wake_cpu = 0.0  # the same since the last `take_period_wake_cpu()`
        self.max_wake_gap = 0.0         # s, the longest from one wake's start to the next's (`note_wake`)
        self.period_gap: WakeGap | None = None      # the longest since the last `take_period_wakes()`
        self.period_wake_cpu = 0.0      # s, the loop thread's CPU time in the wakes since then
        self.period_wakes = 0           # wakes since then (`note_wake`)
        self.period_gc = 0.0            # s, garbage collection in them
        self._last_wake: WakeRecord | None = None

    @property
    def started(self) -> bool:
        return not math.isnan(self.t0)

    def start(self, now: float | None = None) -> float:
        """Anchor model time 0 at `now` (default: the clock). Returns t0."""
        self.t0 = self.clock() if now is None else now
        self.slot = 0
        return self.t0

    @property
    def model_time(self) -> float:
        return self.slot * self.dt

    def due(self, now: float) -> int:
        """Index one past the last step due at `now` (steps [0, due) have ended by then)."""
        # A tiny tolerance so that a wake exactly on a step boundary counts that step as due.
        return max(0, math.floor((now - self.t0) / self.dt + 1e-6))

    def plan(self, now: float | None = None) -> Plan:
        """The steps due at `now`, and account for them as done (the caller must run them)."""
        if not self.started:
            raise RuntimeError("RealTimeSchedule.plan() before start()")
        now = self.clock() if now is None else now
        self.wakes += 1
        first = self.slot
        lag = now - self.t0 - first * self.dt
        self.max_lag = max(self.max_lag, lag)
        self.period_max_lag = max(self.period_max_lag, lag)
        target = self.due(now)
        backlog = target - first
        if backlog <= 0:
            return Plan(first, 0, 0, 0, lag)
        skipped = 0
        if backlog > self.max_catchup_steps:
            skipped = backlog - self.steps_per_wake
            self.skipped_steps += skipped
            self.skips += 1
        steps = backlog - skipped
        # Steps scheduled on grid wakes 1..m_late all started late; their indices are < m_late * S.
        m_late = math.ceil((now - self.late_threshold - self.t0) / self.wake_period) - 1
        late = min(max(m_late * self.steps_per_wake - (first + skipped), 0), steps)
        self.late_steps += late
        self.computed_steps += steps
        self.slot = target
        return Plan(first, skipped, steps, late, lag)

    def finish(self, now: float | None = None) -> float:
        """Record the lag right after a batch (what a sample published now shows); returns it."""
        now = self.clock() if now is None else now
        self.lag_after = now - self.t0 - self.slot * self.dt
        self.max_lag_after = max(self.max_lag_after, self.lag_after)
        self.period_max_lag_after = max(self.period_max_lag_after, self.lag_after)
        return self.lag_after

    def note_wake_cpu(self, seconds: float) -> None:
        """Record the loop thread's CPU time for one wake (its own work, whatever the machine's
        load: what a stall inside the loop, e.g. a computation that belongs in a worker, shows)."""
        self.max_wake_cpu = max(self.max_wake_cpu, seconds)
        self.period_max_wake_cpu = max(self.period_max_wake_cpu, seconds)

    def take_period_wake_cpu(self) -> float:
        """The largest CPU time of one wake since the last call (diagnostics); starts a new period."""
        out, self.period_max_wake_cpu = self.period_max_wake_cpu, 0.0
        return out

    def note_wake(self, wake: WakeRecord) -> None:
        """Record a wake (after it, before the sleep it asked for): the gap from the previous wake's
        start to this one's, kept with that wake when it is the period's longest."""
        last = self._last_wake
        if last is not None:
            gap = wake.start - last.start
            self.max_wake_gap = max(self.max_wake_gap, gap)
            if self.period_gap is None or gap > self.period_gap.gap:
                self.period_gap = WakeGap(gap, last, wake.start)
        self._last_wake = wake
        self.period_wake_cpu += wake.cpu
        self.period_wakes += 1
        self.period_gc += wake.gc

    def take_period_wakes(self) -> tuple[WakeGap | None, float, float]:
        """(the longest wake-to-wake gap, the mean CPU time of a wake, the garbage collection in
        the wakes (s)) since the last call (diagnostics); starts a new period."""
        out = (self.period_gap, self.period_wake_cpu / self.period_wakes if self.period_wakes else 0.0,
               self.period_gc)
        self.period_gap, self.period_wake_cpu, self.period_wakes, self.period_gc = None, 0.0, 0, 0.0
        return out

    def take_period_max(self) -> tuple[float, float]:
        """(max lag before, max lag after a batch) since the last call; starts a new period."""
        out = (self.period_max_lag, self.period_max_lag_after)
        self.period_max_lag = self.period_max_lag_after = 0.0
        return out

    def next_wake(self, now: float | None = None) -> float:
        """The first grid wake t0 + m P strictly after `now`."""
        now = self.clock() if now is None else now
        m = math.floor((now - self.t0) / self.wake_period + 1e-6) + 1
        return self.t0 + m * self.wake_period


class SimulatedSchedule:
    """Pacing for simulated time: model time runs `factor` times as fast as wall time (0/inf: free)."""

    def __init__(self, dt: float, *, factor: float = 0.0, clock: Clock = time.monotonic) -> None:
        if not (math.isfinite(dt) and dt > 0.0):
            raise ValueError(f"model step {dt!r} s: accepted is a finite number > 0")
        self.dt = dt
        self.clock = clock
        self.steps = 0
        self._anchor_wall = math.nan
        self._anchor_steps = 0
        self.factor = self._check(factor)

    @staticmethod
    def _check(factor: float) -> float:
        if math.isnan(factor) or factor < 0.0:
            raise ValueError(f"real_time_factor {factor!r}: accepted is a number >= 0 (0 or inf: as fast as possible)")
        return factor

    @property
    def free(self) -> bool:
        return self.factor == 0.0 or math.isinf(self.factor)

    def start(self, now: float | None = None) -> None:
        self._anchor_wall = self.clock() if now is None else now
        self._anchor_steps = self.steps

    def set_factor(self, factor: float, now: float | None = None) -> None:
        """Change the factor from now on (re-anchors, so there is no jump or burst)."""
        self.factor = self._check(factor)
        self.start(now)

    def ready_at(self, steps: int) -> float:
        """Wall time at which a chunk of `steps` more steps may start (-inf when free)."""
        if self.free:
            return -math.inf
        # As in real time, a chunk is due once paced wall time has reached its *end*: the model
        # never runs ahead of anchor + model time / factor.
        return self._anchor_wall + (self.steps + steps - self._anchor_steps) * self.dt / self.factor

    def advance(self, steps: int) -> None:
        self.steps += steps

    @property
    def model_time(self) -> float:
        return self.steps * self.dt


#: s of external clock run at once; a longer jump ahead is held (the model state kept over it).
EXTERNAL_MAX_JUMP = 10.0


@dataclass(frozen=True)
class ClockPlan:
    """What to do for the latest external clock: compute `run` steps, or hold the model over `skip`
    steps (the clock jumped far ahead), or nothing but re-anchor (`reanchored`: the clock went back)."""

    run: int = 0
    skip: int = 0
    reanchored: bool = False


class ExternalClock:
    """Model time following an external clock (ROS `use_sim_time`: a simulation's /clock), for the
    emulator and the rig node alike.

    Model time 0 is the first clock received (`start`: stamps are that clock); whenever the clock
    advances, the steps up to it are due (`plan`). The clock going back (a simulation reset)
    re-anchors model time at the new clock, the model state kept; a jump ahead of more than
    `max_jump` s is held (the model state kept) but for the last `max_jump` s.
    """

    def __init__(self, dt_ns: int, *, max_jump: float = EXTERNAL_MAX_JUMP) -> None:
        self.dt_ns = dt_ns
        self.max_jump = max_jump
        self.max_steps = round(max_jump * 1e9 / dt_ns)
        self.latest_ns: int | None = None       # the last clock received
        self.origin_ns = 0                      # the clock at model step 0
        self.started = False

    def take(self, clock_ns: int) -> None:
        self.latest_ns = clock_ns

    def start(self, steps: int) -> int:
        """Anchor model step `steps` at the latest clock; returns the origin (ns)."""
        if self.latest_ns is None:
            raise RuntimeError("ExternalClock.start before any clock was received")
        self.origin_ns = self.latest_ns - steps * self.dt_ns
        self.started = True
        return self.origin_ns

    def plan(self, steps: int) -> ClockPlan:
        """What the latest clock asks of a model at step `steps`."""
        clock = self.latest_ns
        if clock is None or not self.started:
            return ClockPlan()
        target = (clock - self.origin_ns) // self.dt_ns
        if target < steps:
            self.origin_ns = clock - steps * self.dt_ns
            return ClockPlan(reanchored=True)
        if target - steps > self.max_steps:
            return ClockPlan(skip=target - steps - self.max_steps)
        return ClockPlan(run=target - steps)

    def went_back(self) -> str:
        clock = self.latest_ns or 0
        return f"/clock went back to {clock / 1e9:.4f} s: model time re-anchored there (the model state is kept)"

    def jumped(self, skipped: int) -> str:
        return (f"/clock jumped {skipped * self.dt_ns / 1e9:.3f} s ahead: the model was held over all but the last "
                f"{self.max_jump:g} s")


#: Why a node with use_sim_time and time_mode simulated is refused (the emulator and the rig).
SIM_TIME_CONFLICT = ("use_sim_time: true follows another node's /clock, time_mode: simulated publishes /clock itself; "
                     "accepted is one of them: use_sim_time with time_mode real (the model follows the external "
                     "clock), or time_mode simulated without use_sim_time")
#: Logged once when no /clock came ~2 s after the start (use_sim_time).
NO_CLOCK_YET = "no /clock received yet: the model waits for the simulation's clock (use_sim_time is true)"
