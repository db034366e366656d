"""The health of any device's node (the emulator, the rig), one status per concern, so that an
aggregator can tell causes apart; the emulator is the case of one valve.

No ROS here: `DiagnosticsBuilder.build` returns plain `Status` values (level, message, key values
as strings, SI units in the key names); the node turns them into a DiagnosticArray.

REP 107 style: every status is named `<node full name>: <concern>` and carries the node's full
name as hardware_id (one device). Levels:

    timing     WARN when, over the last period, the late-step fraction exceeds
               `diagnostics.late_fraction` or the model lagged wall time by more than
               `diagnostics.max_lag` at a wake (how late the first sample of the batch leaves), or
               steps were skipped.
               A few late steps on a shared machine are normal and stay OK.
    inputs     WARN while a watchdog has fired or a fault is active, or when inputs were rejected
               in the period.
    model      ERROR while the model is faulted (no samples are published); OK otherwise.
    recording  OK when off or recording; WARN when messages were dropped in the period; ERROR
               when the recording failed.
    <valve>    a device whose valves are named (the rig's `left`, `right`): one status per valve,
               its inputs (watchdog, duty in force and last valid, the faults on it or its signals,
               its inputs' counts, its options' temperatures) and its last sample; WARN while its
               watchdog has fired, a fault is active on it or its inputs were refused in the period.
               The emulator's one valve goes by the bare names (its topics are `duty_cycle`,
               `pressure`): its inputs are in `inputs`, its last sample in `model`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from pcv_sim.device.device import Device
from pcv_sim.device.inputs import WatchdogState
from pcv_sim.io.recorder import RecorderStatus
from pcv_sim.io.topics import (
    CURRENT,
    DUTY_CYCLE,
    EMULATOR_INTERFACE,
    FAULTS,
    LOAD_FLOW,
    OPTION_INTERFACE,
    PRESSURE,
    RIG_INTERFACE,
    SPOOL_POSITION,
    SUPPLY_PRESSURE,
    input_topics,
)
from pcv_sim.simulation.clock import RealTimeSchedule
from pcv_sim.units import bar

__all__ = ["CONCERNS", "ERROR", "OK", "WARN", "DiagnosticsBuilder", "Shown", "Status", "recording_status",
           "valve_inputs", "valve_signals"]

OK, WARN, ERROR = 0, 1, 2
CONCERNS = ("timing", "inputs", "model", "recording")
#: A topic's unit (`pcv_sim.io.topics`), for the keys of the values it carries.
_UNITS = {e.name: e.unit for e in (*EMULATOR_INTERFACE, *RIG_INTERFACE, *OPTION_INTERFACE)}


def unit_key(unit: str) -> str:
    """A unit as a key's suffix: Pa -> pa, m^3/s -> m3s, N -> n, K -> k."""
    return unit.lower().replace("^", "").replace("/", "")


@dataclass(frozen=True)
class Status:
    name: str
    hardware_id: str
    level: int
    message: str
    values: dict[str, str] = field(default_factory=dict)


@dataclass(frozen=True)
class Shown:
    """What the node showed of its device, for its diagnostics."""

    time_mode: str                      # real, simulated or external_clock
    samples_published: int
    resets: int                         # reset service calls that acted
    waiting_for: tuple[str, ...] = ()   # simulated lockstep: the valves whose answer it waits for


def _prefix(device: Device, valve: str) -> str:
    """How a valve's inputs and signals are named: `<valve>.` (the rig's), or bare (the emulator's)."""
    return "" if device.lone_valve else f"{valve}."


