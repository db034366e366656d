"""Gaps in a recording (issue 11, item 4): a device that skipped steps under load is reported,
and the replay does not compare across the gaps.

The bag is made by the emulator's own device at 1 kHz output, with two 55 ms skips placed in
the transients of duty steps (`ValveDevice.skip`: the state stands still, time jumps, as when
the emulator skips steps). Replaying it on the same device is exact everywhere except after the
skips."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from pcv_sim.cli import main
from pcv_sim.device.valve import VALVE, ValveDevice
from pcv_sim.io.bag import FLOAT64, FLUID_PRESSURE, BagWriter
from pcv_sim.params import load_params
from pcv_sim.replay import check_thresholds, load_recording, replay
from pcv_sim.replay.report import render_markdown, render_text

T0 = 1_704_067_200 * 1_000_000_000
DT_NS = 100_000                        # the device's 0.1 ms
EVERY = 10                             # an output sample per 1 ms
PLAN = {0: 0.5, 1000: 0.7, 6000: 0.4}  # bag step -> duty
SKIPS = {1050: 550, 6050: 550}         # bag step -> steps skipped (55 ms), 5 ms into each step
N = 14000                              # 1.4 s


def _device_bag(path: Path, skips: dict[int, int]) -> Path:
    dev = ValveDevice(load_params(), safe_duty=0.5, watchdog_timeout=0.0)
    topics = {"/duty_cycle": FLOAT64, "/pressure": FLUID_PRESSURE, "/spool_position": FLOAT64}
    with BagWriter(path, topics=topics, flush_thread=False, clock=lambda: 0.0) as w:
        k = 0
        while k < N:
            if k in skips:                 # the device stands still while time goes on
                due = [s for s in PLAN if k <= s < k + skips[k]]
                dev.skip(skips[k])
                k += skips[k]
                for s in due:
                    dev.set_duty(VALVE, PLAN[s])
                    w.write_float64("/duty_cycle", T0 + k * DT_NS, PLAN[s])
            if k in PLAN:
                dev.set_duty(VALVE, PLAN[k])
                w.write_float64("/duty_cycle", T0 + k * DT_NS, PLAN[k])
            if k % EVERY == 0:
                _, x, _, p = dev.sim.x.tolist()
                w.write_fluid_pressure("/pressure", T0 + k * DT_NS, p, 0.0)
                w.write_float64("/spool_position", T0 + k * DT_NS, x)
            dev.advance_to(k + 1)
            k += 1
    return path


@pytest.fixture(scope="module")
def gappy(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _device_bag(tmp_path_factory.mktemp("gaps") / "skipped", SKIPS)


def test_gaps_are_found(gappy: Path) -> None:
    rec = load_recording(gappy)
    assert [(g.start_ns / 1e6, g.end_ns / 1e6, g.missing) for g in rec.gaps] == [
        (104.0, 160.0, 55), (604.0, 660.0, 55)]
    assert rec.gaps[0].roles == ("pressure", "spool_position")


def test_no_comparison_across_gaps(gappy: Path) -> None:
    params = load_params()
    rec = load_recording(gappy)
    r = replay(rec, params, model="simplified", solver="stepper")
    p = r.signals["pressure"]
    # Left out: each gap's first sample after it and the next 300 ms (300 samples at 1 kHz).
    assert p.excluded == 2 * 301 and p.samples == len(rec.measured["pressure"]) - 2 * 301
    # Compared: the same device, exact outside the skips; after 300 ms the model and the device
    # agree to within 0.05 bar (the re-synchronisation measured in bench/replay_gaps.py).
    assert r.scalar_metrics()["pressure_max_error_bar"] < 0.05
    assert r.scalar_metrics()["gaps"] == 2 and r.scalar_metrics()["gap_max_ms"] == pytest.approx(56.0)
    # Both steps had a skip in their transient: not analysed, and said so.
    assert r.steps == ()
    assert sum("is not analysed: a gap" in n for n in r.notes) == 2
    # Compared across the gaps (no re-synchronisation allowance), the skips cost tens of bar.
    r0 = replay(rec, params, model="simplified", solver="stepper", resync=0.0)
    assert r0.signals["pressure"].excluded == 2
    assert r0.scalar_metrics()["pressure_max_error_bar"] > 10.0
    assert check_thresholds(r, {"gaps": 0})[0].key == "gaps"


def test_gaps_in_text_json_and_report(gappy: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["replay", str(gappy), "--model", "simplified", "--solver", "stepper"]
    assert main([*argv, "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert [round(g["duration_s"] * 1e3, 3) for g in data["gaps"]] == [56.0, 56.0]
    assert data["gaps"][0]["not_compared_until_s"] == pytest.approx(0.16 + 0.3)
    assert data["signals"]["pressure"]["excluded_samples"] == 602 and data["resync_s"] == 0.3
    assert data["metrics"]["gaps"] == 2
    assert main([*argv, "--resync-ms", "100", "--report", str(tmp_path / "r.md")]) == 0
    captured = capsys.readouterr()
    text = captured.out
    assert "warning: 2 gap(s) in the recorded outputs (longest 56.0 ms); not compared until 100 ms" in captured.err
    assert "gaps in the measured outputs: 2 (56.0-56.0 ms, 112.0 ms in all)" in text
    assert "gap 1: 0.1040 -> 0.1600 s (56.0 ms, ~55 samples missing), compared again from 0.2600 s" in text
    report = (tmp_path / "r.md").read_text()
    assert "## Gaps (skipped intervals, not compared)" in report
    assert "| 2 | 0.6040 | 0.6600 | 56.0 | 55 | 0.7600 | pressure, spool_position |" in report
    assert main([*argv, "--fail-above", "gaps=0"]) == 1
    assert main([*argv, "--resync-ms", "-1"]) == 2
    assert "--resync-ms -1: accepted is a finite number >= 0" in capsys.readouterr().err


def test_a_bag_without_gaps_says_none(tmp_path: Path) -> None:
    params = load_params()
    r = replay(load_recording(_device_bag(tmp_path / "b", {})), params, model="simplified", solver="stepper")
    assert r.gaps == () and all(s.excluded == 0 for s in r.signals.values())
    assert r.scalar_metrics()["pressure_max_error_bar"] == 0.0 and len(r.steps) == 2
    assert "gaps in the measured outputs" not in render_text(r)
    assert "- **gaps in the measured outputs**: none" in render_markdown(r, {}, [], tmp_path)
    assert np.isfinite(r.scalar_metrics()["pressure_fit_percent"])
