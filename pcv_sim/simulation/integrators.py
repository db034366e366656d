"""Fixed-step explicit integrators on tuples of floats (pure Python: faster than numpy for 4 states).

`f(t, y) -> dy` is any right-hand side. Orders: euler 1, rk2 (Heun) 2, rk4 4; the test suite
checks the orders on a problem with a known solution.
"""

from __future__ import annotations

from typing import Callable

__all__ = ["euler_step", "heun_step", "rk4_step", "STEPPERS", "ORDERS"]

Rhs = Callable[[float, tuple[float, ...]], tuple[float, ...]]


def euler_step(f: Rhs, t: float, y: tuple[float, ...], h: float) -> tuple[float, ...]:
    k1 = f(t, y)
    return tuple(a + h * b for a, b in zip(y, k1))


def heun_step(f: Rhs, t: float, y: tuple[float, ...], h: float) -> tuple[float, ...]:
    """Heun's method (explicit trapezoid, RK2): Euler predictor, trapezoidal corrector."""
    k1 = f(t, y)
    k2 = f(t + h, tuple(a + h * b for a, b in zip(y, k1)))
    hh = 0.5 * h
    return tuple(a + hh * (b + c) for a, b, c in zip(y, k1, k2))


def rk4_step(f: Rhs, t: float, y: tuple[float, ...], h: float) -> tuple[float, ...]:
    hh = 0.5 * h
    k1 = f(t, y)
    k2 = f(t + hh, tuple(a + hh * b for a, b in zip(y, k1)))
    k3 = f(t + hh, tuple(a + hh * b for a, b in zip(y, k2)))
    k4 = f(t + h, tuple(a + h * b for a, b in zip(y, k3)))
    h6 = h / 6.0
    return tuple(a + h6 * (b + 2.0 * c + 2.0 * d + e) for a, b, c, d, e in zip(y, k1, k2, k3, k4))


STEPPERS = {"euler": euler_step, "rk2": heun_step, "rk4": rk4_step}
ORDERS = {"euler": 1, "rk2": 2, "rk4": 4}
