"""pcv_sim.commands.step: `pcv-sim step --model simplified` runs the emulator's device."""
from __future__ import annotations

import argparse

import numpy as np
import pytest

from pcv_sim.commands.step import simulate_step
from pcv_sim.device.valve import ValveDevice
from pcv_sim.params import load_params, replace_param


def _args(**kw: object) -> argparse.Namespace:
    base = {"start": 0.8, "end": 0.4, "at": 0.02, "duration": 0.1, "model": "simplified", "fall_rate": None,
            "damping": None, "config": None}
    return argparse.Namespace(**{**base, **kw})


@pytest.mark.parametrize("rate", [None, 2.0])
def test_the_step_is_the_emulators_device_sample_for_sample(rate: float | None) -> None:
    """The step command's trace is what the emulator's device shows when driven the same way (its
    samples every 10 steps, the command submitted for the step time), with the fall-rate limiter
    ramping the duty when one is given."""
    traj = simulate_step(_args(fall_rate=rate))
    dev = ValveDevice(replace_param(load_params(), "command.duty_fall_rate_limit", rate), safe_duty=0.8,
                      watchdog_timeout=0.0, sample_every=10)
    dev.submit("duty_cycle", 0.4, at_step=200)
    samples = dev.run(1000)
    assert len(traj.t) == 1001 and traj.t[-1] == pytest.approx(0.1)
    for name in ("pressure", "current", "spool_position", "duty"):
        assert np.array_equal(getattr(traj, name)[10::10], [getattr(s, name) for s in samples]), name
    if rate is None:
        assert traj.duty[199] == 0.8 and traj.duty[200] == 0.4
    else:       # 0.8 -> 0.4 at 2 /s, a step's fall in force from step 200 on: past the window's end
        assert traj.duty[200] == pytest.approx(0.8 - 2.0 * 1e-4)
        assert np.diff(traj.duty[200:]) == pytest.approx(-2.0 * 1e-4) and traj.duty[-1] > 0.6
