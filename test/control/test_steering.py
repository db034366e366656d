"""The example steering control law on its own: signs, limits, anti-windup, the coil monitor."""
import pytest

from pcv_sim.control.steering import PositionController

AMPS = 12.0 / 5.6          # coil current per unit duty at rest (V / R)


def measurements(position=0.0, velocity=0.0, setpoint=0.0, left=None, right=None):
    """A sample with healthy coil currents for the base duty unless given."""
    return {"cylinder.position": position, "cylinder.velocity": velocity, "setpoint": setpoint,
            "left.current": AMPS * 0.6 if left is None else left,
            "right.current": AMPS * 0.6 if right is None else right}


def test_a_positive_error_pushes_toward_plus_x():
    c = PositionController()
    out = c(0.0, measurements(setpoint=0.01))
    assert out["left"] > 0.6 > out["right"]
    assert out["left"] - 0.6 == pytest.approx(0.6 - out["right"])
    assert out["flags"] == {"fault_detected": 0.0}


def test_velocity_damps_the_command():
    still = PositionController()(0.0, measurements(setpoint=0.01))
    moving = PositionController()(0.0, measurements(setpoint=0.01, velocity=0.05))
    assert moving["left"] < still["left"]


def test_duties_stay_where_the_valve_regulates():
    out = PositionController()(0.0, measurements(setpoint=10.0))
    assert (out["left"], out["right"]) == (pytest.approx(0.95), pytest.approx(0.3))
    out = PositionController()(0.0, measurements(setpoint=-10.0))
    assert (out["left"], out["right"]) == (pytest.approx(0.3), pytest.approx(0.95))


def test_the_integral_winds_up_only_while_unsaturated():
    c = PositionController()
    for k in range(100):
        c(k * 1e-3, measurements(setpoint=10.0))          # saturated all along
    assert c.integral == 0.0
    c = PositionController()
    for k in range(100):
        c(k * 1e-3, measurements(setpoint=0.001))
    assert c.integral == pytest.approx(100 * 0.001 * 1e-3)


def test_a_dropped_sample_keeps_the_last_values():
    c = PositionController()
    first = c(0.0, measurements(setpoint=0.01))
    assert c(1e-3, {})["left"] == pytest.approx(first["left"], rel=1e-3)


def test_the_coil_monitor_flags_a_low_current_after_fault_time():
    c = PositionController(fault_time=0.02)
    flags = [c(k * 1e-3, measurements(left=0.0))["flags"]["fault_detected"] for k in range(30)]
    assert flags[:20] == [0.0] * 20             # low for less than 20 ms: not yet
    assert flags[20:] == [1.0] * 10
    assert c(0.031, measurements())["flags"]["fault_detected"] == 0.0   # current back: cleared
