"""The emulator's device: one valve on its own load volume and no plant (`ValveDevice`, the
`pcv_sim.device.device.Device` of one valve named `valve`). No ROS here.

Its inputs are the valve's by their role (`duty_cycle`, `load_flow`, `supply_pressure`, the
options' `ambient_temperature`, `oil_temperature`), its signals `pressure`, `current`,
`spool_position` and the options' outputs; everything else (inputs at their steps, the watchdog,
the fall-rate limiter, faults, the physical limits, the fault state, restarts, the recorder hook)
is the device's. Here: the emulator's view of it in the valve's words (`run` hands back `Sample`s
with the duty and command in force; the watchdog of its one valve).
"""

from __future__ import annotations

from dataclasses import dataclass

from pcv_sim.device.device import Device, Recorder, ValveSpec
from pcv_sim.device.device import Sample as DeviceSample
from pcv_sim.device.inputs import Watchdog, WatchdogState
from pcv_sim.device.limits import PhysicalLimits
from pcv_sim.device.spec import RECORD_INPUTS
from pcv_sim.io.topics import DUTY_CYCLE, LOAD_FLOW, OPTION_INTERFACE, OUTPUT_ROLES, SUPPLY_PRESSURE
from pcv_sim.params import ValveParams, WatchdogParams

__all__ = ["OPTION_SIGNALS", "SIGNALS", "VALVE", "Recorder", "Sample", "ValveDevice", "WatchdogState"]

#: What a recorder receives per sample, SI units: duty fractions, m^3/s, Pa, A, m.
SIGNALS = (*RECORD_INPUTS, *OUTPUT_ROLES)
#: The options' signals (docs/model.md R33-R35; `pcv_sim.io.topics.OPTION_INTERFACE`): inputs
#: ambient_temperature, oil_temperature (K), outputs coil_temperature (K), coil_resistance (ohm),
#: core_position (m); `record_values()` adds those the valve's options bring.
OPTION_SIGNALS = tuple(e.name for e in OPTION_INTERFACE)

#: The name of the emulator's one valve (its watchdog's key, a fault's target).
VALVE = "valve"


@dataclass(frozen=True)
class Sample:
    """The device's outputs at model step `step` (time step * dt)."""

    step: int
    pressure: float          # Pa, load port
    current: float           # A, coil
    spool_position: float    # m, paper's sign: x > 0 opens pump -> load
    duty: float              # effective duty (after the fall-rate limiter), fraction
    command: float           # duty command in force (the watchdog's safe duty when it has fired)
    options: tuple[float, ...] = ()   # the valve's `option_outputs` (SI: K, ohm, m)


class ValveDevice(Device):
    """One emulated valve (see the module docstring)."""

    params: ValveParams
    lone_valve = True           # its names are the roles alone: `duty_cycle`, `pressure` (its topics')

    def __init__(
        self, params: ValveParams, *, safe_duty: float = WatchdogParams.safe_duty,
        watchdog_timeout: float = WatchdogParams.watchdog_timeout,
        sample_every: int = 10, recorder: Recorder | None = None, record_every: int = 1, seed: int = 0,
    ) -> None:
        # The inputs come at any rate for as long as the node runs: refusals are counted, not kept.
        super().__init__(params.simulation.time_step, [ValveSpec(VALVE, params)], watchdog_timeout=watchdog_timeout,
                         safe_duty=safe_duty, sample_every=sample_every, seed=seed, keep_rejections=False)
        self.params = params
        self.recorder = recorder
        if isinstance(record_every, bool) or not isinstance(record_every, int) or record_every < 1:
            raise ValueError(f"record_every {record_every!r}: accepted is an integer >= 1")
        self.record_every = record_every
        self.last_sample = DeviceSample(self.steps, self.sample())     # the device at rest before any

    def _valve_specs_of(self, params: ValveParams) -> tuple[ValveSpec, ...]:
        return (ValveSpec(VALVE, params),)

    # --- the one valve's view ----------------------------------------------------------------

    @property
    def watchdog(self) -> Watchdog:
        return self.watchdogs[VALVE]

    @property
    def command(self) -> float:
        """The last valid duty command (the safe duty before any)."""
        return self.commands[VALVE]

    @property
    def duty_command_in_force(self) -> float:
        return self.duty_held(VALVE)

    @property
    def watchdog_state(self) -> str:
        return self.watchdog.state

    @property
    def watchdog_fired(self) -> int:
        """How often the watchdog fired."""
        return self.watchdog.fired

    @property
    def watchdog_fired_step(self) -> int | None:
        return self.watchdog.fired_step

    @property
    def duty_applied_step(self) -> int | None:
        """The step at which the last valid duty command took effect."""
        return self.watchdog.command_step

    @property
    def load_flow(self) -> float:
        """The load flow in force, m^3/s."""
        return self._load_flow[0]

    @property
    def supply_pressure(self) -> float:
        """The supply pressure input in force (without faults), Pa: the YAML's until one comes."""
        return self._supply[0]

    @property
    def last_good(self) -> Sample | None:
        """The last sample handed out (diagnostics; the device at rest before any), in the valve's words."""
        return None if self.last_sample is None else self._in_words(self.last_sample)

    @property
    def physical_limits(self) -> PhysicalLimits:
        return self.limits[VALVE]

    # --- an offline run's start -------------------------------------------------------------

    def start_at_rest(self, duty: float, load_flow: float = 0.0, supply_pressure: float | None = None) -> None:
        """A fresh start (`reset`: model time 0) with the valve at rest at these inputs, each in
        force from step 0, the duty as a first command: where an offline run of a recorded timeline
        starts (replay: at the recording's first inputs; the supply: the YAML's when None).
        CommandError for a value `submit` refuses, `pcv_sim.model.statics.EquilibriumError` when
        the valve has no rest there; the device is unchanged then."""
        checked = [self.inputs[name].check(value) for name, value in (
            (DUTY_CYCLE, duty), (LOAD_FLOW, load_flow),
            (SUPPLY_PRESSURE, self._supply0[0] if supply_pressure is None else supply_pressure))]
        duty, load_flow, supply = checked
        state, current = self._rest_state(0, self.params, duty, load_flow, supply, self.sim.integrator)
        self.reset()
        sim = self.sim
        sim.x[:] = state
        sim.W[0] = current
        self._limiters[0].value = duty              # at rest there: nothing ramps toward it
        self._take_command(VALVE, duty)
        self._set_load_flow(0, load_flow)
        self._set_supply(0, supply)
        self.last_sample = DeviceSample(0, self.sample())

    # --- samples in the valve's words ---------------------------------------------------------

    def run(self, n: int) -> list[Sample]:
        """Advance n steps (`run_to`); the samples at the multiples of sample_every reached, each
        with the duty and command in force at its step."""
        out: list[Sample] = []
        end = self.steps + n
        per = self.sample_every
        while self.steps < end:
            stop = min(end, self.steps + per - self.steps % per)
            out += [self._in_words(s) for s in self.run_to(stop)]
        return out

    def valve_sample(self) -> Sample:
        """The sample at the present step, in the valve's words (not shown: see `present_sample`)."""
        return self._in_words(DeviceSample(self.steps, self.sample()))

    def _in_words(self, s: DeviceSample) -> Sample:
        v = s.values
        p, i, x, *options = v.tolist()
        return Sample(s.step, p, i, x, float(self.sim.u[self._duty_i[0]]), self.duties[VALVE], tuple(options))
