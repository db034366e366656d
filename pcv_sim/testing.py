"""pytest support: run a rig scenario with your own controller in a few lines.

    # conftest.py
    pytest_plugins = ["pcv_sim.testing"]

    # test_my_controller.py
    def test_step(rig_scenario):
        result = rig_scenario("examples/step.yaml", controller=MyController(), duration=1.0)
        # what every controller has: the position against the setpoint, the chamber pressures
        settle = next(o for o in result.outcomes if o.name == "settles within 0.5 mm")
        assert settle.passed, result.summary()
        assert result.run.signal("left.pressure").max() < 180e5

`rig_scenario(path_or_mapping, controller=None, **overrides)` loads the scenario (a YAML file,
or a mapping as the file would hold; `overrides` replace top-level keys, e.g. duration=0.5: a
shorter run drops the timeline's later events, named in `result.notes`),
runs it in lockstep with `controller` (default: the one the scenario names; a mapping
`{"ros": {"namespace": "/rig", "wait": 20}}` runs it with a ROS controller node, as the file's
`controller: {ros: ...}` would) and returns a
`ScenarioResult` (`passed`, `outcomes`, `run` with every sample). The compiled rig is shared by
the tests of a session and reset before each run.

A campaign (`pcv_sim.campaign.spec`: a scenario over a sweep, a Monte Carlo of tolerances, a
fault matrix) in a few lines:

    def test_tolerances(rig_campaign):
        result = rig_campaign("examples/tolerances.yaml", workers=2)
        assert result.pass_rate >= 0.99, result.text()
        assert result.worst_margin("settles within 0.5 mm") > 1e-4

`rig_campaign(path_or_mapping, workers=1, scheduler=None)` runs it into the test's tmp dir (a
mapping is a campaign file's content, its relative paths taken from the working directory) and
returns a `CampaignResult` (`passed`: the gate; `pass_rate`, `worst_margin(name)`, `rows`,
`summary`, `text()`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import pytest
import yaml

from pcv_sim.campaign.run import CampaignResult, run_campaign
from pcv_sim.campaign.spec import campaign_from_mapping
from pcv_sim.rig.lockstep import Controller
from pcv_sim.rig.rig import Rig
from pcv_sim.rig.scenario import ScenarioResult, load_scenario, run_scenario, scenario_from_mapping

__all__ = ["rig_campaign", "rig_scenario", "run_rig_campaign", "run_rig_scenario"]

_RIGS: dict[int, Rig] = {}


def run_rig_scenario(scenario: str | Path | Mapping[str, Any],
                     controller: Controller | Mapping[str, Any] | None = None, **overrides: Any) -> ScenarioResult:
    """Load (with `overrides`), run and check one scenario; see the module docstring."""
    if isinstance(controller, Mapping):          # {ros: {...}}: the file's controller key replaced
        overrides["controller"] = controller
        controller = None
    if isinstance(scenario, Mapping):
        data, path = dict(scenario), None
    else:
        path = Path(scenario)
        if not overrides:
            sc = load_scenario(path)
            data = None
        else:
            data = yaml.safe_load(path.read_text(encoding="utf-8"))
    if data is not None:
        data.update(overrides)
        sc = scenario_from_mapping(data, path=path)
    if controller is None and sc.ros is not None:
        return run_scenario(sc)                  # over DDS: the rig node builds its own rig
    key = hash((sc.rig, sc.seed))
    rig = _RIGS.get(key)
    if rig is None:
        rig = _RIGS[key] = Rig(sc.rig, seed=sc.seed)
    return run_scenario(sc, controller, rig=rig)


@pytest.fixture
def rig_scenario() -> Callable[..., ScenarioResult]:
    """`rig_scenario(path_or_mapping, controller=None, **overrides) -> ScenarioResult`."""
    return run_rig_scenario


def run_rig_campaign(campaign: str | Path | Mapping[str, Any], out: str | Path, *, workers: int = 1,
                     scheduler: str | None = None, report: bool = False) -> CampaignResult:
    """Run a campaign (a file, or a mapping as the file would hold) into `out`."""
    c = campaign_from_mapping(dict(campaign), Path.cwd() / "campaign.yaml") if isinstance(campaign, Mapping) \
        else campaign
    return run_campaign(c, out, workers=workers, scheduler=scheduler, report=report)


@pytest.fixture
def rig_campaign(tmp_path: Path) -> Callable[..., CampaignResult]:
    """`rig_campaign(path_or_mapping, workers=1, scheduler=None) -> CampaignResult` (in tmp_path)."""
    runs = iter(range(1_000_000))

    def run(campaign: str | Path | Mapping[str, Any], **kwargs: Any) -> CampaignResult:
        return run_rig_campaign(campaign, tmp_path / f"campaign_{next(runs)}", **kwargs)

    return run
