"""CSV import: units by flags or header, bad rows by line number, and the round trip
CSV -> bag -> replay giving the same metrics as the original bag."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pcv_sim.cli import main
from pcv_sim.errors import BagError
from pcv_sim.io.bag import read_bag
from pcv_sim.io.csv_import import CsvImportError, import_csv, parse_units
from pcv_sim.params import load_params
from pcv_sim.replay import load_recording, replay

REPO = Path(__file__).resolve().parents[2]
LEVELS = REPO / "bags" / "pcv_step_levels"


def _export(path: Path, *, header: str | None, until_s: float = 1.5) -> Path:
    """The levels bag as rig-style CSV: one row per 1 ms sample, duty held, display units."""
    b = read_bag(LEVELS)
    t = b["/pressure"].t_ns
    t0 = int(b["/duty_cycle"].t_ns[0])
    keep = t <= t0 + int(until_s * 1e9)
    duty_idx = np.searchsorted(b["/duty_cycle"].t_ns, t[keep], side="right") - 1
    rows = [header] if header else []
    for k, i in enumerate(np.nonzero(keep)[0]):
        rows.append(",".join(repr(float(x)) for x in (
            (t[i] - t0) / 1e6, b["/duty_cycle"].value[duty_idx[k]] * 100, b["/pressure"].value[i] / 1e5,
            b["/current"].value[i], b["/spool_position"].value[i] * 1e3)))
    path.write_text("\n".join(rows) + "\n")
    return path


def test_round_trip_gives_the_same_metrics(tmp_path):
    params = load_params()
    csv = _export(tmp_path / "rig.csv", header="time[ms],duty[%],pressure[bar],current[A],position[mm]")
    res = import_csv(csv, tmp_path / "from_csv")
    assert res.rows == 1501 and not res.skipped
    assert res.units == {"time": "ms", "duty_cycle": "%", "pressure": "bar", "current": "a", "spool_position": "mm"}
    # The original, cut to the same 1.5 s.
    orig = load_recording(LEVELS)
    a = replay(load_recording(tmp_path / "from_csv"), params, model="simplified")
    b = replay(orig, params, model="simplified")
    ma, mb = a.scalar_metrics(), {k: v for k, v in b.scalar_metrics().items()}
    # Same inputs; the CSV ends at 1.5 s, inside step 5's window: steps 1-4 must agree.
    assert len(a.steps) == 5
    for sa, sb in zip(a.steps[:4], b.steps[:4]):
        assert sa.step.duty_from == pytest.approx(sb.step.duty_from, abs=1e-12)
        for role in ("pressure", "current", "spool_position"):
            for k, v in sa.errors(role).items():
                assert v == pytest.approx(sb.errors(role)[k], rel=1e-6, abs=1e-9), (role, k)
    whole = replay(load_recording(_bag_cut(tmp_path)), params, model="simplified").scalar_metrics()
    for k, v in ma.items():
        assert v == pytest.approx(whole[k], rel=1e-6, abs=1e-9), k
    assert mb  # the full original replays too


def _bag_cut(tmp_path: Path) -> Path:
    """The original bag's first 1.5 s through the CLI with SI units (a second route)."""
    csv = _export(tmp_path / "si.csv", header=None)
    out = tmp_path / "si_bag"
    assert main(["import-csv", str(csv), str(out), "--columns", "time,duty,pressure,current,position",
                 "--units", "time=ms,duty=percent,pressure=bar", "--units", "position=mm"]) == 0
    return out


BAD = """time[s],duty[1],pressure[Pa],current[A]
0.000,0.5,7.0e6,1.07
0.001,0.5,7.0e6
0.002,0.5,abc,1.07
0.003,0.5,nan,1.07
0.004,0.5,,1.07
0.004,0.5,7.1e6,1.07
0.003,0.5,7.1e6,1.07
0.006,70,7.1e6,1.07
# a comment line
0.007,0.7,7.2e6,1.2
"""


def test_bad_rows_are_refused_with_line_numbers(tmp_path, capsys):
    csv = tmp_path / "bad.csv"
    csv.write_text(BAD)
    with pytest.raises(CsvImportError, match=(
            r"6 bad row\(s\): line 3: 3 fields, expected 4; line 4: pressure 'abc' is not a number; "
            r"line 5: pressure is nan; line 6: pressure is empty; line 8: time 0.003 s does not increase "
            r"\(previous good row: 0.004 s\); line 9: duty 70 is outside 0..1 after conversion "
            r"\(declare duty=percent\?\)")):
        import_csv(csv, tmp_path / "x")
    assert not (tmp_path / "x").exists()
    assert main(["import-csv", str(csv), str(tmp_path / "y")]) == 2
    assert "--skip-bad-rows" in capsys.readouterr().err


