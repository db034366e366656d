"""A trajectory's signals by name: sampled between its points and onto another time grid."""
import numpy as np
import pytest

from pcv_sim.io.topics import CURRENT, PRESSURE, SPOOL_POSITION
from pcv_sim.simulation.trajectory import Trajectory


def ramp() -> Trajectory:
    t = np.array([0.0, 1.0, 2.0])
    return Trajectory(t, 0.5 * t, 1.0 + t, 1e5 * t, -1e-3 * t)


def test_the_signals_are_its_fields_after_the_time_in_order():
    assert Trajectory.signals() == ("duty", CURRENT, PRESSURE, SPOOL_POSITION)


def test_at_interpolates_every_signal_by_name():
    assert ramp().at(0.5) == pytest.approx({"duty": 0.25, CURRENT: 1.5, PRESSURE: 5e4, SPOOL_POSITION: -5e-4})


def test_resample_keeps_each_signal_in_its_place():
    r = ramp().resample(np.array([0.25, 1.5]))
    np.testing.assert_array_equal(r.t, [0.25, 1.5])
    np.testing.assert_allclose(r.duty, [0.125, 0.75])
    np.testing.assert_allclose(r.current, [1.25, 2.5])
    np.testing.assert_allclose(r.pressure, [2.5e4, 1.5e5])
    np.testing.assert_allclose(r.spool_position, [-2.5e-4, -1.5e-3])
