"""The rig node's health, without ROS and beside the rig: one status per valve and one for the rig.

`RigDiagnostics.build` returns plain `Status` values (pcv_sim.device.diagnostics' type: level,
message, string key values with SI units in the names); the node turns them into a
DiagnosticArray. Names `<node full name>: <valve>` and `<node full name>: rig`, hardware_id the
node's full name (REP 107 style, as the emulator's).

    <valve>  the emulator's `inputs` status for this valve (`pcv_sim.device.diagnostics.valve_inputs`:
             watchdog, duty in force and last valid, faults on it or its signals, its inputs' counts,
             its options' temperatures; WARN while its watchdog has fired, a fault is active on it or
             its inputs were refused in the period), its chamber, its last published signals and its
             options' outputs (`coil_temperature_k`, `coil_resistance_ohm`, `core_position_m`).
    rig      ERROR when the model ran away (non-finite: nothing is published any more) or the
             recording failed; WARN while any fault is active, any watchdog has fired, fault or
             external force commands were refused in the period, (real time) steps were skipped in
             the period (late ones are counted), or the recording dropped messages in the period.
             With record.enabled it carries the emulator's `recording*` keys.
"""

from __future__ import annotations

import math
from typing import Any

from pcv_sim.device.diagnostics import (
    ERROR,
    OK,
    WARN,
    PeriodDiagnostics,
    Shown,
    Status,
    recording_status,
    valve_inputs,
)
from pcv_sim.io.recorder import RecorderStatus
from pcv_sim.io.topics import DUTY_CYCLE, FAULTS, OPTION_INTERFACE
from pcv_sim.rig.rig import EXTERNAL_FORCE, Rig
from pcv_sim.rig.settings import RigNodeSettings
from pcv_sim.simulation.clock import RealTimeSchedule

__all__ = ["RigDiagnostics"]

_OPTION_UNITS = {e.name: e.unit for e in OPTION_INTERFACE}


class RigDiagnostics(PeriodDiagnostics):
    """One status per valve and one for the rig; `build` once per diagnostics period."""

    _recorder: RecorderStatus | None = None          # of the build in progress

    def build(self, now: float, *, device: Rig, settings: RigNodeSettings, schedule: RealTimeSchedule | None,
              recorder: RecorderStatus | None, shown: Shown) -> list[Status]:
        """`last`: the last published (measured) sample, signal -> SI value. Never the rig's sample()
        here: computing outputs moves the coil solve's Newton start, and a run must not depend on
        when the wall-clock diagnostics came. The valve options' outputs are in `last` too
        (`<valve>.coil_temperature`...), their inputs read from the rig (what is in force). `recorder`:
        the recording's status (record.enabled). The inputs' counts are the rig's (`Device.counts`,
        by input name: `<valve>.duty_cycle`, `cylinder.external_force`, `faults`...)."""
        self._recorder = recorder
        rig, last = device, shown.last
        counts = rig.counts
        wall, period_steps, new = self._period(now, rig.steps, {f"rejected.{k}": n for k, n in counts.rejected.items()},
                                               schedule)
        statuses = [self._valve(rig, v, new, last) for v in rig.valve_names]
        statuses.append(self._rig(rig, shown.resets, shown.samples_published, new, shown.time_mode, settings.lockstep,
                                  schedule, rig.fault, shown.waiting_for, period_steps * rig.dt / wall))
        return statuses

    def _valve(self, rig: Rig, name: str, new: dict[str, int], y: dict[str, float]) -> Status:
        problems, values = valve_inputs(rig, name, new)     # the emulator's inputs status, for this valve
        values["chamber"] = rig.params.valve(name).chamber
        for key, signal, fmt in (("pressure_pa", "pressure", ".1f"), ("current_a", "current", ".5f"),
                                 ("spool_position_m", "spool_position", ".4e")):
            v = y.get(f"{name}.{signal}")
            values[key] = format(v, fmt) if v is not None and not math.isnan(v) else ""
        for signal in rig.option_outputs:               # the options' outputs, as last published
            if signal.startswith(f"{name}.") and (v := y.get(signal)) is not None:
                option = signal.partition(".")[2]
                values[f"{option}_{_OPTION_UNITS[option].lower()}"] = f"{v:.6g}"
        return self._status(name, WARN if problems else OK, problems, "ok", values)

    def _rig(self, rig: Rig, resets: int, samples_published: int, new: dict[str, int], time_mode: str,
             lockstep: bool, sched: RealTimeSchedule | None, failure: str | None, waiting_for: tuple[str, ...],
             factor: float) -> Status:
        counts = rig.counts
        faults = [f"{kind}@{target}" for (target, kind) in rig.faults]
        fired = [v for v in rig.valve_names if rig.watchdog_fired[v]]
        rejected = sum(counts.rejected.get(f"{v}.{DUTY_CYCLE}", 0) for v in rig.valve_names)
        problems = []
        if faults:
            problems.append(f"fault(s) active: {', '.join(faults)}")
        if fired:
            problems.append(f"watchdog fired: {', '.join(fired)}")
        if new.get(f"rejected.{FAULTS}"):
            problems.append(f"{new[f'rejected.{FAULTS}']} fault command(s) rejected")
        if new.get(f"rejected.{EXTERNAL_FORCE}"):
            problems.append(f"{new[f'rejected.{EXTERNAL_FORCE}']} external force command(s) rejected")
        values: dict[str, Any] = {
            "time_mode": time_mode,
            "lockstep": str(lockstep).lower() if time_mode == "simulated" else "",
            "model_time_s": f"{rig.time:.4f}",
            "real_time_factor": f"{factor:.4f}",
            "control_period_s": f"{rig.params.timing.control_period:g}",
            "faults_active": ", ".join(faults),
            "watchdog_fired": ", ".join(fired),
            "rejected_inputs": sum(counts.rejected.values()),
            "rejected.duty_cycle": rejected,
            "rejected.faults": counts.rejected.get(FAULTS, 0),
            "accepted.faults": counts.accepted.get(FAULTS, 0),
            "external_force_n": f"{rig.input_values()[EXTERNAL_FORCE]:g}",
            "accepted.external_force": counts.accepted.get(EXTERNAL_FORCE, 0),
            "rejected.external_force": counts.rejected.get(EXTERNAL_FORCE, 0),
            "resets": resets,
            "last_rejection": counts.last_rejection,
            "samples_published": samples_published,
            "waiting_for": ", ".join(waiting_for),
        }
        if sched is not None:
            # Late steps are counted, not warned about: on a shared machine a few are normal (the
            # emulator's timing status has the thresholds); skipped ones are a jump of the model.
            if new.get("skipped_steps"):
                problems.append(f"{new['skipped_steps']} steps skipped (model held)")
            period_lag, _ = sched.take_period_max()        # the emulator's figure: the period's worst lag
            values.update({"late_steps": sched.late_steps, "skipped_steps": sched.skipped_steps,
                           "max_lag_ms": f"{sched.max_lag * 1e3:.3f}", "period_max_lag_ms": f"{period_lag * 1e3:.3f}"})
        rec_level = OK
        if self._recorder is not None:
            rec_level, rec_problems, rec_values = recording_status(self._recorder, self._dropped)
            self._dropped = self._recorder.dropped
            problems += rec_problems
            values.update(rec_values)
        if failure is not None:
            return self._status("rig", ERROR, [f"model stopped: {failure}", *problems], "", values)
        if rec_level == ERROR:
            return self._status("rig", ERROR, problems, "", values)
        return self._status("rig", WARN if problems else OK, problems, "running", values)
