"""A campaign on a real Dask cluster on localhost (`dask scheduler` + two `dask worker`
processes) gives the same table as the local run, byte for byte."""
import functools
import socket

from pcv_sim.campaign import executors
from pcv_sim.cli import main

from .test_campaign import MONTE_CARLO


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_dask_cluster_gives_the_local_table(dask_cluster, write_campaign, tmp_path, capsys):
    path = write_campaign({**MONTE_CARLO, "sweep": {"parameters": {"scenario.timeline[0].force": [0.0, 300.0]}}})
    assert main(["campaign", "run", str(path), "--out", str(tmp_path / "local"), "--workers", "1", "--json"]) == 0
    assert main(["campaign", "run", str(path), "--out", str(tmp_path / "dask"), "--scheduler", dask_cluster,
                 "--json"]) == 0
    capsys.readouterr()
    local = (tmp_path / "local" / "results.csv").read_bytes()
    assert local == (tmp_path / "dask" / "results.csv").read_bytes()
    assert local.count(b"\n") == 7            # a header and six variants


def test_no_scheduler_is_a_usage_error(write_campaign, tmp_path, capsys, monkeypatch):
    """Nothing listens at the address: the connection is refused until the client's timeout (10 s in
    the command; 1 s here, the same error sooner), a usage error that says so."""
    monkeypatch.setattr("pcv_sim.campaign.run.run_dask", functools.partial(executors.run_dask, timeout=1.0))
    path = write_campaign(MONTE_CARLO)
    port = free_port()
    assert main(["campaign", "run", str(path), "--out", str(tmp_path / "o"), "--scheduler",
                 f"tcp://127.0.0.1:{port}"]) == 2
    assert "no Dask scheduler answered" in capsys.readouterr().err
