"""pcv_sim.params: the shipped YAML loads with Table 1's values; every refusal names its key.

Each refused file is the default config with one thing changed (yaml.safe_load, edit, dump),
so a test fails only for the reason it names.
"""

from __future__ import annotations

import copy
import math
from pathlib import Path

import pytest
import yaml

from pcv_sim.errors import ParameterError, PcvSimError
from pcv_sim.params import (
    DEFAULT_CONFIG,
    ValveParams,
    default_params,
    load_params,
    params_from_mapping,
    params_to_mapping,
    replace_param,
    validate_section_value,
)


@pytest.fixture(scope="module")
def default_mapping() -> dict:
    return yaml.safe_load(DEFAULT_CONFIG.read_text(encoding="utf-8"))


def write_modified(tmp_path: Path, mapping: dict, edit) -> Path:
    """The default mapping with `edit(data)` applied, dumped to a YAML file in tmp_path."""
    data = copy.deepcopy(mapping)
    edit(data)
    path = tmp_path / "valve.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    return path


def set_key(section: str, key: str, value):
    def edit(data: dict) -> None:
        data[section][key] = value

    return edit


# --- the default ----------------------------------------------------------------------------


def test_default_config_loads_with_table_1_values() -> None:
    p = load_params()
    assert isinstance(p, ValveParams)
    assert p == load_params(DEFAULT_CONFIG) == default_params()
    # Table 1 (paper appendix A.2), as printed; exact: the YAML carries the printed decimals.
    assert p.spool.mass == 0.04
    assert p.spool.pressure_area == 6.36e-5
    assert p.spool.chamber_area == 6.05e-5
    assert p.spool.spring_stiffness == 500.0        # K = 0.5 N/mm
    assert p.spool.spring_preload == 2.0
    assert p.spool.viscous_friction == 4.47
    assert p.orifice.gap_height == 1.5e-5
    assert p.orifice.hole_radius == 0.75e-3         # R4: 1.5 mm diameter (text), not Table 1's 1.5e-3
    assert p.damping.restrictor_conductance == 1.24e-11
    assert p.damping.chamber_volume == 4.7e-11
    assert (p.fluid.density, p.fluid.bulk_modulus, p.fluid.kinematic_viscosity) == (900.0, 1.0e9, 46e-6)
    assert p.circuit.load_volume == 1e-4
    assert p.solenoid.restoring_f3 == (2.13, -9.48, 19.14)
    assert p.solenoid.dissipating == (-0.0004, -0.0003, 0.0472, 0.0059)
    assert p.solenoid.force[3] == (10.76, -40.61, 23.38, 47.33)


def test_net_area_null_is_the_printed_difference() -> None:
    printed = replace_param(default_params(), "calibration.net_area", None)
    # Table 1: A_c - A_cc = 6.36e-5 - 6.05e-5 = 3.1e-6 m^2 (reading R11); rel 1e-9 covers the
    # rounding of the float subtraction only.
    assert printed.net_area == pytest.approx(3.1e-6, rel=1e-9)
    assert printed.chamber_area == pytest.approx(6.05e-5, rel=1e-12)
    # R20: B + A_cc^2 / K_d = 4.47 + (6.05e-5)^2 / 1.24e-11 = 4.47 + 295.18 = 299.65 Ns/m (by hand).
    assert printed.equivalent_damping == pytest.approx(4.47 + 6.05e-5**2 / 1.24e-11, rel=1e-12)
    assert printed.equivalent_damping == pytest.approx(299.65, abs=0.01)


def test_calibrated_net_area_moves_the_chamber_side_only() -> None:
    p = default_params()
    assert p.calibration.net_area == 2.859e-6
    assert p.net_area == 2.859e-6
    # R21: A_c stays as printed, A_cc in effect = A_c - net_area.
    assert p.chamber_area == pytest.approx(6.36e-5 - 2.859e-6, rel=1e-12)
    assert p.spool.pressure_area == 6.36e-5
    assert p.simplified_damping == p.equivalent_damping     # the default is 'equivalent'
    tuned = replace_param(p, "spool.viscous_friction_simplified", 223.6)
    assert tuned.simplified_damping == 223.6                # Table 1's B_simplified


