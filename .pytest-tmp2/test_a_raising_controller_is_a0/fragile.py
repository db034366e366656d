
from pcv_sim.control.steering import PositionController


class Fragile:
    """The example controller, raising from `fail_at` s on (never when fail_at < 0)."""

    def __init__(self, fail_at):
        self.fail_at = fail_at
        self.inner = PositionController()

    def __call__(self, t, m):
        if 0 <= self.fail_at <= t:
            raise ZeroDivisionError("the controller divided by zero")
        return self.inner(t, m)
