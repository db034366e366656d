"""What a scenario run reports about its speed: the run's real-time factor apart from the time to
load the files and compile (or load) the model's kernels before it."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from pcv_sim import jit
from pcv_sim.cli import main
from pcv_sim.rig import Rig
from pcv_sim.rig.params import load_rig

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


@pytest.mark.skipif(not jit.enabled(), reason="plain Python (PCV_SIM_JIT=0): nothing is compiled")
def test_a_new_rig_has_compiled_every_kernel_the_lockstep_calls() -> None:
    rig = Rig(load_rig(None))
    sim = rig.sim
    for fn in (sim._outputs, sim._advance, sim._advance_sample):
        assert fn.signatures, f"{fn} would compile in the first run and count as running"
    # ...and the warm-up left the rig at rest at t = 0.
    assert rig.steps == 0
    again = Rig(load_rig(None))
    assert np.array_equal(rig.sim.x, again.sim.x)


def test_scenario_reports_the_setup_apart_from_the_run(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    scenario = EXAMPLES / "step.yaml"
    assert main(["scenario", "run", str(scenario), "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    assert r["setup_time_s"] > 0.0 and r["wall_time_s"] > 0.0
    # The factor is the run's alone (simulated duration / the run's wall time).
    duration = r["real_time_factor"] * r["wall_time_s"]
    assert duration == pytest.approx(1.5, rel=1e-9), r
    assert main(["scenario", "run", str(scenario)]) == 0
    line = capsys.readouterr().out.splitlines()[0]
    assert "s for the run; " in line and "s before it to load the files and compile or load the model)" in line
