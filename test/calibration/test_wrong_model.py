"""A fit of the wrong parameters must not pass for a good one. Synthetic rig recordings of a valve
whose coil is 15 % hotter (resistance +15 %) and of one whose oil has half the bulk modulus,
calibrated with the README's two keys (spring preload, net area): the fit says that it stays well
above the recording's noise, which sensor offsets are too large for a sensor, and names the
parameter whose effect matches what is left, so the user knows what to add to --fit."""

from __future__ import annotations

from pathlib import Path

import pytest

from pcv_sim.calibration import calibrate, fit_parameter, write_rig_csv
from pcv_sim.calibration.fit import NOISE_RATIO_LIMIT, PLAUSIBLE_OFFSET
from pcv_sim.io.csv_import import import_csv
from pcv_sim.params import default_params, replace_param
from pcv_sim.replay import load_recording

LAG = {"pressure": 0.003, "current": 0.0005, "spool_position": 0.001}
NOISE = {"pressure": 0.3e5, "current": 0.005, "spool_position": 0.003e-3}
OFFSET = {"pressure": 0.5e5, "current": 0.01, "spool_position": 0.005e-3}
README_KEYS = ("spool.spring_preload", "calibration.net_area")


def _fit(tmp: Path, key: str, value: float):
    truth = replace_param(default_params(), key, value)
    csv = write_rig_csv(tmp / "rig.csv", truth, [0.3, 0.6, 0.9, 0.5], hold_s=0.3, lag_s=LAG, noise=NOISE,
                        offset=OFFSET, seed=1)
    import_csv(csv, tmp / "bag", skip_bad_rows=True)
    p0 = default_params()
    return calibrate([load_recording(tmp / "bag")], p0, [fit_parameter(p0, k) for k in README_KEYS])


@pytest.fixture(scope="module")
def hot_coil(tmp_path_factory: pytest.TempPathFactory):
    return _fit(tmp_path_factory.mktemp("coil"), "solenoid.coil_resistance", 5.6 * 1.15)


@pytest.fixture(scope="module")
def soft_oil(tmp_path_factory: pytest.TempPathFactory):
    return _fit(tmp_path_factory.mktemp("oil"), "fluid.bulk_modulus", 0.5e9)


def test_hot_coil_is_named(hot_coil) -> None:
    r = hot_coil
    # The fit converges, and stays well above the noise: said per signal, with the noise floor.
    assert r.status_code > 0
    current = next(s for s in r.signals if s.role == "current")
    assert current.rmse_after > 3 * NOISE_RATIO_LIMIT * current.noise_sigma
    said = [w for w in r.warnings if w.startswith("the model does not explain the current of ")]
    assert len(said) == 1 and "x the recording's noise level" in said[0] and "where the noise allows" in said[0]
    # The current offset absorbed the coil: too large for a current sensor, and said so.
    offset = next(e for e in r.offsets if e.name == "offset.current[0]")
    assert abs(offset.value) > 3 * PLAUSIBLE_OFFSET["current"]
    assert any(w.startswith("the current offset of ") and "more than a current sensor's zero error" in w
               for w in r.warnings), r.warnings
    # What is left points at the coil resistance, first, with about the change that was made.
    first = r.suggestions[0]
    assert first.key == "solenoid.coil_resistance" and first.share > 0.8
    assert first.relative_change == pytest.approx(0.15, abs=0.05)
    assert any("add the first to --fit (--fit spool.spring_preload,calibration.net_area,solenoid.coil_resistance)"
               in w for w in r.warnings), r.warnings


def test_soft_oil_is_named(soft_oil) -> None:
    r = soft_oil
    pressure = next(s for s in r.signals if s.role == "pressure")
    assert pressure.rmse_after > 2 * NOISE_RATIO_LIMIT * pressure.noise_sigma
    assert any(w.startswith("the model does not explain the pressure of ") for w in r.warnings), r.warnings
    assert any(w.startswith("the pressure offset of ") for w in r.warnings), r.warnings
    # Only V / beta acts (Eq. 15): the bulk modulus and the load volume are named together, first,
    # the modulus about halved (a linearised step: -50 % of a change to 1/2), and said to be alike.
    top = {s.key: s for s in r.suggestions[:2]}
    assert set(top) == {"fluid.bulk_modulus", "circuit.load_volume"}, r.suggestions
    assert top["fluid.bulk_modulus"].relative_change == pytest.approx(-0.5, abs=0.1)
    assert any("the same effect as" in w for w in r.warnings), r.warnings


def test_the_right_model_is_not_questioned(tmp_path: Path) -> None:
    """The same recording of a valve that differs only in what is fitted: no such warning."""
    r = _fit(tmp_path, "spool.spring_preload", 2.6)
    for s in r.signals:
        assert s.rmse_after < NOISE_RATIO_LIMIT * s.noise_sigma, s
    assert r.suggestions == ()
    assert not [w for w in r.warnings if "does not explain" in w or "sensor's zero error" in w
                or "what the fit leaves" in w or "lags by" in w], r.warnings