def test_params_mapping_round_trips() -> None:
    p = default_params()
    mapping = params_to_mapping(p)
    assert params_from_mapping(mapping) == p
    # The plain form survives YAML (lists, not tuples), as a user's config would.
    assert params_from_mapping(yaml.safe_load(yaml.safe_dump(mapping))) == p
    assert isinstance(mapping["solenoid"]["force"], list)
    assert isinstance(mapping["solenoid"]["force"][0], list)


def test_replace_param_returns_a_validated_copy() -> None:
    p = default_params()
    q = replace_param(p, "spool.mass", 0.05)
    assert q.spool.mass == 0.05
    assert p.spool.mass == 0.04                              # the original is untouched
    assert q.spool.pressure_area == p.spool.pressure_area
    assert replace_param(p, "orifice.hole_count", 12) == p


# --- refusals of load_params ------------------------------------------------------------------


@pytest.mark.parametrize(
    ("edit", "match"),
    [
        # unknown key: a typo must not silently fall back to a default
        (lambda d: d["spool"].update(masss=0.04), r"unknown parameter spool\.masss"),
        (lambda d: d.update(bogus={"a": 1}), r"unknown section\(s\) \['bogus'\]"),
        (lambda d: d.pop("fluid"), r"missing section\(s\) \['fluid'\]"),
        (lambda d: d["spool"].pop("mass"), r"missing parameter\(s\) spool\.mass"),
        (lambda d: d.update(spool=3), r"section 'spool' must be a mapping"),
        # wrong types
        (set_key("spool", "mass", "heavy"), r"spool\.mass: got 'heavy' \(str\); accepted is a number in kg"),
        (set_key("spool", "mass", True), r"spool\.mass: got True \(bool\)"),
        (set_key("solenoid", "restoring_f3", [2.13, -9.48]), r"solenoid\.restoring_f3: .*a list of 3 numbers"),
        (set_key("solenoid", "restoring_f1", "1 2 3"), r"solenoid\.restoring_f1: .*a list of 6 numbers"),
        (set_key("solenoid", "dissipating", [1, 2, "x", 4]), r"solenoid\.dissipating\[2\]: got 'x'"),
        (set_key("solenoid", "force", [[1, 2, 3, 4]] * 3), r"solenoid\.force: .*a 4x4 list of lists"),
        (set_key("solenoid", "force", [[1, 2, 3, 4]] * 3 + [[1, 2, 3]]), r"solenoid\.force\[3\]: .*a list of 4"),
        (set_key("fits", "tank_geometry", []), r"fits\.tank_geometry: got \[\]; accepted is a Nx3 list of lists"),
        (set_key("fits", "pump_jet", [[1.0, 2.0]]), r"fits\.pump_jet\[0\]: .*a list of 3 numbers"),
        (set_key("orifice", "hole_count", 12.5), r"orifice\.hole_count: got 12\.5; accepted is an integer"),
        (set_key("solenoid", "pwm", 3), r"solenoid\.pwm: got 3; accepted is one of 'averaged', 'switched'"),
        (set_key("spool", "viscous_friction_simplified", "tuned"),
         r"spool\.viscous_friction_simplified: got 'tuned' .*'equivalent' or a number in Ns/m"),
        (set_key("calibration", "net_area", "none"), r"calibration\.net_area: got 'none' .*null \(off\) or a number"),
        # non-physical values
        (set_key("spool", "mass", -0.04), r"spool\.mass: got -0\.04; accepted is a plausible value 0\.001 \.\. 1 \(kg\)"),
        (set_key("circuit", "load_volume", 0.0), r"circuit\.load_volume: got 0\.0; accepted is a plausible value 1e-06 \.\. 1 \(m\^3\)"),
        # Plausible ranges, not signs: 1e-12 m^3 passes "> 0" but makes the model diverge (issue: 1.2e282 bar).
        (set_key("circuit", "load_volume", 1e-12), r"circuit\.load_volume: got 1e-12; accepted is a plausible value 1e-06 \.\. 1"),
        (set_key("fluid", "bulk_modulus", 1e14), r"fluid\.bulk_modulus: got 1\d+\.0; accepted is a plausible value 1e\+08 \.\. 5e\+09 \(Pa\)"),
        (set_key("circuit", "supply_pressure", 2000.0e5), r"circuit\.supply_pressure: got 200000000\.0; accepted is a plausible value 100000 \.\. 4e\+07 \(Pa\)"),
        (set_key("circuit", "tank_pressure", -1.0), r"circuit\.tank_pressure: got -1\.0; accepted is a plausible value 0 \.\. 1e\+06 \(Pa\)"),
        (set_key("fluid", "density", math.nan), r"fluid\.density: got nan; accepted is a finite number"),
        (set_key("fluid", "cavitation_pressure", -0.9), r"fluid\.cavitation_pressure: got -0\.9; accepted is a plausible value -100000 \.\. -10000 \(Pa\)"),
        (set_key("fluid", "cavitation_pressure", -2.0e5), r"fluid\.cavitation_pressure: got -200000\.0; accepted is a plausible value -100000 \.\. -10000"),
        (set_key("fluid", "density", math.inf), r"fluid\.density: got inf; accepted is a finite number"),
        (set_key("spool", "chamber_area", 6.36e-5), r"spool\.chamber_area=6\.36e-05 >= spool\.pressure_area"),
        (set_key("spool", "chamber_area", 7e-5), r"spool\.chamber_area=7e-05 >= spool\.pressure_area"),
        (set_key("spool", "stroke_min_mm", 0.0), r"spool\.stroke_min_mm=0\.0 .*stroke_min_mm < 0 < stroke_max_mm"),
        (set_key("spool", "stroke_min_mm", 0.1), r"spool\.stroke_min_mm=0\.1"),
        (set_key("spool", "stroke_max_mm", -0.1), r"spool\.stroke_max_mm=-0\.1"),
        (set_key("spool", "stroke_min_mm", -2.0), r"stroke_min_mm \+ solenoid\.core_offset_mm .*must stay >= 0"),
        (set_key("calibration", "net_area", 7e-5), r"calibration\.net_area=7e-05: accepted is null"),
        (lambda d: d["circuit"].update(tank_pressure=9e5, supply_pressure=5e5),
         r"circuit\.tank_pressure must be below circuit\.supply_pressure"),
        (set_key("simulation", "time_step", 2e-3), r"simulation\.time_step: got 0\.002; accepted is a plausible value 1e-07 \.\. 0\.001 \(s\)"),
        (set_key("command", "duty_range", [0.0, 1.5]), r"command\.duty_range: got \[0\.0, 1\.5\]; accepted is \[min, max\]"),
        (set_key("command", "duty_range", [-0.1, 1.0]), r"command\.duty_range: .*0 <= min < max <= 1"),
        (set_key("command", "duty_range", [0.8, 0.2]), r"command\.duty_range: got \[0\.8, 0\.2\]"),
        (set_key("command", "duty_range", [0.5, 0.5]), r"command\.duty_range: got \[0\.5, 0\.5\]"),
        (set_key("command", "duty_fall_rate_limit", 0.0), r"command\.duty_fall_rate_limit: got 0\.0; accepted is a plausible value 0\.001"),
        (set_key("fits", "pump_jet_cap", 1.2), r"fits\.pump_jet_cap: got 1\.2; accepted is a fraction in 0\.\.1"),
        # choices
        (set_key("solenoid", "pwm", "pulsed"), r"solenoid\.pwm: got 'pulsed'; accepted is one of 'averaged', 'switched'"),
        (set_key("simulation", "integrator", "rk45"), r"simulation\.integrator: got 'rk45'; .*'euler', 'rk2', 'rk4'"),
    ],
)
def test_load_params_refuses_with_the_key_named(tmp_path: Path, default_mapping: dict, edit, match: str) -> None:
    path = write_modified(tmp_path, default_mapping, edit)
    with pytest.raises(ParameterError, match=match):
        load_params(path)


