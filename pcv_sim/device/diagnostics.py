"""The emulator's health as four statuses, one per concern, so an aggregator can tell causes apart.

No ROS here: `DiagnosticsBuilder.build` returns plain `Status` values (level, message, key values
as strings, SI units in the key names); the node turns them into a DiagnosticArray.

REP 107 style: every status is named `<node full name>: <concern>` and carries the node's full
name as hardware_id (one device). Levels:

    timing     WARN when, over the last period, the late-step fraction exceeds
               `diagnostics.late_fraction` or the model lagged wall time by more than
               `diagnostics.max_lag` at a wake (how late the first sample of the batch leaves), or
               steps were skipped.
               A few late steps on a shared machine are normal and stay OK.
    inputs     WARN while the watchdog has fired, or when inputs were rejected in the period.
    model      ERROR while the model is faulted (no samples are published); OK otherwise.
    recording  OK when off or recording; WARN when messages were dropped in the period; ERROR
               when the recording failed.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from pcv_sim.device.inputs import WatchdogState
from pcv_sim.device.settings import NodeSettings
from pcv_sim.device.valve import VALVE, ValveDevice
from pcv_sim.io.recorder import RecorderStatus
from pcv_sim.io.topics import FAULTS, OPTION_INTERFACE
from pcv_sim.simulation.clock import RealTimeSchedule
from pcv_sim.units import bar

_OPTION_UNITS = {e.name: e.unit for e in OPTION_INTERFACE}

__all__ = ["CONCERNS", "ERROR", "OK", "WARN", "DiagnosticsBuilder", "PeriodDiagnostics", "Shown", "Status",
           "recording_status", "valve_inputs"]

OK, WARN, ERROR = 0, 1, 2
CONCERNS = ("timing", "inputs", "model", "recording")


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
    last: dict[str, float]              # the last published sample: signal -> measured value (SI)
    waiting_for: tuple[str, ...] = ()   # simulated lockstep: the valves whose answer it waits for


def valve_inputs(device: Any, valve: str, new: dict[str, int]) -> tuple[list[str], dict[str, Any]]:
    """What every device's diagnostics say of one valve's inputs (`device`: a `Device`; `new`: the
    counts gained in the period, `rejected.<input>`): its watchdog (state, timeout, firings and
    their stamps, the safe duty), the duty command in force (the safe duty while the watchdog
    holds) and the last valid one, the faults on it or its signals, its inputs' counts
    (`accepted.<role>`, `rejected.<role>`: duty_cycle, the options' temperatures...) and the
    options' temperatures in force (`<name>_k`). Problems: a fired watchdog, active faults,
    refused inputs in the period."""
    prefix = f"{valve}." if f"{valve}.duty_cycle" in device.inputs else ""
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
    }
    for n in mine:
        role = n[len(prefix):]
        values[f"accepted.{role}"] = device.counts.accepted.get(n, 0)
        values[f"rejected.{role}"] = device.counts.rejected.get(n, 0)
    # The valve options' temperatures in force (K), read without computing an output.
    temperatures = ({n[len(prefix):]: v for n, v in device.input_values().items()
                     if n in device.option_inputs and n.startswith(prefix)} if prefix
                    else device.option_input_values())
    for n, value in temperatures.items():
        values[f"{n}_k"] = f"{value:.2f}"
    return problems, values


class PeriodDiagnostics:
    """What every node's diagnostics keep between two builds (one per diagnostics period): the wall
    time, the model steps and the counts of the previous build, so that a build reports the period's."""

    def __init__(self, node_name: str, now: float) -> None:
        self.node_name = node_name
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


class DiagnosticsBuilder(PeriodDiagnostics):
    """The emulator's four statuses; `build` once per diagnostics period."""

    def build(self, now: float, *, device: ValveDevice, settings: NodeSettings, schedule: RealTimeSchedule | None,
              recorder: RecorderStatus | None, shown: Shown) -> list[Status]:
        dev, s = device, settings
        wall, period_steps, new = self._period(
            now, dev.steps, {f"rejected.{k}": v for k, v in dev.counts.rejected.items()}, schedule)
        return [self._timing(dev, s, schedule, new, wall, period_steps, shown.time_mode),
                self._inputs(dev, s, new),
                self._model(dev, shown.samples_published),
                self._recording(recorder)]

    def _timing(self, dev: ValveDevice, s: NodeSettings, sched: RealTimeSchedule | None, new: dict[str, int],
                wall: float, period_steps: int, time_mode: str) -> Status:
        values: dict[str, Any] = {
            "time_mode": time_mode,
            "model_time_s": f"{dev.time:.4f}",
            "real_time_factor": f"{period_steps * dev.dt / wall:.4f}",
            "model_time_origin_ns": dev.origin_ns,
        }
        problems: list[str] = []
        if sched is None:
            values["lockstep"] = str(s.lockstep).lower()
            values["real_time_factor_set"] = f"{s.real_time_factor:g}"
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
        return self._status("timing", WARN if problems else OK, problems, "on time", values)

    def _inputs(self, dev: ValveDevice, s: NodeSettings, new: dict[str, int]) -> Status:
        problems, values = valve_inputs(dev, VALVE, new)
        if new.get(f"rejected.{FAULTS}"):
            problems.append(f"rejected inputs: {FAULTS} {new[f'rejected.{FAULTS}']}")
        last = dev.last_good
        values.update({
            "duty_effective": f"{last.duty:g}" if last else "",
            "load_flow_m3s": f"{dev.load_flow:g}",
            "supply_pressure_pa": f"{dev.input_values()['supply_pressure']:g}",
            "last_rejection": dev.counts.last_rejection,
            f"accepted.{FAULTS}": dev.counts.accepted.get(FAULTS, 0),
            f"rejected.{FAULTS}": dev.counts.rejected.get(FAULTS, 0),
        })
        ok = ("waiting for the first duty command" if dev.watchdog_state == WatchdogState.WAITING
              else "commands arriving")
        return self._status("inputs", WARN if problems else OK, problems, ok, values)

    def _model(self, dev: ValveDevice, samples_published: int) -> Status:
        last = dev.last_good
        values: dict[str, Any] = {
            "model": "fault" if dev.fault else "ok",
            "fault_reason": dev.fault or "",
            "integrator": dev.sim.integrator,
            "pressure_pa": f"{last.pressure:.1f}" if last else "",
            "pressure_bar": f"{bar(last.pressure):.3f}" if last else "",
            "current_a": f"{last.current:.5f}" if last else "",
            "spool_position_m": f"{last.spool_position:.4e}" if last else "",
            "samples_published": samples_published,
        }
        for name, value in zip(dev.option_outputs, last.options if last else ()):   # the options' outputs
            values[f"{name}_{_OPTION_UNITS[name].lower()}"] = f"{value:.6g}"
        if dev.fault is not None:
            return self._status("model", ERROR, [f"model fault: {dev.fault}; call the reset service"], "", values)
        return self._status("model", OK, [], "running", values)

    def _recording(self, st: RecorderStatus | None) -> Status:
        if st is None:
            return self._status("recording", OK, [], "off", {"recording": "off"})
        level, problems, values = recording_status(st, self._dropped)
        self._dropped = st.dropped
        return self._status("recording", level, problems, st.state, values)


def recording_status(st: RecorderStatus, dropped_before: int) -> tuple[int, list[str], dict[str, Any]]:
    """Level, problems and `recording*` values of a recorder (the emulator's and the rig node's);
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
