"""pcv_sim.simulation.integrators: convergence orders on a problem with a known solution, and the
real-time stepper's unrolled Heun path against the generic heun_step."""

from __future__ import annotations

import math

import pytest

from pcv_sim.params import default_params, replace_param
from pcv_sim.simulation import integrators
from pcv_sim.simulation.stepper import RealTimeStepper


def f(t: float, y: tuple[float, ...]) -> tuple[float, ...]:
    return (-y[0] + math.sin(t),)


def exact(t: float) -> float:
    # y' = -y + sin t, y(0) = 1: y = C e^{-t} + (sin t - cos t)/2 with C - 1/2 = 1, so C = 3/2.
    return 1.5 * math.exp(-t) + 0.5 * (math.sin(t) - math.cos(t))


def global_error(step, h: float, t_end: float = 3.0) -> float:  # noqa: ANN001
    """Error at t_end = 3 s (at 2 s the leading RK4 error term happens to pass through zero)."""
    n = int(round(t_end / h))
    y: tuple[float, ...] = (1.0,)
    for k in range(n):
        y = step(f, k * h, y, h)
    return abs(y[0] - exact(n * h))


@pytest.mark.parametrize(("name", "order", "h"), [("euler", 1, 0.01), ("rk2", 2, 0.02), ("rk4", 4, 0.1)])
def test_observed_order(name: str, order: int, h: float) -> None:
    step = integrators.STEPPERS[name]
    assert integrators.ORDERS[name] == order
    e1, e2, e3 = (global_error(step, h / 2**k) for k in range(3))
    observed = [math.log2(e1 / e2), math.log2(e2 / e3)]
    # Asymptotic regime: the observed order within 0.2 of the method's.
    for o in observed:
        assert abs(o - order) < 0.2, observed
    assert e3 < e1


def test_steppers_on_a_vector_state() -> None:
    # y'' = -y as (y, y'): one Heun step from (1, 0) by hand: k1 = (0, -1), y* = (1, -h),
    # k2 = (-h, -1), y1 = (1 - h^2/2, -h).
    def osc(t: float, y: tuple[float, ...]) -> tuple[float, ...]:
        return (y[1], -y[0])

    h = 0.1
    assert integrators.heun_step(osc, 0.0, (1.0, 0.0), h) == pytest.approx((1 - h * h / 2, -h), rel=1e-15)
    assert integrators.euler_step(osc, 0.0, (1.0, 0.0), h) == pytest.approx((1.0, -h), rel=1e-15)
    # RK4 matches cos/sin to O(h^5) per step: 1 - h^2/2 + h^4/24 and -(h - h^3/6).
    assert integrators.rk4_step(osc, 0.0, (1.0, 0.0), h) == pytest.approx(
        (1 - h**2 / 2 + h**4 / 24, -(h - h**3 / 6)), rel=1e-14)


def generic_run(stepper: RealTimeStepper, commands: list[tuple[float, int]], step) -> tuple[float, ...]:  # noqa: ANN001
    """What `advance` must do, written with the generic integrator and the model's RHS: per step,
    the fall-rate limiter, one integrator step with inputs held, then the end-stop projection."""
    m = stepper.model
    state, steps, i_last = stepper.state, stepper.steps, stepper._i  # noqa: SLF001 - the same start
    rate = stepper.params.command.duty_fall_rate_limit
    duty = stepper.duty
    h = stepper.dt
    for command, n in commands:
        for _ in range(n):
            if rate is None or command >= duty:
                duty = command
            else:
                duty = max(command, duty - rate * h)

            def rhs(t: float, y: tuple[float, ...], d: float = duty) -> tuple[float, ...]:
                nonlocal i_last
                dy, i_last = m.derivatives(t, y, d, stepper.load_flow, stepper.supply_pressure, i_last)
                return dy

            state = step(rhs, steps * h, state, h)
            if not m.x_min <= state[1] <= m.x_max:
                x, v = m.project(state[1], state[2])
                state = (state[0], x, v, state[3])
            steps += 1
    return state


@pytest.mark.parametrize(
    ("name", "rate", "commands", "load_flow"),
    [
        ("rk2", None, [(0.7, 300), (0.4, 300)], 0.0),
        ("rk2", 2.0, [(0.8, 100), (0.4, 400)], 0.0),            # rate-limited fall
        ("rk2", None, [(0.3, 400)], -30.0 / 60000.0),           # driven into the x_min stop
        ("rk4", None, [(0.7, 300)], 0.0),
        ("euler", None, [(0.7, 300)], 0.0),
    ],
)
def test_stepper_matches_the_generic_integrator(name: str, rate: float | None, commands, load_flow: float) -> None:  # noqa: ANN001
    params = replace_param(replace_param(default_params(), "simulation.integrator", name),
                           "command.duty_fall_rate_limit", rate)
    st = RealTimeStepper(params, duty=0.5)
    st.set_load_flow(load_flow)
    expected = generic_run(st, commands, integrators.STEPPERS[name])
    for command, n in commands:
        st.set_duty(command)
        st.advance(n)
    assert st.integrator == name
    scale = (1.0, 1e-3, 1.0, 1e7)   # Wb, m, m/s, Pa
    for got, want, s in zip(st.state, expected, scale):
        assert got == pytest.approx(want, rel=1e-12, abs=1e-12 * s)
    if load_flow < 0.0:
        assert st.spool_position == st.model.x_min        # the projection was exercised


def test_unknown_integrator_is_refused() -> None:
    with pytest.raises(ValueError, match=r"integrator 'rk45': accepted are euler, rk2, rk4"):
        RealTimeStepper(default_params(), integrator="rk45", duty=0.5)
