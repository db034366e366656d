"""pcv_sim.cli: the `pcv-sim` commands run in-process (text, --json, --plot) and their exit
statuses; one subprocess run of `python -m pcv_sim --version`."""

from __future__ import annotations

import copy
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from pcv_sim import __version__
from pcv_sim.analysis.static import zero_flow_equilibrium
from pcv_sim.cli import main
from pcv_sim.model.valve import ValveModel
from pcv_sim.params import DEFAULT_CONFIG, default_params

BAR = 1e5
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def strict_json(text: str):
    """JSON as other tools read it: NaN and Infinity are not JSON."""
    def refuse(token: str):
        raise ValueError(f"not JSON: {token}")

    return json.loads(text, parse_constant=refuse)


def run_json(capsys: pytest.CaptureFixture[str], *argv: str):
    assert main([*argv, "--json"]) == 0
    return strict_json(capsys.readouterr().out)


@pytest.fixture(scope="module")
def model() -> ValveModel:
    return ValveModel(default_params())


# --- commands --------------------------------------------------------------------------------


def test_static_json(capsys: pytest.CaptureFixture[str], model: ValveModel) -> None:
    data = run_json(capsys, "static")
    rest = data["zero_flow"]
    assert [r["duty"] for r in rest] == [0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0]
    assert len(data["curves"]) == 8
    # Sec. 4.2: at zero load flow the spool sits on the tank side; pressure rises with duty.
    assert all(r["spool_position_m"] < 0.0 for r in rest)
    pressures = [r["pressure_Pa"] for r in rest]
    assert pressures == sorted(pressures)
    # The same numbers as the library (the CLI is a thin layer): 70 % at ~122.5 bar.
    assert rest[4]["pressure_Pa"] == pytest.approx(zero_flow_equilibrium(model, 0.7).pressure, rel=1e-12)
    assert rest[4]["current_A"] == pytest.approx(1.5, rel=1e-12)
    curve = data["curves"][4]
    assert len(curve["spool_position_m"]) == len(curve["pressure_Pa"]) == len(curve["load_flow_m3s"]) == 100


def test_static_text(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["static", "--duties", "0.5", "0.7", "--points", "20"]) == 0
    out = capsys.readouterr().out
    assert "Zero load flow" in out and "Pressure-flow curves" in out
    assert "0.70" in out and "1.500" in out


def test_step_json(capsys: pytest.CaptureFixture[str], model: ValveModel) -> None:
    data = run_json(capsys, "step", "--from", "0.5", "--to", "0.7")
    assert (data["model"], data["from"], data["to"], data["step_time_s"]) == ("simplified", 0.5, 0.7, 0.02)
    m = data["metrics"]
    assert set(m) == {"pressure", "current", "spool_position"}
    for sig in m.values():
        assert set(sig) == {"initial", "final", "rise_time", "overshoot_percent", "settling_time", "peak", "band",
                            "noise"}
    p = m["pressure"]
    # From the 50 % to the 70 % zero-flow equilibrium: ~72.7 -> ~122.5 bar (static analysis).
    assert p["initial"] == pytest.approx(zero_flow_equilibrium(model, 0.5).pressure, abs=0.01 * BAR)
    assert p["final"] == pytest.approx(zero_flow_equilibrium(model, 0.7).pressure, abs=0.2 * BAR)
    assert 120 * BAR < p["final"] < 125 * BAR
    assert 0.0 < p["rise_time"] < 0.1 and p["settling_time"] < 0.38
    assert m["current"]["final"] == pytest.approx(1.5, abs=1e-3)
    assert data["units"]["pressure"] == "Pa"


def test_step_full_model_json(capsys: pytest.CaptureFixture[str]) -> None:
    simplified = run_json(capsys, "step", "--from", "0.5", "--to", "0.7", "--duration", "0.15")
    full = run_json(capsys, "step", "--from", "0.5", "--to", "0.7", "--duration", "0.15", "--model", "full")
    assert full["model"] == "full"
    # R20: with the equivalent damper the two models agree to < 0.05 bar (test_stepper).
    for key in ("initial", "final", "peak"):
        assert full["metrics"]["pressure"][key] == pytest.approx(simplified["metrics"]["pressure"][key], abs=0.05 * BAR)


def test_step_text_with_fall_rate(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["step", "--from", "0.8", "--to", "0.4", "--fall-rate", "2", "--duration", "0.3"]) == 0
    out = capsys.readouterr().out
    assert "Duty step 0.8 -> 0.4 at 0.02 s, simplified model" in out
    assert "pressure [bar]" in out and "current [A]" in out


