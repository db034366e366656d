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

import contextlib
import os
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Any

import pytest
import yaml

from pcv_sim.campaign.run import CampaignResult, run_campaign
from pcv_sim.campaign.spec import campaign_from_mapping
from pcv_sim.rig.lockstep import Controller
from pcv_sim.rig.rig import Rig
from pcv_sim.rig.scenario import ScenarioResult, load_scenario, run_scenario, scenario_from_mapping

__all__ = ["dask_cluster", "rig_campaign", "rig_scenario", "run_rig_campaign", "run_rig_scenario"]

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
        from pcv_sim.node.scenario_host import run_ros_scenario

        return run_ros_scenario(sc)              # over DDS: the rig node builds its own rig
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


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@contextlib.contextmanager
def dask_cluster(folder: Path, workers: int = 2, *, wait: float = 180.0) -> Iterator[str]:
    """A real Dask cluster on localhost: `dask scheduler` and `workers` single-threaded `dask
    worker` processes (cwd and logs `scheduler.log`, `worker<k>.log` in `folder`); yields the
    scheduler's address, and stops them all after. RuntimeError with the scheduler's and the
    first worker's log when the cluster is not up within `wait` s."""
    import distributed

    client_type: Any = distributed.Client        # distributed carries no annotations
    address = f"tcp://127.0.0.1:{_free_port()}"
    env = {k: v for k, v in os.environ.items() if k != "_ROS_WHEELS_BOOTSTRAP_COMPLETE"}
    procs: list[subprocess.Popen[bytes]] = []
    with contextlib.ExitStack() as logs:
        def start(name: str, *args: str) -> None:
            log = logs.enter_context((folder / f"{name}.log").open("w"))
            procs.append(subprocess.Popen([sys.executable, "-m", "dask", *args], stdout=log, stderr=subprocess.STDOUT,
                                          env=env, cwd=folder))

        try:
            start("scheduler", "scheduler", "--host", "127.0.0.1", "--port", address.rsplit(":", 1)[1],
                  "--dashboard-address", ":0")
            for k in range(workers):
                start(f"worker{k}", "worker", address, "--nworkers", "1", "--nthreads", "1", "--host", "127.0.0.1",
                      "--dashboard-address", ":0", "--name", f"w{k}")
            deadline = time.monotonic() + wait
            while True:
                try:
                    with client_type(address, timeout=10) as c:
                        c.wait_for_workers(workers, timeout=max(1.0, deadline - time.monotonic()))
                    break
                except (OSError, TimeoutError):
                    if time.monotonic() > deadline or any(p.poll() is not None for p in procs):
                        text = "\n".join((folder / f).read_text() for f in ("scheduler.log", "worker0.log"))
                        raise RuntimeError(f"the Dask cluster did not start:\n{text}") from None
                    time.sleep(1.0)
            yield address
        finally:
            for p in reversed(procs):
                p.terminate()
            for p in procs:
                try:
                    p.wait(timeout=20)
                except subprocess.TimeoutExpired:
                    p.kill()
                    p.wait()
