"""The command's outputs for review and CI: the HTML report (engineering units, limit band,
violation marker, every event, metadata, self-contained), a folder's index page, JUnit XML as
CI servers parse it, and CSV of every signal with units in the header."""

import csv
import re
import shutil
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import junitparser
import numpy as np
import pytest
import yaml

from pcv_sim.cli import main
from pcv_sim.rig.record import read_signals

REPO = Path(__file__).resolve().parents[2]
EXAMPLES = REPO / "examples"


def _review(tmp_path, **edits):
    data = yaml.safe_load((EXAMPLES / "review.yaml").read_text())
    data["rig"] = str(REPO / "config" / "rig.yaml")
    data.update(edits)
    shutil.copy(EXAMPLES / "steering.py", tmp_path / "steering.py")
    path = tmp_path / "review.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


@pytest.fixture(scope="module")
def failed_run(tmp_path_factory):
    """The review example with a 112 bar limit on chamber a from 1 s on (it reaches ~112.1 bar
    after the force step: a violation) and run for 2.2 s (the sensor clear at 2.6 s is dropped)."""
    tmp = tmp_path_factory.mktemp("review")
    data = yaml.safe_load((EXAMPLES / "review.yaml").read_text())
    data["assertions"].append({"name": "chamber a below 112 bar", "type": "never_above", "signal": "left.pressure",
                               "max": "112 bar", "after": 1.0})
    path = _review(tmp, assertions=data["assertions"], duration=2.2)
    status = main(["scenario", "run", str(path), "--report", str(tmp / "r.html"), "--junit", str(tmp / "j.xml"),
                   "--csv", str(tmp / "csv")])
    return tmp, status


def test_the_report_draws_limits_marks_the_violation_and_lists_every_event(failed_run):
    tmp, status = failed_run
    assert status == 1
    page = (tmp / "r.html").read_text()
    # self-contained: the plot inline, nothing fetched
    assert "data:image/png;base64," in page and not re.search(r"(src|href)=['\"]https?:", page)
    # metadata
    for key in ("pcv_sim", "seed", "config hash", "date"):
        assert f"<td>{key}</td>" in page
    # engineering units in the table: the limit in bar, the band in mm, times in ms
    row = next(r for r in page.split("<tr>") if "chamber a below 112 bar" in r)
    assert "112 bar" in row and "FAIL" in row
    # the violation: its time in the table (the worst point), marked on the plot's caption and legend
    m = re.search(r"<span class='violation' data-t='([0-9.]+)'>violated at ([0-9.]+) s</span>", row)
    assert m and 1.0 <= float(m.group(1)) <= 2.2
    band_row = next(r for r in page.split("<tr>") if "holds 1 mm under the force step" in r)
    assert "<span class='band'>band setpoint &plusmn; 1 mm over 1.300-2.200 s</span>" in band_row
    assert "<span class='limit'>upper limit 112 bar over 1.000-2.200 s</span>" in row
    # every event of the timeline (the force step, the supply ramp, the sensor fault, the setpoint ramp)
    events = re.findall(r"<tr class='event'><td>E\d+</td><td class='num'>([0-9.]+) s</td><td>(\w+)</td><td>(.*?)</td>",
                        page)
    texts = [e[2] for e in events]
    assert any(t.startswith("external force: -1000 N") for t in texts)
    assert any(t.startswith("supply left: ramp from the value before to 120 bar over 50 ms") for t in texts)
    assert any(t.startswith("fault bias on left.pressure") for t in texts)
    assert any(t.startswith("setpoint: ramp") for t in texts)
    # the dropped clear is named as a note, not run
    assert "note: timeline[3] (clear at 2.6 s) is after the run&#x27;s end (2.2 s): dropped" in page
    assert not any("clear" in t for t in texts)


def test_the_junit_file_is_what_ci_servers_parse(failed_run):
    tmp, _ = failed_run
    xml = junitparser.JUnitXml.fromfile(str(tmp / "j.xml"))
    suites = list(xml)
    assert len(suites) == 1 and suites[0].tests == 1 and suites[0].failures == 1
    case = next(iter(suites[0]))
    assert case.name == "review" and case.classname == "scenario"
    assert not case.is_passed and isinstance(case.result[0], junitparser.Failure)
    assert "chamber a below 112 bar" in case.result[0].message
    # the schema Jenkins reads: testsuite/testcase/failure, each assertion a property with its numbers
    root = ET.parse(tmp / "j.xml").getroot()
    assert root.tag == "testsuites" and [c.tag for c in root] == ["testsuite"]
    tc = root.find("testsuite/testcase")
    assert [c.tag for c in tc] == ["properties", "failure", "system-out"]
    props = {p.get("name"): p.get("value") for p in tc.find("properties")}
    assert props["assertion: chamber a below 112 bar"].startswith("FAIL; value 1.12")
    assert re.search(r"margin -[0-9.e+]+, worst at [0-9.]+ s$", props["assertion: chamber a below 112 bar"])
    assert props["assertion: chamber a below 180 bar"].startswith("pass")


def test_the_csv_has_every_signal_with_units_and_reads_back(failed_run):
    tmp, _ = failed_run
    path = tmp / "csv" / "review.csv"
    with path.open() as fh:
        rows = list(csv.reader(fh))
    header = rows[0]
    assert header[0] == "time [s]"
    for col in ("left.pressure [Pa]", "cylinder.position [m]", "cylinder.velocity [m/s]", "left.duty [-]",
                "setpoint [m]", "controller.fault_detected [-]", "left.pressure measured [Pa]"):
        assert col in header
    assert len(rows) == 1 + 2201
    back = read_signals(path)
    t, p = back["left.pressure"]
    j = header.index("left.pressure measured [Pa]")
    meas = np.array([float(r[j]) for r in rows[1:]])
    # the measured column carries the 5 bar bias from 2 s on
    assert np.allclose(meas[t >= 2.0] - p[t >= 2.0], 5e5)
    assert np.array_equal(meas[t < 2.0], p[t < 2.0])


def test_a_folder_run_writes_an_index_and_one_junit_case_per_scenario(tmp_path):
    folder = tmp_path / "scen"
    folder.mkdir()
    _review(folder)
    (folder / "bad.yaml").write_text("durration: 1.0\n")
    status = main(["scenario", "run", str(folder), "--report", str(tmp_path / "rep"), "--junit",
                   str(tmp_path / "j.xml"), "--jobs", "1"])
    assert status == 2
    index = (tmp_path / "rep" / "index.html").read_text()
    assert "<a href='review.html'>review</a>" in index and "BAD FILE" in index and "1 of 2 passed" in index
    suite = next(iter(junitparser.JUnitXml.fromfile(str(tmp_path / "j.xml"))))
    cases = {c.name: c for c in suite}
    assert set(cases) == {"review", "bad"}
    assert cases["review"].is_passed
    assert isinstance(cases["bad"].result[0], junitparser.Error)
    assert "did you mean" in cases["bad"].result[0].message


if __name__ == "__main__":
    sys.exit(pytest.main([__file__]))
