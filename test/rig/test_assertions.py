"""Each assertion kind passing and failing on a constructed run, its value against the formula,
with margin and the worst point's time; event-relative windows; baselines from a CSV, a bag and
a --json file."""

import json
import math

import numpy as np
import pytest

from pcv_sim.rig.assertions import AssertionSpecError, check_assertions, normalize
from pcv_sim.rig.lockstep import RigRun
from pcv_sim.rig.record import write_bag, write_csv

SIGNALS = ("left.pressure", "left.current", "left.spool_position", "cylinder.position", "cylinder.velocity",
           "cylinder.effort")
KNOWN = (*SIGNALS, "left.duty", "setpoint")
T_STEP, TAU, ZETA, WN = 0.5, 0.1, 0.5, 20.0
EVENTS = [(0.3, "fault", "coil_open"), (1.2, "clear", "coil_open")]


def constructed_run(*, zeta=ZETA, flag_at=0.52):
    t = np.round(np.arange(0, 2001) * 1e-3, 12)
    sp = np.where(t >= T_STEP, 0.02, 0.0)
    tau = np.clip(t - T_STEP, 0, None)
    wd = WN * math.sqrt(1 - zeta ** 2)
    y = 0.02 * (1 - np.exp(-zeta * WN * tau) * (np.cos(wd * tau) + zeta / math.sqrt(1 - zeta ** 2) * np.sin(wd * tau)))
    p = 100e5 + 20e5 * np.sin(2 * np.pi * t)            # peaks at 120 bar at t = 0.25 and 1.25
    true = np.zeros((len(t), len(SIGNALS)))
    true[:, 0], true[:, 3] = p, y
    meas = true.copy()
    meas[t >= 1.0, 0] += 5e5                            # a 5 bar sensor bias from 1 s
    flags = {"controller.fault_detected": np.where(t >= flag_at, 1.0, 0.0)}
    return RigRun(t, SIGNALS, true, meas, np.full((len(t), 1), 0.5), ("left",), sp, flags)


def check(run, *specs, **kw):
    norm = tuple(normalize(f"a[{k}]", s, signals=KNOWN, has_setpoint=True, events=EVENTS, base=kw.get("base"))
                 for k, s in enumerate(specs))
    return check_assertions(run, norm, next_change=lambda t: 10.0)


def test_never_above_and_below_report_value_limit_margin_and_worst_time():
    run = constructed_run()
    up, = check(run, {"type": "never_above", "signal": "left.pressure", "max": "125 bar"})
    assert up.passed and up.value == pytest.approx(120e5) and up.limit == 125e5
    assert up.margin == pytest.approx(5e5) and up.time == pytest.approx(0.25)
    bad, = check(run, {"type": "never_above", "signal": "left.pressure", "max": "115 bar", "after": 1.0})
    assert not bad.passed and bad.margin == pytest.approx(-5e5) and bad.time == pytest.approx(1.25)
    # what the controller saw: the bias adds 5 bar
    seen, = check(run, {"type": "never_above", "signal": "left.pressure", "max": "122 bar", "after": 1.0,
                        "measured": True})
    assert not seen.passed and seen.value == pytest.approx(125e5)
    low, = check(run, {"type": "never_below", "signal": "left.pressure", "min": "85 bar"})
    assert not low.passed and low.value == pytest.approx(80e5) and low.time == pytest.approx(0.75)
    assert low.margin == pytest.approx(-5e5)
    high, = check(run, {"type": "never_below", "signal": "left.pressure", "min": "75 bar"})
    assert high.passed and high.margin == pytest.approx(5e5) and high.time == pytest.approx(0.75)


def test_step_response_against_the_second_order_formulas():
    run = constructed_run()
    spec = {"type": "step_response", "signal": "cylinder.position", "at": T_STEP, "rise_time": "200 ms",
            "overshoot": "20 %", "settling_time": "600 ms", "band": "2 %", "steady_state_error": "0.1 mm"}
    out = {o.name.split(": ")[1]: o for o in check(run, spec)}
    wd = WN * math.sqrt(1 - ZETA ** 2)
    assert out["overshoot"].value == pytest.approx(math.exp(-math.pi * ZETA / math.sqrt(1 - ZETA ** 2)), abs=1e-4)
    assert out["overshoot"].time == pytest.approx(T_STEP + math.pi / wd, abs=1e-3)
    # the 10-90 % rise time of this system, from the response itself (found numerically to 1 ms)
    tt = np.linspace(0, 1, 1_000_001)
    yy = 1 - np.exp(-ZETA * WN * tt) * (np.cos(wd * tt) + ZETA / math.sqrt(1 - ZETA ** 2) * np.sin(wd * tt))
    rise = tt[np.argmax(yy >= 0.9)] - tt[np.argmax(yy >= 0.1)]
    assert out["rise_time"].value == pytest.approx(rise, abs=1.5e-3)
    # settling into +-2 %: the last time the envelope's response leaves the band
    outside = np.flatnonzero(np.abs(yy - 1) > 0.02)
    assert out["settling_time"].value == pytest.approx(tt[outside[-1]], abs=1.5e-3)
    assert all(o.passed for o in out.values())
    assert out["steady_state_error"].value < 1e-6
    tight = {o.name.split(": ")[1]: o for o in check(run, {**spec, "rise_time": "50 ms", "overshoot": "5 %",
                                                             "settling_time": "200 ms"})}
    assert not tight["rise_time"].passed and tight["rise_time"].margin == pytest.approx(0.05 - rise, abs=1.5e-3)
    assert not tight["overshoot"].passed and not tight["settling_time"].passed
    # a response that never gets there: the steady-state error and the settling fail
    lazy = constructed_run()
    lazy.true[:, 3] *= 0.5
    out = {o.name.split(": ")[1]: o for o in check(lazy, spec)}
    assert not out["rise_time"].passed and out["rise_time"].value == math.inf
    assert not out["steady_state_error"].passed and out["steady_state_error"].value == pytest.approx(0.01, rel=1e-3)
    assert not out["settling_time"].passed


