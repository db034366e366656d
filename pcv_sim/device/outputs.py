"""What leaves a device: its samples (true values in the order of `signals`), what the sensors
show of them (`measure`), what a recorder receives (`record_values`), each checked against the
valves' physical limits (`pcv_sim.device.limits`) before it leaves. No ROS.
"""

from __future__ import annotations

import numpy as np

from pcv_sim.device.composition import Composition
from pcv_sim.device.spec import MODEL_FAILURES, Sample

__all__ = ["Outputs"]


class Outputs(Composition):
    """A device's outputs (see the module docstring)."""

    def sample(self) -> np.ndarray:
        """The true values of `signals` now (SI: Pa, A, m per valve, the plant's), with the inputs in
        force from now on. A new array."""
        y = self.sim.outputs()
        self._outputs_taken(y)
        return y.copy() if self._all_outputs else y[self.signal_outputs]

    def _outputs_taken(self, y: np.ndarray) -> None:
        """What a sample's outputs `y` (every output) tell besides the signals: the load volumes,
        the options' outputs."""
        if self._wired_volumes:
            self._volumes = [float(y[i]) if i >= 0 else v for i, v in zip(self._volume_i, self._volumes)]
        if len(self._option_out_i):
            self.option_sample = y[self._option_out_i].tolist()

    def present_sample(self) -> Sample:
        """The sample at the present step (with the inputs in force from it on); it counts as shown."""
        self.shown = self.sim.steps
        self.last_sample = Sample(self.sim.steps, self.sample())
        return self.last_sample

    def measure(self, sample: Sample) -> np.ndarray:
        """What the sensors show of `sample` (sensor faults applied; NaN: no value, not to be
        published). Called once per sample, in order (a delay or noise fault keeps history)."""
        sensors = self.sensors
        if not sensors.active and not sensors.keeps_history:
            return sample.values
        return sensors.measure(sample.step * self.dt, sample.values)

    def record_values(self) -> dict[str, float]:
        """What a recorder receives now, SI: per valve (its names as its inputs and signals are
        named) duty_command (the duty in force), duty (after the fall-rate limiter), load_flow,
        supply_pressure, pressure, current, spool_position and its options' inputs and outputs;
        the plant's inputs and signals."""
        return self._record_values(self.sim.outputs())

    def _record_values(self, y: np.ndarray) -> dict[str, float]:
        u = self.sim.u
        out: dict[str, float] = {}
        for valve, (command, duty, flow, supply, *outputs), i_duty, i_flow, o_flow, i_supply, o in self._record_slots:
            out[command] = self.duties[valve]
            out[duty] = float(u[i_duty])
            out[flow] = float(u[i_flow]) if i_flow >= 0 else float(y[o_flow])
            out[supply] = float(u[i_supply])
            for key, i in zip(outputs, o):
                out[key] = float(y[i])
        for name, i in zip(self.option_inputs, self._option_in_i):
            out[name] = float(u[i])
        for name, i in zip(self.option_outputs, self._option_out_i):
            out[name] = float(y[i])
        for name, i in self._plant_i.items():
            out[name] = float(u[i])
        for name, i in self._plant_signal_i:
            out[name] = float(y[i])
        return out

    def load_volumes(self) -> list[float]:
        """Each valve's load volume at the last `sample()` (not updated by `advance_sample`'s fused
        path; m^3: its chamber's, or its own), in the order of `valve_names`. Its change over an
        interval / the interval is the valve's mean load flow there (the chamber's displacement
        flow is dV/dt)."""
        return list(self._volumes)

    def _check_limits(self, values: np.ndarray) -> None:
        """ModelFault (and `fault` set) when a valve's pressure or current in `values` (the signals)
        is none a valve can show."""
        for jp, ji, lim in self._limit_slots:
            p, i = values[jp], values[ji]
            if not (lim.pressure_min <= p <= lim.pressure_max and -lim.current_max <= i <= lim.current_max):
                self._fail(lim.problem(float(p), float(i)) or "the model state ran away (non-finite)")

    def _rows_problem(self, rows: np.ndarray) -> tuple[int, str] | None:
        """The first row (step) no valve can show, and why; None when all are fine."""
        for jp, ji, lim in self._limit_slots:
            p, i = rows[:, jp], rows[:, ji]
            # The usual case in four reductions (a NaN fails every comparison); the row only when not.
            if lim.pressure_min <= p.min() and p.max() <= lim.pressure_max and -lim.current_max <= i.min() \
                    and i.max() <= lim.current_max and np.isfinite(rows).all():
                continue
            ok = np.isfinite(rows).all(axis=1) & (p >= lim.pressure_min) & (p <= lim.pressure_max) & \
                (np.abs(i) <= lim.current_max)
            k = int(np.argmin(ok))
            return k, lim.problem(float(p[k]), float(i[k])) or "the model state ran away (non-finite)"
        return None

    def _run_rows(self, steps: np.ndarray, inputs: np.ndarray, targets: np.ndarray) -> np.ndarray:
        """`Simulator.run`: one compiled call to `targets` with these input changes (every output
        at each target); a model that fails in it is the fault (ModelFault)."""
        try:
            return self.sim.run(steps, inputs, targets)
        except MODEL_FAILURES as err:
            self._fail(f"model step failed ({type(err).__name__}: {err})")

    def _check_rows(self, rows: np.ndarray, targets: np.ndarray) -> None:
        """Rows of signals about to leave the device, one per step of `targets`: the first no valve
        can show is the fault (ModelFault), with model time at its step."""
        bad = self._rows_problem(rows)
        if bad is not None:
            self.sim.steps = int(targets[bad[0]])
            self._fail(bad[1])
