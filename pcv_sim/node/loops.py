"""The loops of a node's three time modes, written once over its device (`pcv_sim.device.device.Device`:
steps, origin, skip, fault) and the hooks `_begin`, `_compute`, `_halted`, `_send_samples`,
`_sample_period`: real time (the wall clock's grid, `RealTimeSchedule`), simulated time (in
lockstep with the answers to each sample, or free running; /clock published, the domain's one),
and an external /clock (use_sim_time, `ExternalClock`). Inputs are taken by `_drain` at every wake
(`pcv_sim.node.inputs`), service requests with them every SERVICE_POLL_PERIOD of wall time."""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from typing import Any, Protocol

from rclpy.event_handler import PublisherEventCallbacks, SubscriptionEventCallbacks
from rclpy.node import Node
from rosgraph_msgs.msg import Clock

from pcv_sim.device.device import Device
from pcv_sim.device.diagnostics import DiagnosticsBuilder
from pcv_sim.errors import ParameterError
from pcv_sim.io.recorder import SWITCH_INTERVAL
from pcv_sim.io.topics import CLOCK
from pcv_sim.node.inputs import drain
from pcv_sim.node.polling import Waiter
from pcv_sim.node.qos_events import topic_qos
from pcv_sim.node.tuning import GcTimer, freeze_heap, set_realtime_priority, tighten_timer_slack
from pcv_sim.simulation.clock import (
    NO_CLOCK_YET,
    ExternalClock,
    RealTimeSchedule,
    SimulatedSchedule,
    WakeRecord,
)
from pcv_sim.units import NS_PER_S

__all__ = ["CLOCK_DISCOVERY", "LOCKSTEP_FULL_POLL", "LOCKSTEP_RESEND", "StopFlag", "TimeModeLoops"]

CLOCK_DISCOVERY = 3.0                       # s a simulated-time node looks for another /clock publisher at start
LOCKSTEP_RESEND = 0.5                       # s without a command: publish the last sample again
LOCKSTEP_FULL_POLL = 1e-3                   # s (wall) between polls of every input while the lockstep waits for its answers


class StopFlag(Protocol):
    """Set from outside (the signal handlers of `pcv_sim.node.process`); the loops poll it."""

    requested: bool