def test_within_band_after_an_event_and_max_error():
    run = constructed_run()
    spec = {"type": "within_band", "signal": "cylinder.position", "reference": "setpoint", "tolerance": "0.5 mm",
            "after": {"event": "coil_open", "delay": "700 ms"}}
    ok, = check(run, spec)
    assert ok.passed and ok.draw["t0"] == pytest.approx(1.0)
    early, = check(run, {**spec, "after": {"event": "fault", "delay": 0.2}})        # from 0.5 s: the step
    assert not early.passed and early.value == pytest.approx(0.02) and early.time == pytest.approx(0.5)
    err, = check(run, {"type": "max_error", "signal": "cylinder.position", "reference": "20 mm", "max": "1 mm",
                       "after": 1.5})
    assert err.passed and err.margin > 0.9e-3
    miss, = check(run, {"type": "max_error", "signal": "cylinder.position", "reference": "setpoint", "max": "1 mm",
                        "after": 0.5})
    assert not miss.passed and miss.value == pytest.approx(0.02) and miss.time == pytest.approx(0.5)
    assert miss.margin == pytest.approx(-0.019)
    with pytest.raises(AssertionSpecError, match=r"a\[0\]\.after\.event: 'supply' is not on the timeline"):
        check(run, {**spec, "after": {"event": "supply"}})
    with pytest.raises(AssertionSpecError, match=r"unknown key 'delai' \(did you mean 'delay'\?\)"):
        check(run, {**spec, "after": {"event": "fault", "delai": 1}})


def test_flag_within_an_event():
    good, = check(constructed_run(flag_at=0.35), {"type": "flag_within", "signal": "controller.fault_detected",
                                                  "at": {"event": "fault"}, "within": "60 ms"})
    assert good.passed and good.value == pytest.approx(0.05) and good.margin == pytest.approx(0.01)
    slow, = check(constructed_run(flag_at=0.4), {"type": "flag_within", "signal": "controller.fault_detected",
                                                 "at": {"event": "fault"}, "within": "60 ms"})
    assert not slow.passed and slow.time == pytest.approx(0.4)
    early, = check(constructed_run(flag_at=0.1), {"type": "flag_within", "signal": "controller.fault_detected",
                                                  "at": 0.3, "within": "60 ms"})
    assert not early.passed and early.time == pytest.approx(0.1)


def test_baseline_from_csv_and_bag(tmp_path):
    old = constructed_run()
    write_csv(old, tmp_path / "csv" / "old.csv")
    write_bag(old, tmp_path / "bag")
    new = constructed_run(zeta=0.6)
    spec = {"type": "baseline", "signals": {"cylinder.position": {"nrmse": "2 %", "max_error": "0.5 mm"},
                                            "controller.fault_detected": {"max_error": 0}}}
    for source in ("csv", "bag"):
        same = check(old, {**spec, "file": source}, base=tmp_path)
        assert [o.passed for o in same] == [True, True, True], source
        assert same[0].value == pytest.approx(0.0, abs=1e-12)
        diff = check(new, {**spec, "file": source}, base=tmp_path)
        y_new, y_old = new.signal("cylinder.position"), old.signal("cylinder.position")
        assert diff[0].value == pytest.approx(np.max(np.abs(y_new - y_old)), rel=1e-9)
        assert diff[0].time == pytest.approx(new.times[np.argmax(np.abs(y_new - y_old))])
        nrmse = np.sqrt(np.mean((y_new - y_old) ** 2)) / np.ptp(y_old)
        assert diff[1].value == pytest.approx(nrmse, rel=1e-9)
        assert [o.passed for o in diff] == [diff[0].value <= 5e-4, nrmse <= 0.02, True]
        assert not all(o.passed for o in diff)
    with pytest.raises(AssertionSpecError, match=r"a\[0\]\.file: .* does not exist"):
        check(old, {**spec, "file": "nosuch"}, base=tmp_path)


def test_baseline_from_json_compares_the_margins(tmp_path):
    run = constructed_run()
    limit = {"name": "pressure", "type": "never_above", "signal": "left.pressure", "max": "125 bar"}
    first = check(run, limit)
    (tmp_path / "old.json").write_text(json.dumps({"assertions": [
        {k: v for k, v in o.__dict__.items() if k != "draw"} for o in first]}))
    same = check(run, limit, {"type": "baseline", "file": "old.json", "tolerance": "1 %"}, base=tmp_path)
    assert [o.passed for o in same] == [True, True]
    worse = check(run, {**limit, "max": "123 bar"}, {"type": "baseline", "file": "old.json", "tolerance": "1 %"},
                  base=tmp_path)
    # margin 3 bar now vs 5 bar before, at most 1 % of 123 bar lost: fails
    assert worse[1].name == "baseline old.json: pressure" and not worse[1].passed
    assert worse[1].value == pytest.approx(3e5) and worse[1].limit == pytest.approx(5e5 - 0.01 * 123e5)