def test_parameter_error_is_a_value_error_and_a_pcv_sim_error(tmp_path: Path, default_mapping: dict) -> None:
    path = write_modified(tmp_path, default_mapping, set_key("spool", "mass", -1.0))
    with pytest.raises(ValueError, match=r"spool\.mass") as info:
        load_params(path)
    assert isinstance(info.value, PcvSimError)


def test_cross_field_errors_name_the_file(tmp_path: Path, default_mapping: dict) -> None:
    path = write_modified(tmp_path, default_mapping, set_key("spool", "chamber_area", 7e-5))
    with pytest.raises(ParameterError, match=r"spool\.chamber_area") as info:
        load_params(path)
    assert str(info.value).startswith(f"{path}: ")


def test_yaml_11_exponent_trap_hints_at_the_fix(tmp_path: Path) -> None:
    # YAML 1.1 (PyYAML) reads 1e9 without a dot and a sign as the string '1e9'.
    text = DEFAULT_CONFIG.read_text(encoding="utf-8")
    assert "bulk_modulus: 1.0e+9" in text
    path = tmp_path / "valve.yaml"
    path.write_text(text.replace("bulk_modulus: 1.0e+9", "bulk_modulus: 1e9"), encoding="utf-8")
    assert yaml.safe_load(path.read_text())["fluid"]["bulk_modulus"] == "1e9"   # the trap itself
    with pytest.raises(ParameterError, match=r"fluid\.bulk_modulus: got '1e9' .*write 1\.0e\+9"):
        load_params(path)


