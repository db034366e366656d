"""pcv_sim.simulation.duty and the valve's input checks (pcv_sim.simulation.valve): duty profiles
(effective duty, breakpoints, validation), the fall-rate limiter, the check functions, and the
switched PWM's on-time (the model's coil voltage)."""

from __future__ import annotations

import math

import pytest

from pcv_sim.errors import CommandError
from pcv_sim.model.valve import ValveModel
from pcv_sim.params import default_params, replace_param
from pcv_sim.simulation.duty import DutyProfile, FallRateLimiter
from pcv_sim.simulation.valve import check_load_flow, check_supply_pressure


@pytest.fixture(scope="module")
def params():
    return default_params()


def test_duty_profile_effective_and_breakpoints() -> None:
    prof = DutyProfile((0.0, 0.1, 0.2), (0.8, 0.4, 0.9), fall_rate_limit=2.0)
    assert prof.command(0.05) == 0.8 and prof.command(0.15) == 0.4 and prof.command(0.3) == 0.9
    assert prof.effective(0.15) == pytest.approx(0.7, abs=1e-12)     # 0.8 - 2 * 0.05
    assert prof.effective(0.2) == 0.9                                # rise: immediate
    # Kinks of the input: the switching instants (the ramp to 0.4 would end at 0.3 s but the rise
    # at 0.2 s cuts it; an extra breakpoint there is harmless: it only splits an interval).
    assert {0.0, 0.1, 0.2, 0.5} <= set(prof.breakpoints(0.5))
    assert all(0.0 <= b <= 0.5 for b in prof.breakpoints(0.5))
    slow = DutyProfile.step(0.8, 0.4, 0.1, fall_rate_limit=2.0)
    assert slow.breakpoints(0.5) == pytest.approx([0.0, 0.1, 0.3, 0.5])
    assert slow.effective(0.4) == 0.4
    assert DutyProfile.step(0.8, 0.4, 0.1).effective(0.1) == 0.4    # no limiter


def test_fall_rate_limiter_off() -> None:
    lim = FallRateLimiter(None, 0.8)
    assert lim.update(0.2, 1e-4) == 0.2
    lim = FallRateLimiter(1.0, 0.8)
    assert lim.update(0.2, 0.1) == pytest.approx(0.7)
    assert lim.update(0.9, 0.1) == 0.9


@pytest.mark.parametrize(
    ("times", "values", "match"),
    [
        ((0.0, 0.1), (0.5,), r"as many times as values"),
        ((), (), r"as many times as values, at least one"),
        ((0.0, 0.1, 0.1), (0.5, 0.6, 0.7), r"times must increase strictly"),
        ((0.0, 0.2, 0.1), (0.5, 0.6, 0.7), r"times must increase strictly"),
        ((0.0, 0.1), (0.5, 70.0), r"not percent \(did you mean 0\.7\?\)"),
        ((0.0,), (math.nan,), r"is not finite"),
        ((0.0,), (-0.2,), r"out of range: accepted is a fraction 0\.\.1"),
    ],
)
def test_duty_profile_validation(times, values, match: str) -> None:
    with pytest.raises(CommandError, match=match):
        DutyProfile(times, values)


def test_check_functions_return_floats() -> None:
    assert check_load_flow(0) == 0.0 and isinstance(check_load_flow(0), float)
    assert check_supply_pressure(200e5) == 200e5
    with pytest.raises(CommandError, match=r"load flow True"):
        check_load_flow(True)


@pytest.mark.parametrize("duty", [0.7, 0.71, 0.5])
def test_switched_pwm_on_time_is_the_same_every_period(params, duty: float) -> None:
    m = ValveModel(replace_param(params, "solenoid.pwm", "switched"))
    dt, per_period = 1e-4, 50      # 200 Hz at 0.1 ms
    counts = {sum(m.coil_voltage(duty, (k * per_period + j) * dt) > 0.0 for j in range(per_period))
              for k in range(400)}
    assert len(counts) == 1
