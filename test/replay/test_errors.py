"""Errors users meet, each with a clear message, and nothing skipped silently."""

from __future__ import annotations

import json
import shutil

import pytest

from pcv_sim.cli import main
from pcv_sim.errors import BagError
from pcv_sim.params import DEFAULT_CONFIG
from pcv_sim.replay import ReplayError, load_recording, replay

from .conftest import BAGS
from .helpers import write_bag

DEVICE = {"duty": "/duty_cycle", "pressure": "/pressure", "current": "/current", "position": "/spool_position"}


def test_path_that_is_not_a_bag(tmp_path, capsys):
    with pytest.raises(BagError, match=r"does not exist; expected a rosbag2 directory"):
        load_recording(tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    with pytest.raises(BagError, match=r"is not a bag: it contains no readable .mcap file"):
        load_recording(tmp_path / "empty")
    text = tmp_path / "run.csv"
    text.write_text("time,duty,pressure\n0,0.5,1e6\n")
    assert main(["replay", str(text)]) == 2
    assert "is not an MCAP file" in capsys.readouterr().err


def test_truncated_file_is_replayed_in_part_and_said_so(tmp_path, params, capsys):
    bag = shutil.copytree(BAGS / "pcv_step_levels", tmp_path / "cut")
    (mcap,) = bag.glob("*.mcap")
    data = mcap.read_bytes()
    mcap.write_bytes(data[: len(data) // 2])
    rec = load_recording(bag)
    assert not rec.closed_cleanly
    assert any("not closed properly" in w for w in rec.warnings)
    r = replay(rec, params, model="simplified")
    assert 1.0 < r.duration_s < 3.5  # the complete chunks in the first half only (of 4.743 s)
    assert r.scalar_metrics()["pressure_fit_percent"] > 99.99
    report = tmp_path / "cut.md"
    # A gate on a damaged file fails (exit 1), however good its readable part fits, saying what is
    # wrong and how to accept it; the report is written all the same.
    assert main(["replay", str(bag), "--model", "simplified", "--report", str(report)]) == 1
    captured = capsys.readouterr()
    assert (f"pcv-sim replay: error: {bag} was not closed properly: its readable part ({r.duration_s:.3f} s) is "
            f"replayed but the run fails (exit 1); --allow-unclosed accepts a partial recording") in captured.err
    assert f"warning: {mcap.name}: not closed properly (" in captured.err      # what was lost and where
    assert "FAILED: closed_cleanly = 0 < 1" in captured.out
    md = report.read_text()
    assert "**bag closed properly**: NO" in md
    assert "## Warnings from the bag reader" in md and "not closed properly" in md
    assert main(["replay", str(bag), "--model", "simplified", "--json"]) == 1
    doc = json.loads(capsys.readouterr().out)
    assert doc["closed_cleanly"] is False and doc["warnings"]
    assert doc["thresholds"]["failed"] == ["closed_cleanly = 0 < 1"]
    # Accepted by name: the readable part replays, exit 0 unless a limit is crossed.
    assert main(["replay", str(bag), "--model", "simplified", "--allow-unclosed"]) == 0
    err = capsys.readouterr().err
    assert "was not closed properly" in err and "accepted by --allow-unclosed" in err
    assert main(["replay", str(bag), "--model", "simplified", "--allow-unclosed",
                 "--fail-below", "pressure_fit_percent=100.1"]) == 1
    assert "FAILED: pressure_fit_percent" in capsys.readouterr().out
    # A bag closed properly is not touched by the rule.
    assert main(["replay", str(BAGS / "pcv_step_levels"), "--model", "simplified", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["thresholds"]["failed"] == []


def test_bag_not_closed_properly(tmp_path, params):
    bag = write_bag(tmp_path / "open", DEVICE, until_s=0.4, close=False)
    rec = load_recording(bag)
    assert not rec.closed_cleanly
    assert any("not closed properly" in w for w in rec.warnings)
    assert replay(rec, params, model="simplified").signals["pressure"].samples > 300


def test_bag_of_a_writer_that_did_not_finish_fails_unless_allowed(tmp_path, capsys):
    bag = write_bag(tmp_path / "open", DEVICE, until_s=0.4, close=False)
    assert main(["replay", str(bag), "--model", "simplified"]) == 1
    assert "--allow-unclosed accepts a partial recording" in capsys.readouterr().err
    assert main(["replay", str(bag), "--model", "simplified", "--allow-unclosed"]) == 0


def test_unknown_message_type(tmp_path, capsys):
    bag = write_bag(tmp_path / "temp", {"duty": "/duty_cycle", "pressure": "/pressure"}, until_s=0.2,
                    types={"pressure": "sensor_msgs/msg/Temperature"})
    with pytest.raises(ReplayError, match=r"pressure: topic '/pressure' has message type "
                                          r"'sensor_msgs/msg/Temperature', which replay cannot read; accepted "
                                          r"types: std_msgs/msg/Float64, sensor_msgs/msg/FluidPressure"):
        load_recording(bag)
    assert main(["replay", str(bag)]) == 2
    assert "cannot read" in capsys.readouterr().err


def test_time_going_backwards_says_where(tmp_path):
    def swap(sig, rows):
        if sig == "pressure":
            rows[100], rows[101] = rows[101], rows[100]
        return rows

    bag = write_bag(tmp_path / "back", DEVICE, until_s=0.3, mangle=swap)
    with pytest.raises(ReplayError, match=r"pressure: time goes backwards on /pressure at message 101 \(0-based, in bag order\): "
                                          r"1704067200101000000 ns -> 1704067200100000000 ns \(-1\.000000 ms\); 1 such place"):
        load_recording(bag)


def test_duty_in_percent_is_refused(tmp_path):
    def percent(sig, rows):
        return [(t, v * 100 if sig == "duty" else v) for t, v in rows]

    bag = write_bag(tmp_path / "pct", DEVICE, until_s=0.3, mangle=percent)
    with pytest.raises(ReplayError, match=r"outside 0\.\.1, first 30 at message 0 \(percent\?"):
        load_recording(bag)


def test_non_finite_values(tmp_path):
    def nan(sig, rows):
        if sig == "current":
            rows[7] = (rows[7][0], float("nan"))
        return rows

    bag = write_bag(tmp_path / "nan", DEVICE, until_s=0.3, mangle=nan)
    with pytest.raises(ReplayError, match=r"current: 1 non-finite value\(s\) on /current, first at message 7"):
        load_recording(bag)


def test_samples_before_the_first_command_are_reported(tmp_path, params):
    def late_duty(sig, rows):
        return rows[:1] if sig != "duty" else [(rows[0][0] + 5000000, rows[0][1]), *rows[1:]]

    bag = write_bag(tmp_path / "late", {"duty": "/duty_cycle", "pressure": "/pressure"}, until_s=0.3)
    rec = load_recording(bag)
    assert not any("before the first duty command" in n for n in rec.notes)
    bag2 = write_bag(tmp_path / "late2", {"duty": "/duty_cycle", "pressure": "/pressure"}, until_s=0.3,
                     mangle=lambda s, r: r if s != "duty" else [(r[0][0] + 5000000, r[0][1]), *r[1:]])
    rec2 = load_recording(bag2)
    assert any("5 sample(s) before the first duty command not compared" in n for n in rec2.notes)


def test_thresholds_and_options(tmp_path, capsys):
    bag = str(BAGS / "pcv_step_levels")
    assert main(["replay", bag, "--model", "simplified", "--fail-above", "pressure_rmse_psi=1"]) == 2
    err = capsys.readouterr().err
    assert "unknown metric 'pressure_rmse_psi' for --fail-above; this bag has: closed_cleanly, current_fit_percent" in err
    assert main(["replay", bag, "--fail-above", "pressure_rmse_bar"]) == 2
    assert "expected METRIC=NUMBER" in capsys.readouterr().err
    assert main(["replay", bag, "--report", "out.pdf"]) == 2
    assert "must end in .md or .html" in capsys.readouterr().err
    limited = tmp_path / "limited.yaml"
    limited.write_text(DEFAULT_CONFIG.read_text().replace("duty_fall_rate_limit: null", "duty_fall_rate_limit: 2.0"))
    assert main(["--config", str(limited), "replay", bag, "--solver", "radau"]) == 2
    assert "only the stepper applies it" in capsys.readouterr().err


def test_html_report_and_plot_dir(tmp_path, capsys):
    bag = write_bag(tmp_path / "short", DEVICE, until_s=0.8)
    report = tmp_path / "r.html"
    assert main(["replay", str(bag), "--model", "simplified", "--report", str(report),
                 "--plot-dir", str(tmp_path / "png"), "--fail-below", "pressure_fit_percent=99.9"]) == 0
    page = report.read_text()
    assert page.count("<img") == 4 and "data:image/png;base64," in page
    assert "NRMSE fit %" in page and "0.3 -&gt; 0.4" in page
    assert sorted(p.name for p in (tmp_path / "png").iterdir()) == [
        "short_current.png", "short_duty.png", "short_pressure.png", "short_spool_position.png"]
