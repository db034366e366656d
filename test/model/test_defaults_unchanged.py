"""The shipped configuration's outputs, bit for bit: the valve's options beyond the paper's bench
(coil heating, oil temperature, core-spool separation) are off by default and must leave every
number of the paper's model as it was.

`data/default_outputs.json` holds the outputs (as float.hex) of short duty-step runs of both
models, a run through the fall-rate limiter, two valves on a piston, and the analysis model's
derivatives, made by this file's `_runs()` with the model as the paper has it. Regenerate it
only for a change of the paper's model itself:
`.venv-kilted/bin/python test/model/test_defaults_unchanged.py --write`.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from pcv_sim import jit
from pcv_sim.model.valve import ValveModel
from pcv_sim.params import default_params, replace_param
from pcv_sim.plant.mass_spring import mass_spring
from pcv_sim.simulation.duty import DutyProfile
from pcv_sim.simulation.rest import rest_state
from pcv_sim.simulation.simulator import Simulator
from pcv_sim.simulation.system import compose
from pcv_sim.simulation.valve import valve_system

GOLDEN = Path(__file__).resolve().parent / "data" / "default_outputs.json"
STEPS = DutyProfile((0.0, 0.02, 0.06, 0.10), (0.5, 0.9, 0.3, 0.7))


def _stepper(kind: str, limit: float | None = None) -> list[list[float]]:
    from offline_valve import at_rest, run_profile  # the emulator's device (test/offline_valve.py)

    params = default_params()
    if limit is not None:
        params = replace_param(params, "command.duty_fall_rate_limit", limit)
    tr = run_profile(at_rest(params, 0.5, kind=kind), STEPS, 0.14, sample_every=10)
    return [tr.t.tolist(), tr.duty.tolist(), tr.current.tolist(), tr.pressure.tolist(),
            tr.spool_position.tolist()]


def _composite() -> list[list[float]]:
    params = default_params()
    plant = compose([valve_system(params, "simplified", "left"), valve_system(params, "simplified", "right"),
                     mass_spring("piston", area=1e-4, mass=1.0, stiffness=2e5, damping=2000.0)],
                    [("left.pressure", "piston.pressure_a"), ("right.pressure", "piston.pressure_b"),
                     ("piston.flow_a", "left.load_flow"), ("piston.flow_b", "right.load_flow")])
    rest = rest_state(params, "simplified", 0.5)
    sim = Simulator(plant, 1e-4, "rk2")
    sim.x[:] = np.concatenate([rest.state, rest.state, [0.0, 0.0]])
    sim.W[:] = (rest.current, rest.current, 0.0)
    sim.u[:] = (0.5, 200e5, params.circuit.load_volume, 0.5, 200e5, params.circuit.load_volume)
    out = []
    for left, right in ((0.9, 0.4), (0.4, 0.9), (0.7, 0.5)):
        sim.u[0], sim.u[3] = left, right
        sim.advance(200)
        out.append([*sim.x.tolist(), *sim.outputs().tolist()])
    return out


def _analysis() -> list[list[float]]:
    out = []
    for kind in ("simplified", "full"):
        m = ValveModel(default_params(), kind)  # type: ignore[arg-type]
        state = m.initial_state(0.7, 1e-4, 110e5)
        for duty, q in ((0.7, 0.0), (0.3, 1e-5), (1.0, -2e-5)):
            dx, i = m.derivatives(0.0, state, duty, q, 200e5, 1.5)
            out.append([*dx, i])
    return out


def _runs() -> dict[str, list[list[float]]]:
    return {"simplified": _stepper("simplified"), "full": _stepper("full"),
            "simplified_rate_limited": _stepper("simplified", 2.0), "composite": _composite(),
            "analysis": _analysis()}


def _hex(runs: dict[str, list[list[float]]]) -> dict[str, list[list[str]]]:
    return {k: [[float(v).hex() for v in row] for row in rows] for k, rows in runs.items()}


@pytest.mark.skipif(not jit.enabled(), reason="the golden outputs are the compiled kernel's (plain Python "
                    "agrees to rounding only: test_jit)")
def test_default_outputs_bit_for_bit():
    golden = json.loads(GOLDEN.read_text())
    fresh = _hex(_runs())
    assert set(fresh) == set(golden)
    for name, rows in golden.items():
        assert len(fresh[name]) == len(rows), name
        for k, (a, b) in enumerate(zip(fresh[name], rows)):
            assert a == b, (name, k, [float.fromhex(v) for v in a], [float.fromhex(v) for v in b])


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))      # test/, as pytest has it
    if "--write" in sys.argv:
        GOLDEN.write_text(json.dumps(_hex(_runs()), indent=0) + "\n")
        print(f"wrote {GOLDEN}")