def test_working_points_json(capsys: pytest.CaptureFixture[str]) -> None:
    data = run_json(capsys, "working-points")
    assert data["as_printed"]["net_area_m2"] == pytest.approx(3.1e-6, rel=1e-9)
    assert data["calibrated"]["net_area_m2"] == 2.859e-6
    cal = {p["name"]: p for p in data["calibrated"]["points"]}
    printed = {p["name"]: p for p in data["as_printed"]["points"]}
    for name in ("P1", "P2"):
        assert abs(cal[name]["pressure_error"]) < 1.0 * BAR          # test_static's tolerances
        assert -15 * BAR < printed[name]["pressure_error"] < -5 * BAR
    assert [r["name"] for r in data["required_constants"]] == ["P1", "P2"]


def test_working_points_text(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["working-points"]) == 0
    out = capsys.readouterr().out
    assert "As printed (net area 3.1e-06 m^2, preload 2 N)" in out
    assert "Calibrated: damping: equivalent (B + A_cc^2/K_d, R20) 302.0 Ns/m; calibration: net_area (net area 2.859e-06 m^2)" in out
    assert "P2 (1.490 A): force offset" in out


def test_working_points_fit_and_write(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    path = tmp_path / "v.yaml"
    path.write_text(DEFAULT_CONFIG.read_text(encoding="utf-8"), encoding="utf-8")
    data = run_json(capsys, "--config", str(path), "working-points", "--fit", "--kind", "both", "--write")
    fitted = data["fit"]["values"]
    cfg = yaml.safe_load(path.read_text(encoding="utf-8"))
    assert cfg["calibration"]["net_area"] == pytest.approx(fitted["calibration.net_area"], rel=1e-5)
    assert cfg["spool"]["spring_preload"] == pytest.approx(fitted["spool.spring_preload"], rel=1e-5)
    # Read back: the written config is in force, named "both".
    again = run_json(capsys, "--config", str(path), "working-points")
    assert again["in_force"]["calibration_kind"] == "both"
    assert all(abs(p["pressure_error"]) < 0.05 * BAR for p in again["calibrated"]["points"])
    assert main(["working-points", "--write"]) == 2
    assert "--write needs --fit" in capsys.readouterr().err


def test_linearize_json(capsys: pytest.CaptureFixture[str]) -> None:
    data = run_json(capsys, "linearize")
    assert set(data) == {"P1", "P2", "in_force"}
    state = data.pop("in_force")
    assert (state["damping_choice"], state["calibration_kind"], state["coil"]) == ("equivalent", "net_area", "table")
    assert [data[n]["current_A"] for n in ("P1", "P2")] == pytest.approx([1.5, 1.49], rel=1e-12)  # the table's
    assert data["P1"]["K_e"] > 0.0 > data["P2"]["K_e"]          # Sec. 5
    for point in data.values():
        assert point["stable"] is True
        assert len(point["eigenvalues"]) == 4
        assert all(re < 0.0 for re, _ in point["eigenvalues"])
        assert point["margins"]["phase_margin_deg"] > 0.0
    assert data["P2"]["margins"]["phase_margin_deg"] < data["P1"]["margins"]["phase_margin_deg"]


def test_linearize_text(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["linearize"]) == 0
    out = capsys.readouterr().out
    assert out.count("(stable)") == 2 and "UNSTABLE" not in out
    assert "K_e = K - K_fx + K_ff" in out


@pytest.mark.parametrize(
    "argv",
    [
        ["static", "--duties", "0.5", "0.7", "--points", "20"],
        ["step", "--from", "0.5", "--to", "0.7", "--duration", "0.1"],
        ["linearize"],
    ],
)
def test_plot_writes_a_png(capsys: pytest.CaptureFixture[str], tmp_path: Path, argv: list[str]) -> None:
    path = tmp_path / f"{argv[0]}.png"
    assert main([*argv, "--plot", str(path)]) == 0
    data = path.read_bytes()
    assert data.startswith(PNG_MAGIC)
    assert len(data) > 10_000          # a rendered figure, not an empty canvas
    assert f"wrote {path}" in capsys.readouterr().err


# --- bad arguments: exit status 2 and a message ----------------------------------------------


@pytest.mark.parametrize(
    ("argv", "match"),
    [
        (["step", "--from", "70", "--to", "0.7"], "70 is outside 0..1 (did you mean 0.7? the duty is a fraction, not percent)"),
        (["step", "--from", "0.5", "--to", "1.5"], "1.5 is outside 0..1"),
        (["step", "--from", "x", "--to", "0.7"], "'x' is not a number; a duty is a fraction 0..1"),
        (["step", "--from", "nan", "--to", "0.7"], "nan is outside 0..1"),
        (["step", "--from", "0.5"], "the following arguments are required: --to"),
        (["step", "--from", "0.5", "--to", "0.7", "--at", "-1"], "-1 must be a finite number > 0"),
        (["step", "--from", "0.5", "--to", "0.7", "--model", "exact"], "invalid choice: 'exact'"),
        (["static", "--duties", "30"], "did you mean 0.3?"),
        (["bogus"], "invalid choice: 'bogus'"),
        ([], "the following arguments are required: COMMAND"),
    ],
)
def test_bad_arguments_exit_2(capsys: pytest.CaptureFixture[str], argv: list[str], match: str) -> None:
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert match in err
    assert "usage:" in err


@pytest.mark.parametrize(
    ("argv", "match"),
    [
        (["step", "--from", "0.5", "--to", "0.7", "--at", "0.5"], "pcv-sim step: error: --at 0.5 s is not before --duration 0.4 s"),
        (["static", "--points", "1"], "pcv-sim static: error: --points 1: accepted is an integer >= 2"),
    ],
)
def test_option_conflicts_exit_2(capsys: pytest.CaptureFixture[str], argv: list[str], match: str) -> None:
    assert main(argv) == 2
    assert match in capsys.readouterr().err


def test_bad_config_exits_2_naming_the_key(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    data = copy.deepcopy(yaml.safe_load(DEFAULT_CONFIG.read_text(encoding="utf-8")))
    data["spool"]["masss"] = 0.04          # a typo next to the right key
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    assert main(["--config", str(path), "static"]) == 2
    captured = capsys.readouterr()
    assert "pcv-sim static: error:" in captured.err
    assert "unknown parameter spool.masss" in captured.err
    assert captured.out == ""
    # A misspelt key in place of the right one: the typo is named (and the file), not "missing".
    data["spool"].pop("mass")
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    assert main(["--config", str(path), "static"]) == 2
    err = capsys.readouterr().err
    assert "unknown parameter spool.masss" in err and str(path) in err
    data["spool"].pop("masss")
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    assert main(["--config", str(path), "static"]) == 2
    assert "missing parameter(s) spool.mass" in capsys.readouterr().err


def test_missing_config_exits_2(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    assert main(["--config", str(tmp_path / "nope.yaml"), "linearize"]) == 2
    assert "cannot read parameter file" in capsys.readouterr().err


def test_config_is_used(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    # A different calibration in --config changes the result: proof the file is read.
    data = yaml.safe_load(DEFAULT_CONFIG.read_text(encoding="utf-8"))
    data["calibration"]["net_area"] = None
    path = tmp_path / "printed.yaml"
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    out = run_json(capsys, "--config", str(path), "working-points")
    assert out["calibrated"]["net_area_m2"] == pytest.approx(3.1e-6, rel=1e-9)


# --- version --------------------------------------------------------------------------------


def test_version_in_process(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as info:
        main(["--version"])
    assert info.value.code == 0
    assert capsys.readouterr().out.strip() == f"pcv_sim {__version__}"


def test_version_as_a_module() -> None:
    # docs/ros_wheels.md: a child must not inherit the ros_wheels_bootstrapper mark.
    env = {k: v for k, v in os.environ.items() if k != "_ROS_WHEELS_BOOTSTRAP_COMPLETE"}
    proc = subprocess.run([sys.executable, "-m", "pcv_sim", "--version"], env=env, capture_output=True,
                          text=True, timeout=60, cwd=Path(__file__).resolve().parent.parent)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == f"pcv_sim {__version__}"


def test_reference_bags_refuses_a_file_as_out(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    # The bit-for-bit run of `pcv-sim reference-bags --out DIR` is test/replay/test_reproducible.py.
    target = tmp_path / "file"
    target.write_text("x")
    assert main(["reference-bags", "--out", str(target)]) == 2
    assert "is a file; expected a directory" in capsys.readouterr().err


def test_duty_hint_only_where_percent_is_plausible(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        main(["step", "--from", "1.5", "--to", "0.7"])
    err = capsys.readouterr().err
    assert "1.5 is outside 0..1" in err and "did you mean" not in err


def test_common_options_after_the_subcommand(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    from pcv_sim.cli import build_parser
    from pcv_sim.commands import COMMANDS

    required = {"replay": ["bag"], "import-csv": ["in.csv", "out"], "step": ["--from", "0.5", "--to", "0.7"],
                "calibrate": ["bag", "--fit", "spool.spring_preload", "-o", "out.yaml"],
                "scenario": ["run", "s.yaml"], "campaign": ["run", "c.yaml"]}
    parser = build_parser()
    names = [sys.modules[m].NAME for m in COMMANDS]
    for name in names:                      # every subcommand takes --config after its name
        args = parser.parse_args([name, *required.get(name, []), "--config", "f.yaml"])
        assert args.config == Path("f.yaml"), name
        assert parser.parse_args(["--config", "g.yaml", name, *required.get(name, [])]).config == Path("g.yaml")
        assert parser.parse_args([name, *required.get(name, [])]).config is None
    # and it is used: the as-printed calibration, as test_config_is_used does it before the command
    data = yaml.safe_load(DEFAULT_CONFIG.read_text(encoding="utf-8"))
    data["calibration"]["net_area"] = None
    path = tmp_path / "printed.yaml"
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    out = run_json(capsys, "working-points", "--config", str(path))
    assert out["calibrated"]["net_area_m2"] == pytest.approx(3.1e-6, rel=1e-9)
    assert main(["linearize", "--config", str(tmp_path / "nope.yaml")]) == 2
    assert "cannot read parameter file" in capsys.readouterr().err

def test_linearize_damping_choice(capsys: pytest.CaptureFixture[str]) -> None:
    """Sec. 5: "positive, but low, phase margin" at P2: the paper's 223.6 Ns/m leaves a few degrees,
    the equivalent damping (~300 Ns/m) ~10; the choice in force is named in text and JSON."""
    paper = run_json(capsys, "linearize", "--damping", "paper")
    equiv = run_json(capsys, "linearize", "--damping", "equivalent")
    assert paper["in_force"]["damping_choice"] == "paper" and paper["in_force"]["damping_Ns_per_m"] == 223.6
    assert equiv["in_force"]["damping_choice"] == "equivalent"
    assert 0.0 < paper["P2"]["margins"]["phase_margin_deg"] < equiv["P2"]["margins"]["phase_margin_deg"]
    assert main(["linearize", "--damping", "150"]) == 0
    out = capsys.readouterr().out
    assert "damping: custom 150.0 Ns/m" in out and "(UNSTABLE)" in out
    # The unstable loop's gain margin is a real, negative number (was "inf dB at inf rad/s").
    assert "gain margin -" in out and "inf dB" not in out
    with pytest.raises(SystemExit) as info:  # argparse refuses it: exit 2
        main(["linearize", "--damping", "soft"])
    assert info.value.code == 2
    assert "accepted are equivalent, paper or a number in Ns/m" in capsys.readouterr().err


def test_step_short_duration_warns_and_uses_the_static_solution(capsys: pytest.CaptureFixture[str]) -> None:
    full = run_json(capsys, "step", "--from", "0.5", "--to", "0.7")
    assert full["warnings"] == [] and full["steady_state"] == "static solution"
    assert full["in_force"]["damping_choice"] == "equivalent"
    rest = zero_flow_equilibrium(ValveModel(default_params()), 0.7)
    assert full["metrics"]["pressure"]["final"] == rest.pressure
    assert main(["step", "--from", "0.5", "--to", "0.7", "--duration", "0.04", "--json"]) == 0
    cap = capsys.readouterr()
    short = strict_json(cap.out)
    assert "ends before the response settles" in cap.err and "lengthen --duration" in cap.err
    # The steady state is the static one, not the window's end (the pressure is still rising there).
    assert short["metrics"]["pressure"]["final"] == rest.pressure
    assert short["metrics"]["pressure"]["settling_time"] is None


def test_replay_states_damping_and_calibration(capsys: pytest.CaptureFixture[str]) -> None:
    bag = str(Path(__file__).resolve().parent.parent / "bags" / "pcv_step_levels")
    assert main(["replay", bag, "--model", "simplified", "--solver", "fast"]) == 0
    assert "damping: equivalent (B + A_cc^2/K_d, R20)" in capsys.readouterr().out
    data = run_json(capsys, "replay", bag, "--model", "simplified", "--solver", "fast")
    assert data["in_force"]["calibration_kind"] == "net_area" and data["in_force"]["net_area_m2"] == 2.859e-6
    assert all("band" in s["signals"]["pressure"]["measured"] for s in data["steps"])
