"""pcv_sim.model.flow_force: Eq. 30 and the jet-angle fits, Eqs. 31-32 (readings R8, R9, R26)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pcv_sim.model import flow_force as ff
from pcv_sim.params import default_params

# Eqs. 31, 32 as printed, read as Gaussians a exp(-((s - b)/c)^2) (R8) with the printed centres
# -3.129 (pump) and -1.741 (tank) (R26).
PUMP = ((6.151e13, -3.129, 0.5478), (0.1908, 0.154, 0.106))
TANK = ((932.0, -1.741, 0.7617), (0.3796, 0.5226, 0.2083))


def test_config_carries_the_printed_fits() -> None:
    f = default_params().fits
    assert f.pump_jet == PUMP and f.tank_jet == TANK
    assert f.pump_jet_cap == f.tank_jet_cap == 0.7


def test_pump_side_at_closed_centre_hand_evaluated() -> None:
    # x = 0: 6.151e13 exp(-(3.129/0.5478)^2) + 0.1908 exp(-(0.154/0.106)^2)
    #      = 6.151e13 * exp(-32.627) + 0.1908 * exp(-2.1107) = 0.416 + 0.0231 = 0.440 (< 0.7: no cap)
    expected = 6.151e13 * math.exp(-((3.129 / 0.5478) ** 2)) + 0.1908 * math.exp(-((0.154 / 0.106) ** 2))
    assert expected == pytest.approx(0.440, abs=0.001)
    assert ff.jet_cosine(0.0, PUMP, 0.7) == pytest.approx(expected, rel=1e-12)


def test_cap_is_a_minimum_not_a_maximum() -> None:
    """Reading R9: with max(0.7, .) the pump side would be 0.7 everywhere the fit is below it and
    the tank side would exceed 1 near x = 0; min(0.7, .) caps the fit."""
    # Tank side at |x| = 0: 932 exp(-(1.741/0.7617)^2) + 0.3796 exp(-(0.5226/0.2083)^2) = 5.02 + 0.0007
    raw = 932.0 * math.exp(-((1.741 / 0.7617) ** 2)) + 0.3796 * math.exp(-((0.5226 / 0.2083) ** 2))
    assert raw > 1.0                                     # read literally, cos(delta) > 1: impossible
    assert ff.jet_cosine(0.0, TANK, 0.7) == 0.7          # capped
    assert ff.jet_cosine(0.1, TANK, 0.7) == 0.7          # still capped near 0
    # Below the cap the fit passes through: pump side at x = 0 gives 0.44, not 0.7.
    assert ff.jet_cosine(0.0, PUMP, 0.7) < 0.7
    s = np.linspace(-0.55, 0.85, 281)
    for fit in (PUMP, TANK):
        c = np.array([ff.jet_cosine(float(v), fit, 0.7) for v in s])
        assert np.all((c >= 0.0) & (c <= 0.7))


def test_jet_cosine_falls_with_pump_opening() -> None:
    # Fig. 5 / R26: the jet turns toward 90 deg as the pump side opens, so cos(delta) falls from
    # 0.44 at x = 0 to nearly 0 (the second Gaussian, centred at 0.154 mm, leaves a shoulder).
    assert ff.jet_cosine(0.4, PUMP, 0.7) < 0.01
    assert ff.jet_cosine(0.85, PUMP, 0.7) < 1e-6
    s = np.linspace(0.0, 0.85, 171)
    c = np.array([ff.jet_cosine(float(v), PUMP, 0.7) for v in s])
    assert np.all(c[s >= 0.2] < c[0] / 2)
    assert np.all(np.diff(c[s >= 0.2]) < 0.0)


def test_flow_force_eq_30() -> None:
    # Hand value: 2 * 0.65 * 3e-6 m^2 * 50e5 Pa * 0.44 = 8.58 N.
    assert ff.flow_force(0.65, 3e-6, 50e5, 0.44) == pytest.approx(8.58, rel=1e-12)
    # A jet force magnitude: the same for either flow direction, >= 0.
    assert ff.flow_force(0.65, 3e-6, -50e5, 0.44) == ff.flow_force(0.65, 3e-6, 50e5, 0.44)
    assert ff.flow_force(0.65, 3e-6, 0.0, 0.44) == 0.0
