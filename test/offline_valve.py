"""The emulator's device (`ValveDevice`) driven offline the way the tests drive one valve: at rest
at a duty, an input acting from the present step, n steps, a duty profile sampled. Only the
device's public API: what these helpers run is what the emulator and replay run."""
from __future__ import annotations

import math

import numpy as np

from pcv_sim.device.valve import VALVE, ValveDevice
from pcv_sim.errors import CommandError
from pcv_sim.params import ValveParams, replace_param
from pcv_sim.simulation.duty import DutyProfile
from pcv_sim.simulation.trajectory import Trajectory


def at_rest(params: ValveParams, duty: float = 0.0, *, kind: str | None = None, integrator: str | None = None,
            **kw) -> ValveDevice:
    """The device of the model `kind` (default: the config's), with `integrator` (default: the
    config's), at rest at `duty` (its safe duty; watchdog off unless given)."""
    if integrator is not None:
        params = replace_param(params, 'simulation.integrator', integrator)
    if kind is not None and kind != params.simulation.model:
        params = replace_param(replace_param(params, 'simulation.integrator', integrator or 'auto'),
                               'simulation.model', kind)
    kw.setdefault('watchdog_timeout', 0.0)
    return ValveDevice(params, safe_duty=duty, **kw)


def put(dev: ValveDevice, name: str, value) -> None:
    """Input `name` acts from the present step on; CommandError (nothing changes) if refused."""
    if name == 'duty_cycle':
        dev.set_duty(VALVE, value)
        return
    reason = dev.submit(name, value, dev.steps)
    if reason is not None:
        raise CommandError(reason)
    dev.advance_to(dev.steps)


def advance(dev: ValveDevice, n: int = 1) -> None:
    dev.advance_to(dev.steps + n)


def now(dev: ValveDevice):
    """The sample at the present step (pressure, current, spool_position, duty, command, options)."""
    return dev.valve_sample()


def output(dev: ValveDevice, name: str) -> float:
    """A signal by its name at the present step (e.g. coil_temperature, core_position)."""
    return float(dev.sample()[dev.signals.index(name)])


def run_profile(dev: ValveDevice, profile: DutyProfile, t_end: float, *, sample_every: int = 1) -> Trajectory:
    """From the present step: each command of `profile` acts from the first step at or after its
    time, samples every `sample_every` steps and at `t_end` (times relative to the start); a
    sample shows the duty in force from its step on."""
    start, dt = dev.steps, dev.dt
    n = round(t_end / dt)
    for t, duty in zip(profile.times, profile.values, strict=True):
        reason = dev.submit('duty_cycle', duty, start + math.ceil(t / dt - 1e-9))
        if reason is not None:
            raise CommandError(reason)
    dev.advance_to(start)
    samples = [dev.valve_sample()]
    for k in [*range(sample_every, n, sample_every), n]:
        dev.advance_to(start + k)
        samples.append(dev.valve_sample())
    return Trajectory(np.array([(s.step - start) * dt for s in samples]), np.array([s.duty for s in samples]),
                      np.array([s.current for s in samples]), np.array([s.pressure for s in samples]),
                      np.array([s.spool_position for s in samples]))