def test_skip_bad_rows_reports_them(tmp_path, capsys):
    csv = tmp_path / "bad.csv"
    csv.write_text(BAD)
    res = import_csv(csv, tmp_path / "ok", skip_bad_rows=True)
    assert res.rows == 3
    assert [b.line for b in res.skipped] == [3, 4, 5, 6, 8, 9]
    b = read_bag(tmp_path / "ok")
    assert b["/pressure"].t_ns.tolist() == [0, 4_000_000, 7_000_000]
    assert b["/pressure"].value.tolist() == [7.0e6, 7.1e6, 7.2e6]
    assert b["/pressure"].stamp_ns.tolist() == [0, 4_000_000, 7_000_000]
    assert main(["import-csv", str(csv), str(tmp_path / "ok2"), "--skip-bad-rows"]) == 0
    err = capsys.readouterr().err
    assert "skipped line 3: 3 fields, expected 4" in err and "6 bad row(s) skipped" in err


@pytest.mark.parametrize(("text", "kwargs", "match"), [
    ("0,0.5,1\n", {}, r"has no header line: name the columns with --columns"),
    ("time,duty\n0,0.5\n", {}, r"at least one of pressure, current, position"),
    ("time,pressure\n0,1\n", {}, r"a time and a duty column are needed"),
    ("time[h],duty,pressure\n0,0.5,1\n", {}, r"unit 'h' for time: accepted are s, ms, us, ns"),
    ("0,0.5,1\n", {"columns": ["time", "duty", "flux"]}, r"unknown column 'flux'"),
    ("0,0.5,1\n", {"columns": ["time", "duty", "pressure"], "units": {"current": "A"}},
     r"--units names 'current', which is not among the columns"),
    ("time,duty,duty,pressure\n0,0.5,0.5,1\n", {}, r"column\(s\) \['duty_cycle'\] appear more than once"),
    ("# only a comment\n", {}, r"holds no data rows"),
])
def test_column_and_unit_errors(tmp_path, text, kwargs, match):
    csv = tmp_path / "c.csv"
    csv.write_text(text)
    with pytest.raises(CsvImportError, match=match):
        import_csv(csv, tmp_path / "b", **kwargs)


def test_units_flags_and_conversion(tmp_path):
    assert parse_units(["pressure=bar,time=ms", "position=um"]) == {"pressure": "bar", "time": "ms",
                                                                    "spool_position": "um"}
    with pytest.raises(CsvImportError, match=r"unit 'furlong' for pressure: accepted are pa, kpa, bar"):
        parse_units("pressure=furlong")
    with pytest.raises(CsvImportError, match=r"expected COLUMN=UNIT"):
        parse_units("bar")
    csv = tmp_path / "u.csv"
    csv.write_text("t;duty;p;extra;flow\n0;0.5;100;x;6\n2;0.5;101;y;6\n")
    res = import_csv(csv, tmp_path / "b", columns=["time", "duty", "pressure", "-", "load_flow"],
                     units={"time": "ms", "pressure": "bar", "load_flow": "l/min"})
    b = read_bag(tmp_path / "b")
    assert res.columns == ("time", "duty_cycle", "pressure", "-", "load_flow")
    assert b["/pressure"].value.tolist() == [100e5, 101e5]
    assert b["/load_flow"].value.tolist() == pytest.approx([1e-4, 1e-4])
    assert b["/duty_cycle"].t_ns.tolist() == [0, 2_000_000]
    assert b.topic_types["/pressure"] == "sensor_msgs/msg/FluidPressure"


def test_output_bag_must_be_new_and_file_must_exist(tmp_path):
    csv = tmp_path / "u.csv"
    csv.write_text("time,duty,pressure\n0,0.5,1e6\n")
    (tmp_path / "exists").mkdir()
    with pytest.raises(BagError, match=r"exists already"):
        import_csv(csv, tmp_path / "exists")
    with pytest.raises(CsvImportError, match=r"does not exist"):
        import_csv(tmp_path / "missing.csv", tmp_path / "b")


