"""`pcv-sim calibrate` end to end: a synthetic rig bag in, a valve YAML out that --config and
replay accept, a report, JSON, and exit status 2 on bad input."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from pcv_sim.calibration import write_rig_csv
from pcv_sim.cli import main
from pcv_sim.params import default_params, load_params, replace_param

NOISE = {"pressure": 0.3e5, "current": 0.005, "spool_position": 0.003e-3}


@pytest.fixture(scope="module")
def rig_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    tmp = tmp_path_factory.mktemp("rig")
    truth = replace_param(default_params(), "spool.spring_preload", 1.5)
    csv = write_rig_csv(tmp / "rig.csv", truth, [0.4, 0.8, 0.5], hold_s=0.25, noise=NOISE,
                        lag_s={"pressure": 0.002}, offset={"pressure": -0.4e5}, seed=11)
    assert main(["import-csv", str(csv), str(tmp / "bag"), "--skip-bad-rows"]) == 0
    return tmp / "bag"


def test_calibrate_writes_a_config_replay_accepts(rig_bag: Path, tmp_path: Path,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "fitted.yaml"
    report = tmp_path / "report.html"
    assert main(["calibrate", str(rig_bag), "--fit", "spool.spring_preload", "-o", str(out), "--solver", "fast",
                 "--report", str(report), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    (est,) = data["parameters"]
    assert est["name"] == "spool.spring_preload" and est["interval_95"][0] <= 1.5 <= est["interval_95"][1]
    assert data["converged"] is True and data["in_force"]["calibration_kind"] == "both"
    assert {s["role"] for s in data["signals"]} == {"pressure", "current", "spool_position"}
    steps = data["steps"][0]["steps"]        # per step and signal, before / after, SI
    assert {s["signal"] for s in steps} == {"pressure", "current", "spool_position"}
    pressure = [s for s in steps if s["signal"] == "pressure"]
    assert [s["duty_to"] for s in pressure] == [0.8, 0.5]
    # The fit closes the steady-state gap the wrong preload and the sensor offset made.
    assert all(abs(s["steady_state_error_after"]) < abs(s["steady_state_error_before"]) for s in pressure)
    fitted = load_params(out)
    assert fitted.spool.spring_preload == pytest.approx(est["value"], rel=1e-5)
    html = report.read_text()
    for part in ("95 % interval", "Correlations", "sensor lag, pressure", "Steps:", "data:image/png;base64"):
        assert part in html
    # The fitted YAML replays the recording better than the shipped one.
    assert main(["replay", str(rig_bag), "--model", "simplified", "--json"]) == 0
    before = json.loads(capsys.readouterr().out)["metrics"]["pressure_fit_percent"]
    assert main(["--config", str(out), "replay", str(rig_bag), "--model", "simplified", "--json"]) == 0
    after = json.loads(capsys.readouterr().out)["metrics"]["pressure_fit_percent"]
    assert after > before


def test_calibrate_text_and_markdown(rig_bag: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["calibrate", str(rig_bag), "--fit", "spool.spring_preload=0:4", "--signals", "pressure",
                 "--solver", "fast", "-o", str(tmp_path / "f.yaml"), "--report", str(tmp_path / "r.md")]) == 0
    out = capsys.readouterr().out
    assert "spool.spring_preload" in out and "in force:" in out and "sensor lag, pressure" in out
    assert "current" not in out.split("bag ")[-1]      # only the pressure was fitted
    assert (tmp_path / "r_plots").is_dir() and "![" in (tmp_path / "r.md").read_text()


@pytest.mark.parametrize(("argv", "message"), [
    (["--fit", "solenoid.force"], "not a scalar parameter of the valve YAML"),
    (["--fit", "spool.mass", "--signals", "flux"], "--signals 'flux': accepted are pressure, current"),
    (["--fit", "spool.mass", "--report", "r.pdf"], "must end in .md or .html"),
    (["--fit", "spool.mass", "--max-evaluations", "1"], "accepted is an integer >= 2"),
    (["--fit", "fluid.bulk_modulus=-1:2e9"], "LOW = -1 Pa is not a value of fluid.bulk_modulus"),
])
def test_calibrate_bad_input_exits_2(rig_bag: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                     argv: list[str], message: str) -> None:
    assert main(["calibrate", str(rig_bag), "-o", str(tmp_path / "f.yaml"), *argv]) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "f.yaml").exists()


def test_calibrate_not_converged_exits_1(rig_bag: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["calibrate", str(rig_bag), "--fit", "spool.spring_preload", "--max-evaluations", "2",
                 "--solver", "fast", "-o", str(tmp_path / "f.yaml")]) == 1
    assert "did not converge" in capsys.readouterr().err
    assert (tmp_path / "f.yaml").exists()


def test_calibrate_config_after_the_command_and_damping(rig_bag: Path, tmp_path: Path,
                                                        capsys: pytest.CaptureFixture[str]) -> None:
    src = tmp_path / "mine.yaml"
    src.write_text((Path(__file__).resolve().parents[2] / "config" / "valve.yaml").read_text()
                   .replace("spring_preload: 2.0 ", "spring_preload: 1.8 "))
    out = tmp_path / "f.yaml"
    assert main(["calibrate", str(rig_bag), "--config", str(src), "--fit", "spool.spring_preload", "--damping",
                 "paper", "--solver", "fast", "--signals", "pressure", "--max-evaluations", "30", "-o", str(out),
                 "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["parameters"][0]["initial"] == 1.8                     # started from --config
    fitted = load_params(out)
    assert fitted.spool.viscous_friction_simplified == 223.6            # the damping it was fitted with
    assert data["in_force"]["damping_choice"] == "paper"


def test_calibrate_sensors_only(rig_bag: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "same.yaml"
    assert main(["calibrate", str(rig_bag), "--fit", "none", "--solver", "fast", "-o", str(out), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["parameters"] == [] and len(data["sensor_lags_s"]) == 3
    assert load_params(out) == default_params()          # nothing fitted: the config as it was


def test_calibrate_thresholds(rig_bag: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """--fail-below / --fail-above gate on the metrics after the fit (worst over the bags), as
    replay's do on a plain replay: exit 1 when crossed, the failures named."""
    out = str(tmp_path / "f.yaml")
    base = ["calibrate", str(rig_bag), "--fit", "none", "--solver", "fast", "-o", out, "--signals", "pressure"]
    assert main([*base, "--json"]) == 0
    fit = json.loads(capsys.readouterr().out)["metrics_after"]["pressure_fit_percent"]
    assert main([*base, "--fail-below", f"pressure_fit_percent={fit + 0.01}"]) == 1
    assert "FAILED: pressure_fit_percent = " in capsys.readouterr().err
    assert main([*base, "--fail-below", f"pressure_fit_percent={fit - 0.01}", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["failed"] == []
    assert main([*base, "--fail-above", "pressure_rmse_bar=0.01"]) == 1
    assert main([*base, "--fail-below", "flux_fit=1"]) == 2
    assert "unknown metric 'flux_fit' for --fail-below; this fit has: pressure_fit_percent, pressure_rmse_bar" \
        in capsys.readouterr().err
    assert main([*base, "--fail-below", "x"]) == 2
    assert "expected METRIC=NUMBER" in capsys.readouterr().err


def test_calibrate_refuses_a_named_signal_the_bag_lacks(rig_bag: Path, tmp_path: Path,
                                                        capsys: pytest.CaptureFixture[str]) -> None:
    """--signals pressure,current on a bag without current: exit 2 naming what the bag has, not a
    fit of the pressure alone that puts the difference into the pressure offset."""
    csv = tmp_path / "rig.csv"
    write_rig_csv(csv, default_params(), [0.4, 0.8], hold_s=0.2, noise=NOISE, seed=3, broken_rows=0)
    rows = [line.split(",") for line in csv.read_text().splitlines()]
    csv.write_text("\n".join(",".join(r[:3] + r[4:]) for r in rows) + "\n")   # the current column out
    assert main(["import-csv", str(csv), str(tmp_path / "bag")]) == 0
    out = tmp_path / "f.yaml"
    argv = ["calibrate", str(tmp_path / "bag"), "--fit", "calibration.net_area", "-o", str(out)]
    assert main([*argv, "--signals", "pressure,current"]) == 2
    err = capsys.readouterr().err
    assert "--signals current: " in err and "does not record current (it has pressure, spool_position)" in err
    assert not out.exists()
    # Two bags: one lacking the signal is enough to refuse it.
    assert main(["calibrate", str(rig_bag), str(tmp_path / "bag"), "--fit", "none", "-o", str(out),
                 "--signals", "current"]) == 2
    assert f"{tmp_path / 'bag'} does not record current" in capsys.readouterr().err


def test_calibrate_names_the_solver_that_ran(rig_bag: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """--model full runs the emulator's fixed-step engine unless --solver radau: the result says so."""
    base = ["calibrate", str(rig_bag), "--fit", "none", "--model", "full", "--signals", "pressure",
            "--max-evaluations", "2", "-o", str(tmp_path / "f.yaml"), "--json"]
    main(base)
    assert json.loads(capsys.readouterr().out)["solver"] == "stepper"
    main([*base, "--solver", "fast"])
    assert json.loads(capsys.readouterr().out)["solver"] == "stepper"
