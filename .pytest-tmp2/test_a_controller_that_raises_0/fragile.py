
from pcv_sim.control.steering import PositionController


class Fragile(PositionController):
    """The example controller whose array form raises from `fail_at` s on (never when < 0)."""

    def __init__(self, fail_at):
        super().__init__()
        self.fail_at = fail_at

    def lockstep_arrays(self, signals, valves):
        step, commanded, flags = super().lockstep_arrays(signals, valves)

        def fragile(t, y, out):
            if 0 <= self.fail_at <= t:
                raise ZeroDivisionError("the controller divided by zero")
            step(t, y, out)

        return fragile, commanded, flags