def test_nan_written_as_yaml_nan_is_refused(tmp_path: Path) -> None:
    text = DEFAULT_CONFIG.read_text(encoding="utf-8").replace("mass: 0.04", "mass: .nan")
    path = tmp_path / "valve.yaml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(ParameterError, match=r"spool\.mass: got nan; accepted is a finite number"):
        load_params(path)


def test_invalid_yaml_syntax(tmp_path: Path) -> None:
    path = tmp_path / "broken.yaml"
    path.write_text("spool: [mass: 0.04\n  pressure_area: {\n", encoding="utf-8")
    with pytest.raises(ParameterError, match=r"broken\.yaml: not valid YAML"):
        load_params(path)


def test_nonexistent_file(tmp_path: Path) -> None:
    with pytest.raises(ParameterError, match=r"cannot read parameter file .*nope\.yaml"):
        load_params(tmp_path / "nope.yaml")


@pytest.mark.parametrize("text", ["- spool\n- fluid\n", "just a string\n", ""])
def test_top_level_must_be_a_mapping(tmp_path: Path, text: str) -> None:
    path = tmp_path / "valve.yaml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(ParameterError, match=r"the top level must be a mapping of sections"):
        load_params(path)


# --- replace_param and validate_section_value hold values to the same rules -----------------


@pytest.mark.parametrize(
    ("dotted", "value", "match"),
    [
        ("spool.masss", 0.04, r"unknown parameter spool\.masss; accepted in spool: mass"),
        ("bogus.mass", 0.04, r"unknown section 'bogus'"),
        ("spool.mass", "heavy", r"spool\.mass: got 'heavy'"),
        ("spool.mass", -1.0, r"spool\.mass: got -1\.0; accepted is a plausible value 0\.001 \.\. 1 \(kg\)"),
        ("fluid.bulk_modulus", "1e9", r"write 1\.0e\+9"),
        ("solenoid.pwm", "pulsed", r"solenoid\.pwm: got 'pulsed'"),
        ("simulation.integrator", "rk45", r"simulation\.integrator: got 'rk45'"),
        ("command.duty_range", [0.9, 0.1], r"command\.duty_range: got \[0\.9, 0\.1\]"),
        # cross-field checks run on the replaced copy, prefixed with the assignment
        ("spool.chamber_area", 7e-5, r"spool\.chamber_area=7e-05: spool\.chamber_area=7e-05 >= spool\.pressure_area"),
        ("spool.stroke_min_mm", 0.2, r"spool\.stroke_min_mm=0\.2: .*stroke_min_mm < 0 < stroke_max_mm"),
        ("circuit.tank_pressure", 300e5, r"circuit\.tank_pressure: got 30000000\.0; accepted is a plausible value 0 \.\. 1e\+06"),
    ],
)
def test_replace_param_validates_like_the_file(dotted: str, value, match: str) -> None:
    p = default_params()
    with pytest.raises(ParameterError, match=match):
        replace_param(p, dotted, value)
    assert p == load_params()   # nothing changed in place


