"""pcv_sim.device.limits: what a valve can show (beyond it a device's model has diverged)."""
import math

import pytest

from pcv_sim.device.limits import PhysicalLimits
from pcv_sim.params import load_params

PARAMS = load_params()


def test_physical_limits():
    lim = PhysicalLimits.of(PARAMS)
    assert (lim.pressure_min, lim.pressure_max) == (-1e5, 800e5)         # -1 bar .. 2 x 400 bar
    assert lim.current_max == pytest.approx(2 * 12.0 / 5.6)
    assert lim.problem(122e5, 1.5) is None
    assert 'pressure 1.2e+282 bar outside the physical range -1 .. 800 bar' in lim.problem(1.2e287, 1.0)
    assert 'pressure -2 bar' in lim.problem(-2e5, 1.0)
    assert "coil current 9 A beyond the coil's possible +-4.29 A" in lim.problem(100e5, 9.0)
    assert lim.problem(100e5, math.nan) is not None