def valve_inputs(device: Device, valve: str, new: dict[str, int]) -> tuple[list[str], dict[str, Any]]:
    """What the diagnostics say of one valve's inputs (`new`: the counts gained in the period,
    `rejected.<input>`): its watchdog (state, timeout, firings and their stamps, the safe duty), the
    duty command in force (the safe duty while the watchdog holds), the last valid one and the duty
    the model uses (after the fall-rate limiter), its supply pressure (the emulator's load flow
    too), the faults on it or its signals, its inputs' counts (`accepted.<role>`,
    `rejected.<role>`: duty_cycle, the options' temperatures...) and the options' temperatures in
    force (`<name>_k`). Problems: a fired watchdog, active faults, refused inputs in the period."""
    prefix = _prefix(device, valve)
    dog = device.watchdogs[valve]
    timeout = dog.timeout_steps * device.dt
    faults = [f"{kind}@{target}" for target, kind in device.faults
              if not prefix or target == valve or target.startswith(prefix)]
    problems = []
    if dog.state == WatchdogState.FIRED:
        problems.append(f"watchdog: no duty command for {timeout:g} s, safe duty {device.safe_duty:g}")
    if faults:
        problems.append(f"faults active: {', '.join(faults)}")
    mine = [n for n in device.inputs if n.startswith(prefix)] if prefix else list(device.inputs)
    rejected = {n[len(prefix):]: new.get(f"rejected.{n}", 0) for n in mine}
    if any(rejected.values()):
        problems.append("rejected inputs: " + ", ".join(f"{k} {v}" for k, v in rejected.items() if v))
    in_force = device.input_values()
    values: dict[str, Any] = {
        "watchdog": dog.state,
        "watchdog_timeout_s": f"{timeout:g}",
        "watchdog_fired_count": dog.fired,
        "safe_duty": f"{device.safe_duty:g}",
        "duty_command": f"{device.duties[valve]:g}",
        "duty_last_valid": f"{device.commands[valve]:g}" if dog.command_step is not None else "",
        "duty_applied_stamp_ns": device.stamp_ns(dog.command_step) if dog.command_step is not None else "",
        "watchdog_fired_stamp_ns": device.stamp_ns(dog.fired_step) if dog.fired_step is not None else "",
        "faults_active": ", ".join(faults),
        "duty_effective": f"{in_force[f'{prefix}{DUTY_CYCLE}']:g}",
        f"{SUPPLY_PRESSURE}_pa": f"{in_force[f'{prefix}{SUPPLY_PRESSURE}']:g}",
    }
    if not prefix and LOAD_FLOW in device.inputs:   # the emulator's valve on its own load volume
        values[f"{LOAD_FLOW}_{unit_key(_UNITS[LOAD_FLOW])}"] = f"{getattr(device, LOAD_FLOW):g}"
    for n in mine:
        role = n[len(prefix):]
        values[f"accepted.{role}"] = device.counts.accepted.get(n, 0)
        values[f"rejected.{role}"] = device.counts.rejected.get(n, 0)
    for n in device.option_inputs:                   # the valve options' temperatures in force (K)
        if n.startswith(prefix):
            values[f"{n[len(prefix):]}_k"] = f"{in_force[n]:.2f}"
    return problems, values


def valve_signals(device: Device, valve: str) -> dict[str, Any]:
    """One valve's signals in the device's last sample (SI; read, not computed: computing outputs moves
    the coil solve's Newton start, and a run must not depend on when the wall-clock diagnostics came),
    its options' outputs too (`coil_temperature_k`, `coil_resistance_ohm`, `core_position_m`)."""
    prefix = _prefix(device, valve)
    last = device.last_sample
    y = dict(zip(device.signals, last.values.tolist())) if last is not None else {}

    def show(signal: str, fmt: str) -> str:
        v = y.get(f"{prefix}{signal}")
        return format(v, fmt) if v is not None else ""

    values: dict[str, Any] = {
        "pressure_pa": show(PRESSURE, ".1f"),
        "pressure_bar": format(bar(y[f"{prefix}{PRESSURE}"]), ".3f") if f"{prefix}{PRESSURE}" in y else "",
        "current_a": show(CURRENT, ".5f"),
        "spool_position_m": show(SPOOL_POSITION, ".4e"),
    }
    for signal in device.option_outputs:
        if signal.startswith(prefix) and signal in y:
            option = signal[len(prefix):]
            values[f"{option}_{unit_key(_UNITS[option])}"] = f"{y[signal]:.6g}"
    return values