def test_validate_section_value_converts_ints_to_floats() -> None:
    out = validate_section_value("spool", "mass", 1)
    assert out == 1.0 and isinstance(out, float)
    assert validate_section_value("calibration", "net_area", None) is None
    assert validate_section_value("spool", "viscous_friction_simplified", "equivalent") == "equivalent"
    assert validate_section_value("command", "duty_range", [0, 1]) == (0.0, 1.0)


def test_a_duplicate_key_is_refused_with_its_name_and_line(tmp_path: Path) -> None:
    text = DEFAULT_CONFIG.read_text(encoding="utf-8")
    lines = text.splitlines()
    at = next(k for k, line in enumerate(lines) if line.strip().startswith("mass:"))
    lines.insert(at + 1, "  mass: 0.05")            # YAML alone would keep 0.05 silently
    path = tmp_path / "valve.yaml"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    with pytest.raises(ParameterError, match=rf"valve\.yaml: duplicate key 'mass' at line {at + 2} \(first at line {at + 1}\)"):
        load_params(path)


def test_a_key_added_later_is_optional_with_its_default(tmp_path: Path, default_mapping: dict) -> None:
    """fluid.cavitation_pressure came after valve YAMLs were written: a file without it loads with
    the default; the keys of the paper stay required."""
    path = write_modified(tmp_path, default_mapping, lambda d: d["fluid"].pop("cavitation_pressure"))
    assert load_params(path).fluid.cavitation_pressure == -0.9e5
    path = write_modified(tmp_path, default_mapping, lambda d: d["fluid"].pop("density"))
    with pytest.raises(ParameterError, match=r"missing parameter\(s\) fluid\.density"):
        load_params(path)


def test_values_with_units_are_read_in_si(tmp_path: Path, default_mapping: dict) -> None:
    data = copy.deepcopy(default_mapping)
    data["circuit"]["supply_pressure"] = "200 bar"
    data["simulation"]["time_step"] = "0.1 ms"
    path = tmp_path / "valve.yaml"
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    p = load_params(path)
    assert p.circuit.supply_pressure == pytest.approx(200e5)
    assert p.simulation.time_step == pytest.approx(1e-4)
    data["circuit"]["supply_pressure"] = "200 mm"
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    with pytest.raises(ParameterError, match=r"circuit\.supply_pressure: unit 'mm' in '200 mm' \(mm is a unit of "
                                             r"length\); accepted for a pressure are Pa, kPa, MPa, bar"):
        load_params(path)


def test_the_yaml_files_read_through_libyaml_as_through_pyyaml():
    """read_yaml parses with libyaml where pyyaml has it: every YAML file of the repository (valve,
    rig, emulator, scenarios, campaigns) gives the data pyyaml's own SafeLoader gives; a duplicate
    key and a broken document are refused in pyyaml's words, line and column."""
    from pcv_sim.params import read_yaml, yaml_load_unique

    repo = Path(__file__).resolve().parents[1]
    files = [*repo.glob("config/*.yaml"), *repo.glob("examples/**/*.yaml"), *repo.glob("launch/**/*.yaml")]
    assert len(files) >= 10
    for f in files:
        want = yaml.load(f.read_text(encoding="utf-8"), Loader=yaml.SafeLoader)
        assert read_yaml(f, "file") == want and read_yaml(f, "file", unique=True) == want, f
    with pytest.raises(ParameterError, match=r"x: duplicate key 'a' at line 3 \(first at line 1\)"):
        yaml_load_unique("a: 1\nb: {c: 2}\na: 3\n", "x")
    bad = "a: 1\nb: c: 2\n"
    with pytest.raises(yaml.YAMLError) as pure:
        yaml.safe_load(bad)
    with pytest.raises(ParameterError) as ours:
        yaml_load_unique(bad, "x")
    assert str(ours.value) == f"x: not valid YAML: {pure.value}"