class TimeModeLoops(Node):
    """The time-mode part of the package's node (`pcv_sim.node.base.NodeBase`)."""

    settings: Any
    device: Device
    simulated: bool                 # time_mode simulated (else real: the wall clock, or an external /clock)
    external_clock: bool            # use_sim_time (pcv_sim.node.parameters)
    hook: Any                       # a scenario's hook (pcv_sim.node.base)
    _diag: DiagnosticsBuilder
    _external: ExternalClock
    _pub_clock: Any                 # the /clock publisher (simulated time), or None
    # pcv_sim.node.inputs
    lockstep_keys: tuple[str, ...] = ()
    _inputs: list[tuple[Any, Any]]
    _answer_subs: list[Any]
    _channel_sub: Any
    _answered: set[str]
    _shown: int
    _drain: Callable[[], int]
    # pcv_sim.node.services, pcv_sim.node.qos_events, pcv_sim.node.base
    _poll_services: Callable[[], None]
    output_events: Callable[..., PublisherEventCallbacks]
    input_events: Callable[[str], SubscriptionEventCallbacks]
    _publish_diagnostics: Callable[[float], None]
    _finish: Callable[[], None]

    def _init_loops(self) -> None:
        self._schedule: RealTimeSchedule | None = None      # real time: the loop's schedule
        self._sim: SimulatedSchedule | None = None          # simulated time: the loop's schedule
        self._pub_clock = None
        self._msg_clock = Clock()

    def run(self, stop: StopFlag) -> None:
        """Run the loop of the node's time mode until stop.requested (SIGINT/SIGTERM); then `_finish`
        (the bag of record.enabled finalised)."""
        try:
            if self.simulated:
                self._run_simulated(stop)
            elif self.external_clock:
                self._run_external_clock(stop)
            else:
                self._run_real_time(stop)
        finally:
            self._finish()

    def _lockstep_answers(self) -> tuple[list[Any], Any]:
        """The subscriptions of the `lockstep_keys` commands (made first, in that order), and one that
        answers for all of them at once (a lockstep channel, made right after them), or None."""
        return list(self._answer_subs), self._channel_sub

    def _wait_for_controllers(self, stop: StopFlag, subs: list[Any], channel: Any) -> None:
        """Lockstep: before the first sample, until every answering command (or the channel that
        answers for all) has a matched publisher (a command sent before that is lost); the 0.5 s
        re-publication covers what is left. Service requests (parameters, reset) are answered meanwhile."""
        start = time.monotonic()
        told = False
        while not stop.requested and not all(sub.get_publisher_count() > 0 for sub in subs) \
                and not (channel is not None and channel.get_publisher_count() > 0):
            if not told and time.monotonic() - start > 2.0:
                missing = [sub.topic_name for sub in subs if sub.get_publisher_count() == 0]
                alternative = f" (or {channel.topic_name})" if channel is not None else ""
                self.get_logger().info(f"lockstep: waiting for a controller publishing {', '.join(missing)}"
                                       f"{alternative}")
                told = True
            self._poll_services()
            time.sleep(0.01)

    def _run_simulated(self, stop: StopFlag) -> None:
        """Simulated time: model time from 0, in periods of one sample (`_sample_period` steps), /clock
        published with each sample.

        Lockstep (default): publish /clock and the samples at T, wait until every `lockstep_keys`
        command has had a message since then, apply them from T + dt, the first step not shown (the
        sample at T shows the inputs in force at T), compute to the next sample, repeat: a controller
        that answers every sample the same way sees bit for bit the same run. A sample left
        unanswered for 0.5 s is published again (a controller not yet connected, a lost command).
        Without lockstep the periods run back to back, paced by real_time_factor, and an input acts
        from the period after it was taken, which depends on wall-clock timing."""
        s, dev = self.settings, self.device
        lock = s.lockstep
        sim = self._sim = SimulatedSchedule(dev.dt, factor=s.real_time_factor)
        tighten_timer_slack()         # the free-running wait sleeps to its period's wall time
        freeze_heap()
        mono = time.monotonic
        keys = self.lockstep_keys
        subs, channel = self._lockstep_answers()
        answers = self._inputs[:len(subs) + (channel is not None)]      # made first, in this order
        if lock:
            self._wait_for_controllers(stop, subs, channel)
        sim.start()
        self._diag.restart(mono(), dev.steps)
        next_diag = mono() + s.diagnostics_period
        self._begin(0)
        published = mono()
        self._answered.clear()
        waiter = Waiter([sub for sub, _ in answers], self.context)
        next_full = 0.0
        while not stop.requested:
            answers_only = lock and len(self._answered) < len(keys) and mono() < next_full
            if answers_only:
                drain(answers)               # waiting: the answers alone, blocked in `waiter` between
                                             # (BENCHMARKS.md, "Where a 1 kHz lockstep period goes")
            else:
                self._drain()
                next_full = mono() + LOCKSTEP_FULL_POLL
            now = mono()
            if now >= next_diag:
                self._publish_diagnostics(now)
                next_diag = max(next_diag + self.settings.diagnostics_period, now)
            if dev.fault is not None:
                time.sleep(1e-3)             # model time stands still until reset
                continue
            period = self._sample_period()
            if lock:
                if len(self._answered) < len(keys):
                    if now - published > LOCKSTEP_RESEND:
                        missing = [k for k in keys if k not in self._answered]
                        # A command was lost (sent before its publisher matched) or the controller is
                        # slow: an answer to both copies may count for the next period, so such a run
                        # is not promised to repeat bit for bit; say so.
                        self.get_logger().warning(
                            f"lockstep: no duty_cycle from {', '.join(missing)} for {LOCKSTEP_RESEND:g} s after the "
                            f"sample at t = {dev.time:.4f} s: published again", throttle_duration_sec=5.0)
                        self._publish_clock()
                        self._send_samples()
                        published = now
                    waiter.wait(max(0.0, next_full - now))       # woken by an answer
                    continue
            else:
                ready = sim.ready_at(period)
                if ready > now:
                    time.sleep(min(ready - now, 1e-3))
                    continue
            if answers_only:
                self._drain()                # what came with the answers acts from the same step as before
            chunk = period - dev.steps % period
            target = dev.steps + chunk
            if self.hook is not None:
                # The answers act from the step after the sample (scheduled there): take that one
                # step first, so the hook sees the inputs in force after the instant.
                k = self._shown // period
                self._compute(1)
                if dev.fault is not None:
                    continue
                self.hook.answered(k)
            self._answered.clear()
            self._compute(target - dev.steps)
            if dev.fault is None:
                sim.advance(chunk)
            published = mono()

    def _sample_period(self) -> int:
        """Model steps between two samples."""
        raise NotImplementedError

    def _send_samples(self) -> None:
        """Publish the last sample again (a lockstep re-publication: not computed anew)."""
        raise NotImplementedError

    def _publish_clock(self) -> None:
        """/clock at the present model step (simulated time: the one clock of the domain)."""
        msg = self._msg_clock
        msg.clock.sec, msg.clock.nanosec = divmod(self.device.stamp_ns(), NS_PER_S)
        assert self._pub_clock is not None              # created in simulated time, the only caller
        self._pub_clock.publish(msg)

    def _on_clock(self, msg: Clock, _info: Any = None) -> None:
        """use_sim_time: the latest external /clock."""
        self._external.take(msg.clock.sec * NS_PER_S + msg.clock.nanosec)

    def _run_real_time(self, stop: StopFlag) -> None:
        """Real time: wake on a fixed grid of the monotonic clock (`wake_period`), take the inputs, run the
        steps due by wall time (`RealTimeSchedule`: model time never ahead of wall time, never drifting),
        publish the samples that fell due. Falling behind: the backlog is computed up to the catch-up
        bound (`overrun`, `max_catchup`), beyond it skipped (the model state held over it)."""
        s, dev = self.settings, self.device
        sched = RealTimeSchedule(dev.dt, wake_period=s.wake_period, late_threshold=s.late_threshold,
                                 max_catchup=s.catchup_bound)
        self._schedule = sched
        tighten_timer_slack()
        # Another Python thread (a worker computing rest states, a recorder) competes for the
        # interpreter lock: hand it back within one wake period rather than the default 5 ms.
        sys.setswitchinterval(SWITCH_INTERVAL)
        if s.realtime_priority:
            set_realtime_priority(s.realtime_priority, self.get_logger())
        freeze_heap()
        mono = time.monotonic
        sched.start()
        self._begin(self.get_clock().now().nanoseconds)
        self._diag.restart(mono(), dev.steps)
        next_diag = mono() + s.diagnostics_period
        cpu = time.thread_time
        # Each wake's parts, CPU time and collections (`WakeRecord`): the diagnostics name what
        # filled the longest gap between two wakes.
        with GcTimer(mono) as collected:
            while not stop.requested:
                now = mono()
                c0 = cpu()
                gc0 = collected.total
                self._drain()
                drained = mono()
                steps = 0
                if not self._halted():
                    plan = sched.plan(now)
                    if plan.skipped:
                        self._skip(plan.skipped)
                        st = self.settings
                        bound = (f"max_catchup {st.max_catchup * 1e3:g} ms" if st.overrun == "catch_up"
                                 else "one wake period, overrun: skip")
                        self.get_logger().warning(
                            f"{plan.lag * 1e3:.1f} ms behind wall time (more than {bound}): "
                            f"skipped {plan.skipped} steps, the model state was held over them",
                            throttle_duration_sec=1.0)
                    steps = plan.steps
                    if steps:
                        self._compute(steps)
                    sched.finish()
                computed = mono()
                sched.note_wake_cpu(cpu() - c0)
                if now >= next_diag:
                    self._publish_diagnostics(now)
                    next_diag = max(next_diag + self.settings.diagnostics_period, now)
                end = mono()
                delay = sched.next_wake(end) - end
                sched.note_wake(WakeRecord(now, drained - now, computed - drained, end - computed, end, cpu() - c0,
                                           collected.total - gc0, steps, delay))
                if delay > 0.0:
                    time.sleep(delay)

    def _retime(self, settings: Any) -> None:
        """Changed settings into the running loop's schedule (late threshold, catch-up bound, pace)."""
        if self._schedule is not None:
            self._schedule.late_threshold = settings.late_threshold
            self._schedule.max_catchup_steps = int(settings.catchup_bound / self.device.dt)
        if self._sim is not None and self._sim.factor != settings.real_time_factor:
            self._sim.set_factor(settings.real_time_factor)

    def _run_external_clock(self, stop: StopFlag) -> None:
        """use_sim_time: model time follows an external /clock (e.g. a Gazebo simulation).

        Model time 0 is the first /clock received (stamps = that clock); whenever /clock advances,
        the steps up to it run and the samples that fell due are published. An input acts from the
        step after the last one run when it was taken. The clock going back (a simulation reset)
        re-anchors model time at the new clock, keeping the model's state; a jump far ahead is held
        (`ExternalClock`)."""
        freeze_heap()
        mono = time.monotonic
        ext = self._external
        self._diag.restart(mono(), self.model_steps)
        next_diag = mono() + self.settings.diagnostics_period
        loops = 0
        while not stop.requested:
            loops += 1
            self._drain()
            now = mono()
            if now >= next_diag:
                self._publish_diagnostics(now)
                next_diag = max(next_diag + self.settings.diagnostics_period, now)
            if ext.latest_ns is None:
                if loops == 2000:           # ~2 s: say why nothing is published
                    self.get_logger().warning(NO_CLOCK_YET)
                time.sleep(1e-3)
                continue
            if not ext.started:
                self._begin(ext.start(self.model_steps))
                continue
            if self._halted():
                time.sleep(1e-2)
                continue
            plan = ext.plan(self.model_steps)
            if plan.reanchored:
                self._set_origin(ext.origin_ns)
                self.get_logger().warning(ext.went_back(), throttle_duration_sec=1.0)
            elif plan.skip:
                self._skip(plan.skip)
                self.get_logger().warning(ext.jumped(plan.skip), throttle_duration_sec=1.0)
            elif plan.run:
                self._compute(plan.run)
            else:
                time.sleep(2e-4)           # wait for the clock to advance

    @property
    def model_steps(self) -> int:
        """The device's model steps computed (or skipped) so far."""
        return self.device.steps

    def _begin(self, origin_ns: int) -> None:
        """Model time 0 is stamped origin_ns: the first sample (and the recording) start."""
        raise NotImplementedError

    def _set_origin(self, origin_ns: int) -> None:
        self.device.origin_ns = origin_ns

    def _skip(self, n: int) -> None:
        """n steps of model time pass uncomputed (the state held)."""
        self.device.skip(n)

    def _compute(self, n: int) -> None:
        """n model steps computed, their samples published."""
        raise NotImplementedError

    def _halted(self) -> bool:
        """True while the model stands still (it ran away) until a reset."""
        return False

    def publish_clock(self, accepted: str) -> None:
        """In simulated time the /clock publisher, the domain's one clock: refused beside another
        (`accepted` says what to do instead); otherwise none."""
        if self.simulated:
            self.refuse_a_second_clock(accepted)
        self._pub_clock = (self.create_publisher(Clock, CLOCK, topic_qos(CLOCK), event_callbacks=self.output_events(CLOCK))
                           if self.simulated else None)

    def follow_clock(self) -> None:
        """With use_sim_time, /clock in: the model follows it (`ExternalClock`, `_run_external_clock`)."""
        self._external = ExternalClock(self.device.dt_ns)
        if self.external_clock:
            sub = self.create_subscription(Clock, CLOCK, self._on_clock, topic_qos(CLOCK),
                                           event_callbacks=self.input_events(CLOCK))
            self._inputs.append((sub, self._on_clock))

    def refuse_a_second_clock(self, accepted: str) -> None:
        """Two simulated-time nodes would both publish /clock, and every node with use_sim_time would see
        time jump between them. Before creating its own /clock publisher the node looks for another one
        for up to CLOCK_DISCOVERY s (discovery is usually done within the node's creation; under load it
        can take longer) and refuses to start if it finds one. Only the newcomer looks, so a running
        simulation is never stopped by a second one."""
        end = time.monotonic() + CLOCK_DISCOVERY
        while True:
            others = self.count_publishers(CLOCK)
            if others > 0 or time.monotonic() >= end:
                break
            time.sleep(0.05)
        if others > 0:
            raise ParameterError(f"time_mode: simulated: {others} other publisher(s) of {CLOCK} found; two clocks "
                                 f"make time jump for every node that follows /clock. Accepted is one clock: {accepted}")
