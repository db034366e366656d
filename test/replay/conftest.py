"""Fixtures for the replay tests: the committed reference bags, their full-model replays (once
per session), and a regeneration of the bags started in the background at the first replay test
so that it runs on the second core while the other tests run (test_reproducible.py waits)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest

from pcv_sim.params import load_params
from pcv_sim.replay import load_recording, replay

REPO = Path(__file__).resolve().parents[2]
BAGS = REPO / "bags"
REFERENCE_BAGS = ("pcv_step_levels", "pcv_step_amplitudes")


@pytest.fixture(scope="session", autouse=True)
def regeneration(tmp_path_factory: pytest.TempPathFactory):
    """`pcv-sim reference-bags --out TMP` running in a child process."""
    out = tmp_path_factory.mktemp("regenerated")
    env = {k: v for k, v in os.environ.items() if k != "_ROS_WHEELS_BOOTSTRAP_COMPLETE"}
    proc = subprocess.Popen(
        [sys.executable, "-m", "pcv_sim", "reference-bags", "--out", str(out)],
        cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )
    handle = SimpleNamespace(out=out, proc=proc)
    yield handle
    if proc.poll() is None:
        proc.kill()
        proc.wait()


@pytest.fixture(scope="session")
def params():
    return load_params()


@pytest.fixture(scope="session")
def full_results(params):
    """Full-model replays of every reference bag on the stiff reference solver (Radau), the way
    the bags were made (the slowest part: ~10 s together)."""
    return {name: replay(load_recording(BAGS / name), params, model="full", solver="radau")
            for name in REFERENCE_BAGS}


@pytest.fixture(scope="session")
def full_stepper_results(params):
    """Full-model replays on the emulator's engine (the default): exponential Heun at 0.1 ms."""
    return {name: replay(load_recording(BAGS / name), params, model="full") for name in REFERENCE_BAGS}


@pytest.fixture(scope="session")
def simplified_results(params):
    return {name: replay(load_recording(BAGS / name), params, model="simplified") for name in REFERENCE_BAGS}
