"""The example steering control law on its own: signs, limits, anti-windup, the coil monitor."""
import numpy as np
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


def test_the_current_loop_makes_each_coil_carry_the_current_the_duty_stands_for():
    """A coil 3 % above the nominal resistance (and one 3 % below): with duties alone its current is
    3 % off the D V / R the control law meant; with `current_loop` the duty sent is trimmed until
    the measured current is that target, whatever the coil."""
    for factor in (1.03, 0.97):
        amps = 12.0 / (5.6 * factor)              # this coil's current per unit duty
        c = PositionController(current_loop=0.02)
        sent = {"left": 0.6, "right": 0.6}
        for k in range(300):
            out = c(k * 1e-3, measurements(setpoint=0.0, left=amps * sent["left"], right=AMPS * sent["right"]))
            sent = {v: out[v] for v in ("left", "right")}
        assert amps * sent["left"] == pytest.approx(AMPS * c.duty["left"], rel=1e-4)
        assert sent["right"] == pytest.approx(c.duty["right"], rel=1e-6)        # the nominal coil: no trim
        assert out["flags"] == {"fault_detected": 0.0}
    with pytest.raises(ValueError, match="current_loop"):
        PositionController(current_loop=-1.0)


SIGNALS = ("left.pressure", "left.current", "right.current", "cylinder.position", "cylinder.velocity", "setpoint")


def test_the_array_form_gives_the_dict_forms_numbers_to_the_last_bit_and_shares_its_state():
    """The lockstep's array form and the dict form over the same measurements: saturation,
    anti-windup, a coil low for longer than fault_time and back, the current loop; one controller
    switching between the forms every few periods (as a run with a passing sensor fault does)
    against one that only ever gets dicts."""
    rng = np.random.default_rng(7)
    for current_loop in (0.0, 0.02):
        by_dict = PositionController(current_loop=current_loop)
        mixed = PositionController(current_loop=current_loop)
        step, commanded, flags = mixed.lockstep_arrays(SIGNALS, ("left", "right"))
        assert commanded == ("left", "right") and flags == ("fault_detected",)
        out = [0.0] * 3
        fault_seen = set()
        for k in range(400):
            t = k * 1e-3
            left = 0.2 if 100 <= k < 150 else AMPS * 0.6 * (1 + 0.05 * rng.standard_normal())
            m = {"left.pressure": 50e5, "left.current": left, "right.current": AMPS * 0.6 * (1 + 0.05 * rng.random()),
                 "cylinder.position": 0.01 * rng.standard_normal(), "cylinder.velocity": 0.05 * rng.standard_normal(),
                 "setpoint": 0.0 if k < 50 else (10.0 if k < 80 else 0.002)}
            want = by_dict(t, dict(m))
            if (k // 7) % 2:
                got = mixed(t, dict(m))
            else:
                step(t, [m[s] for s in SIGNALS], out)
                got = {"left": out[0], "right": out[1], "flags": {"fault_detected": out[2]}}
            assert got == want, k
            assert all(type(v) is float for v in (got["left"], got["right"], got["flags"]["fault_detected"]))
            fault_seen.add(got["flags"]["fault_detected"])
        assert fault_seen == {0.0, 1.0} and by_dict.integral == mixed.integral != 0.0


def test_the_array_form_takes_nan_as_no_setpoint_and_needs_its_signals():
    c = PositionController()
    step, _, _ = c.lockstep_arrays(SIGNALS, ("left", "right"))
    out = [0.0] * 3
    step(0.0, [50e5, AMPS * 0.6, AMPS * 0.6, 0.0, 0.0, 0.01], out)
    step(1e-3, [50e5, AMPS * 0.6, AMPS * 0.6, 0.0, 0.0, float("nan")], out)     # holds 0.01
    d = PositionController()
    d(0.0, measurements(setpoint=0.01))
    none = measurements()
    del none["setpoint"]
    r = d(1e-3, none)
    assert out[:2] == [r["left"], r["right"]] and r["left"] > 0.6
    assert PositionController().lockstep_arrays(SIGNALS[:-1], ("left", "right")) is None
    assert PositionController().lockstep_arrays(SIGNALS, ("left",)) is None


def test_a_measurement_never_sampled_is_named():
    with pytest.raises(KeyError, match=r"cylinder\.velocity"):
        PositionController()(0.0, {"cylinder.position": 0.0, "left.current": 1.0, "right.current": 1.0})
