"""A short scenario (0.3 s) and campaign files over it, written into the test's tmp dir; one real
Dask cluster for them all."""
import os
from pathlib import Path

import pytest
import yaml

REPO = Path(__file__).resolve().parents[2]

SCENARIO = {
    "name": "short",
    "rig": str(REPO / "config" / "rig.yaml"),
    "duration": 0.3,
    "controller": "pcv_sim.control.steering:PositionController",
    "setpoint": [{"t": 0.0, "value": 0.0}, {"t": 0.05, "value": 0.01}],
    "timeline": [{"t": 0.1, "force": 200.0}],
    "assertions": [
        {"name": "tracks", "type": "max_error", "signal": "cylinder.position", "reference": "setpoint",
         "max": 2.5e-3, "after": 0.2},
        {"name": "chamber a", "type": "never_above", "signal": "left.pressure", "max": 1.8e7},
        {"name": "no alarm", "type": "never_above", "signal": "controller.fault_detected", "max": 0.0},
    ],
}


def child_env(**extra):
    env = {k: v for k, v in os.environ.items() if k != '_ROS_WHEELS_BOOTSTRAP_COMPLETE'}
    env.update(extra)
    return env


@pytest.fixture(scope="package")
def dask_cluster(tmp_path_factory):
    """tcp://127.0.0.1:PORT of a scheduler with two single-threaded workers (real `dask scheduler` and
    `dask worker` processes), shared by the campaign tests: each only submits a campaign to it, and
    its start and stop (the workers' nannies close on SIGTERM) take ~5-10 s. Stopped at the end."""
    from pcv_sim import testing

    try:
        with testing.dask_cluster(tmp_path_factory.mktemp("dask"), 2) as address:
            yield address
    except RuntimeError as err:
        pytest.fail(str(err))


@pytest.fixture
def write_campaign(tmp_path):
    """`write_campaign(campaign_mapping, scenario=SCENARIO) -> path`: the scenario as short.yaml
    beside the campaign file."""

    def write(campaign, scenario=None, name="campaign.yaml"):
        (tmp_path / "short.yaml").write_text(yaml.safe_dump(scenario or SCENARIO, sort_keys=False))
        path = tmp_path / name
        path.write_text(yaml.safe_dump({"scenario": "short.yaml", **campaign}, sort_keys=False))
        return path

    return write