RIG = "0,50,70.1,1.02,0.01\n1,50,120.3,1.05,-0.02\n2,90,150.2,1.9,0.2\n"


@pytest.mark.parametrize(("header", "match"), [
    # bar read as Pa: the replay printed a fit of -22 million %; now refused with the unit to add.
    ("time[ms],duty[%],pressure,current[A],position[mm]",
     r"pressure reaches at most 150.2 Pa \(read as pa\), below .*looks like bar: add --units pressure=bar"),
    # mm read as m: 0.2 m is far outside the stroke.
    ("time[ms],duty[%],pressure[bar],current[A],position",
     r"spool_position spans -0.02 .. 0.2 m \(read as m\), outside .*looks like mm: add --units position=mm"),
    ("time[ms],duty[%],pressure[bar],current[mA],position[mm]",
     r"current reaches at most 0.0019 A \(read as ma\), .*looks like a: add --units current=a"),
])
def test_a_unit_left_out_is_refused_with_a_hint(tmp_path, header, match):
    csv = tmp_path / "rig.csv"
    csv.write_text(header + "\n" + RIG)
    with pytest.raises(CsvImportError, match=match):
        import_csv(csv, tmp_path / "b")
    assert not (tmp_path / "b").exists()
    # Refused by the CLI with exit 2; --no-range-check imports it as it is.
    assert main(["import-csv", str(csv), str(tmp_path / "c")]) == 2
    assert main(["import-csv", str(csv), str(tmp_path / "d"), "--no-range-check"]) == 0


def test_in_range_units_import(tmp_path):
    csv = tmp_path / "rig.csv"
    csv.write_text("time[ms],duty[%],pressure[bar],current[A],position[mm]\n" + RIG)
    res = import_csv(csv, tmp_path / "b")
    assert res.rows == 3
    # A valve at 0 % duty holds no pressure: small pressures are not refused there.
    low = tmp_path / "low.csv"
    low.write_text("time,duty,pressure\n0,0,1.0\n0.001,0.1,300.0\n")
    assert import_csv(low, tmp_path / "low_bag").rows == 2


def test_unknown_header_names_are_listed(tmp_path, capsys):
    csv = tmp_path / "rig.csv"
    csv.write_text("Zeit,PWM,pressure[bar],I,x\n" + RIG)
    with pytest.raises(CsvImportError, match=(
            r"the header names \['Zeit', 'PWM', 'pressure\[bar\]', 'I', 'x'\] give no time and no duty "
            r"column \(a time and a duty column are needed\); understood: 'pressure\[bar\]' -> pressure; accepted names: time, duty .*--columns")):
        import_csv(csv, tmp_path / "b")
    assert main(["import-csv", str(csv), str(tmp_path / "c")]) == 2
    assert "['-', '-'" not in capsys.readouterr().err


def test_the_units_are_those_of_the_one_table():
    """A CSV header's units are the units of pcv_sim.units.KINDS (the table's factors, found by their
    names there in lower case); beside them only a data logger's words for a few."""
    from pcv_sim.io.csv_import import UNITS
    from pcv_sim.io.topics import CURRENT, DUTY_CYCLE, LOAD_FLOW, PRESSURE, SPOOL_POSITION, SUPPLY_PRESSURE
    from pcv_sim.units import KINDS

    kinds = {"time": "time", DUTY_CYCLE: "fraction", PRESSURE: "pressure", SUPPLY_PRESSURE: "pressure",
             CURRENT: "current", SPOOL_POSITION: "length", LOAD_FLOW: "flow"}
    own = {}
    for column, units in UNITS.items():
        table = {name.lower(): f for name, f in KINDS[kinds[column]].units.items()}
        assert {u: f for u, f in units.items() if u in table} == {u: table[u] for u in units if u in table}, column
        own[column] = {u for u in units if u not in table}
    assert own == {"time": {"ns"}, DUTY_CYCLE: {"1", "fraction", "percent"}, PRESSURE: set(), SUPPLY_PRESSURE: set(),
                   CURRENT: set(), SPOOL_POSITION: set(), LOAD_FLOW: {"lpm", "l/s"}}
    assert UNITS[DUTY_CYCLE]["percent"] == UNITS[DUTY_CYCLE]["%"] and UNITS[LOAD_FLOW]["lpm"] == UNITS[LOAD_FLOW]["l/min"]