class DiagnosticsBuilder:
    """The statuses of any device (see the module docstring); `build` once per diagnostics period.
    It keeps between two builds the wall time, the model steps and the counts of the previous one,
    so that a build reports the period's."""

    def __init__(self, node_name: str, now: float, chambers: dict[str, str] | None = None) -> None:
        self.node_name = node_name
        self.chambers = dict(chambers or {})        # valve -> the cylinder chamber it feeds (a | b)
        self._wall = now
        self._steps = 0
        self._counts: dict[str, int] = {}
        self._dropped = 0                  # the recorder's drops at the previous build

    def restart(self, now: float, steps: int) -> None:
        """Start the first period at `now` (the loop's start)."""
        self._wall, self._steps = now, steps

    def _status(self, concern: str, level: int, problems: list[str], ok: str, values: dict[str, Any]) -> Status:
        return Status(f"{self.node_name}: {concern}", self.node_name, level, "; ".join(problems) if problems else ok,
                      {k: str(v) for k, v in values.items()})

    def _period(self, now: float, steps: int, counts: dict[str, int],
                schedule: RealTimeSchedule | None) -> tuple[float, int, dict[str, int]]:
        """Wall seconds and model steps since the previous build, and what each count (with the
        schedule's late and skipped steps, in real time) gained since then; starts a new period."""
        if schedule is not None:
            counts["late_steps"] = schedule.late_steps
            counts["skipped_steps"] = schedule.skipped_steps
        wall = max(now - self._wall, 1e-9)
        period_steps = steps - self._steps
        new = {k: v - self._counts.get(k, 0) for k, v in counts.items()}
        self._wall, self._steps, self._counts = now, steps, counts
        return wall, period_steps, new

    def build(self, now: float, *, device: Device, settings: Any, schedule: RealTimeSchedule | None,
              recorder: RecorderStatus | None, shown: Shown) -> list[Status]:
        """The four concerns', then (a device of named valves) one status per valve. `settings`: the
        node's (`pcv_sim.device.settings.CommonSettings`); `recorder`: the recording's status
        (record.enabled)."""
        dev, s = device, settings
        wall, period_steps, new = self._period(
            now, dev.steps, {f"rejected.{k}": v for k, v in dev.counts.rejected.items()}, schedule)
        named = [v for v in dev.valve_names if _prefix(dev, v)]
        return [self._timing(dev, s, schedule, new, wall, period_steps, shown),
                self._inputs(dev, new, named),
                self._model(dev, shown, named),
                self._recording(recorder),
                *(self._valve(dev, v, new) for v in named)]

    def _timing(self, dev: Device, s: Any, sched: RealTimeSchedule | None, new: dict[str, int],
                wall: float, period_steps: int, shown: Shown) -> Status:
        time_mode = shown.time_mode
        values: dict[str, Any] = {
            "time_mode": time_mode,
            "model_time_s": f"{dev.time:.4f}",
            "real_time_factor": f"{period_steps * dev.dt / wall:.4f}",
            "model_time_origin_ns": dev.origin_ns,
            "sample_period_s": f"{dev.sample_every * dev.dt:g}",
        }
        problems: list[str] = []
        if sched is None:
            values["lockstep"] = str(s.lockstep).lower()
            values["real_time_factor_set"] = f"{s.real_time_factor:g}"
            values["waiting_for"] = ", ".join(shown.waiting_for)
            return self._status("timing", OK, problems, f"{time_mode} time", values)
        late, skipped = new["late_steps"], new["skipped_steps"]
        computed = max(period_steps - skipped, 1)
        fraction = late / computed
        lag, lag_after = sched.take_period_max()
        if fraction > s.diagnostics_late_fraction:
            problems.append(f"{late} of {computed} steps late ({100 * fraction:.1f} % > "
                            f"{100 * s.diagnostics_late_fraction:g} %) in the last {wall:.1f} s")
        # The first sample of a batch that catches up leaves the node `lag` after its model time.
        if lag > s.diagnostics_max_lag:
            problems.append(f"samples up to {lag * 1e3:.1f} ms behind wall time (> "
                            f"{s.diagnostics_max_lag * 1e3:g} ms)")
        if skipped:
            problems.append(f"{skipped} steps skipped (model held; overrun {s.overrun})")
        values.update({
            "overrun": s.overrun,
            "late_steps": sched.late_steps,
            "skipped_steps": sched.skipped_steps,
            "period_late_fraction": f"{fraction:.5f}",
            "late_threshold_ms": f"{s.late_threshold * 1e3:g}",
            "lag_ms": f"{sched.lag_after * 1e3:.3f}",
            "max_lag_ms": f"{sched.max_lag * 1e3:.3f}",
            "max_wake_cpu_ms": f"{sched.max_wake_cpu * 1e3:.3f}",
            "period_max_wake_cpu_ms": f"{sched.take_period_wake_cpu() * 1e3:.3f}",
            "max_lag_after_step_ms": f"{sched.max_lag_after * 1e3:.3f}",
            "period_max_lag_ms": f"{lag * 1e3:.3f}",
            "period_max_lag_after_step_ms": f"{lag_after * 1e3:.3f}",
            "wakes": sched.wakes,
        })
        gap, mean_cpu, collecting = sched.take_period_wakes()
        values.update({
            "period_mean_wake_cpu_ms": f"{mean_cpu * 1e3:.4f}",
            "period_gc_ms": f"{collecting * 1e3:.3f}",
            "max_wake_gap_ms": f"{sched.max_wake_gap * 1e3:.3f}",
            "period_max_wake_gap_ms": f"{gap.gap * 1e3:.3f}" if gap is not None else "",
            "period_max_wake_gap_cause": gap.cause if gap is not None else "",
            "period_max_wake_gap": gap.describe() if gap is not None else "",
        })
        return self._status("timing", WARN if problems else OK, problems, "on time", values)

    def _inputs(self, dev: Device, new: dict[str, int], named: list[str]) -> Status:
        """The device's inputs: its one bare valve's (the emulator), or what the named valves' statuses
        sum up to (faults, watchdogs, rejections); the inputs of no valve (the plant's:
        `cylinder.external_force`) and fault commands."""
        waiting = [v for v in dev.valve_names if dev.watchdogs[v].state == WatchdogState.WAITING]
        if named:
            faults = [f"{kind}@{target}" for target, kind in dev.faults]
            fired = [v for v in dev.valve_names if dev.watchdogs[v].state == WatchdogState.FIRED]
            problems = []
            if faults:
                problems.append(f"faults active: {', '.join(faults)}")
            if fired:
                problems.append(f"watchdog fired: {', '.join(fired)}")
            values: dict[str, Any] = {
                "faults_active": ", ".join(faults),
                "watchdog_fired": ", ".join(fired),
                "rejected_inputs": sum(dev.counts.rejected.values()),
                f"rejected.{DUTY_CYCLE}": sum(dev.counts.rejected.get(f"{v}.{DUTY_CYCLE}", 0) for v in named),
            }
            ok = f"waiting for the first duty command of {', '.join(waiting)}" if waiting else "commands arriving"
        else:
            problems, values = valve_inputs(dev, dev.valve_names[0], new)
            ok = "waiting for the first duty command" if waiting else "commands arriving"
        in_force = dev.input_values()
        for entry in input_topics(dev.input_names, dev.valve_names):
            owner = entry.input.rpartition(".")[0]
            if not owner or owner in dev.valve_names:
                continue                                # a valve's
            role = entry.input.rpartition(".")[2]
            values[f"{role}_{unit_key(_UNITS[entry.topic])}"] = f"{in_force[entry.input]:g}"
            values[f"accepted.{role}"] = dev.counts.accepted.get(entry.input, 0)
            values[f"rejected.{role}"] = dev.counts.rejected.get(entry.input, 0)
            if new.get(f"rejected.{entry.input}"):
                problems.append(f"rejected inputs: {role} {new[f'rejected.{entry.input}']}")
        if new.get(f"rejected.{FAULTS}"):
            problems.append(f"rejected inputs: {FAULTS} {new[f'rejected.{FAULTS}']}")
        values.update({
            "last_rejection": dev.counts.last_rejection,
            f"accepted.{FAULTS}": dev.counts.accepted.get(FAULTS, 0),
            f"rejected.{FAULTS}": dev.counts.rejected.get(FAULTS, 0),
        })
        return self._status("inputs", WARN if problems else OK, problems, ok, values)

    def _model(self, dev: Device, shown: Shown, named: list[str]) -> Status:
        values: dict[str, Any] = {
            "model": "fault" if dev.fault else "ok",
            "fault_reason": dev.fault or "",
            "integrator": dev.sim.integrator,
        }
        if not named:                                   # the one bare valve's last sample
            values.update(valve_signals(dev, dev.valve_names[0]))
        values.update({"samples_published": shown.samples_published, "resets": shown.resets})
        if dev.fault is not None:
            return self._status("model", ERROR, [f"model fault: {dev.fault}; call the reset service"], "", values)
        return self._status("model", OK, [], "running", values)

    def _valve(self, dev: Device, valve: str, new: dict[str, int]) -> Status:
        problems, values = valve_inputs(dev, valve, new)
        if valve in self.chambers:
            values["chamber"] = self.chambers[valve]
        values.update(valve_signals(dev, valve))
        ok = "waiting for the first duty command" if dev.watchdogs[valve].state == WatchdogState.WAITING \
            else "commands arriving"
        return self._status(valve, WARN if problems else OK, problems, ok, values)

    def _recording(self, st: RecorderStatus | None) -> Status:
        if st is None:
            return self._status("recording", OK, [], "off", {"recording": "off"})
        level, problems, values = recording_status(st, self._dropped)
        self._dropped = st.dropped
        return self._status("recording", level, problems, st.state, values)


def recording_status(st: RecorderStatus, dropped_before: int) -> tuple[int, list[str], dict[str, Any]]:
    """Level, problems and `recording*` values of a recorder;
    `dropped_before`: its drop count at the previous diagnostics."""
    new_dropped = st.dropped - dropped_before
    problems = []
    if st.error:
        problems.append(f"recording failed: {st.error}")
    if new_dropped:
        problems.append(f"recording dropped {new_dropped} messages in the last period")
    level = ERROR if st.error else WARN if new_dropped else OK
    values = {
        "recording": st.state,
        "recording_path": str(st.path),
        "recording_messages": st.messages,
        "recording_bytes": st.bytes,
        "recording_files": st.files,
        "recording_queued": st.queued,
        "recording_dropped": st.dropped,
        "recording_error": st.error,
    }
    return level, problems, values
