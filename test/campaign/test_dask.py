"""A campaign on a real Dask cluster on localhost (`dask scheduler` + two `dask worker`
processes) gives the same table as the local run, byte for byte."""
import socket
import subprocess
import sys
import time

import pytest

from pcv_sim.cli import main

from .conftest import child_env
from .test_campaign import MONTE_CARLO


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def dask_cluster(tmp_path):
    """tcp://127.0.0.1:PORT of a scheduler with two single-threaded workers; all stopped after."""
    port = free_port()
    address = f"tcp://127.0.0.1:{port}"
    env = child_env()
    procs = []
    logs = []

    def start(name, *args):
        log = (tmp_path / f"{name}.log").open("w")
        logs.append(log)
        procs.append(subprocess.Popen([sys.executable, "-m", "dask", *args], stdout=log, stderr=subprocess.STDOUT,
                                      env=env, cwd=tmp_path))

    try:
        start("scheduler", "scheduler", "--host", "127.0.0.1", "--port", str(port), "--dashboard-address", ":0")
        for k in range(2):
            start(f"worker{k}", "worker", address, "--nworkers", "1", "--nthreads", "1", "--host", "127.0.0.1",
                  "--dashboard-address", ":0", "--name", f"w{k}")
        from distributed import Client

        deadline = time.monotonic() + 180
        while True:
            try:
                with Client(address, timeout=10) as c:
                    c.wait_for_workers(2, timeout=max(1.0, deadline - time.monotonic()))
                break
            except (OSError, TimeoutError):
                if time.monotonic() > deadline or any(p.poll() is not None for p in procs):
                    logs_text = "\n".join((tmp_path / f).read_text() for f in ("scheduler.log", "worker0.log"))
                    pytest.fail(f"the Dask cluster did not start:\n{logs_text}")
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
        for log in logs:
            log.close()


def test_dask_cluster_gives_the_local_table(dask_cluster, write_campaign, tmp_path, capsys):
    path = write_campaign({**MONTE_CARLO, "sweep": {"parameters": {"scenario.timeline[0].force": [0.0, 300.0]}}})
    assert main(["campaign", "run", str(path), "--out", str(tmp_path / "local"), "--workers", "1", "--json"]) == 0
    assert main(["campaign", "run", str(path), "--out", str(tmp_path / "dask"), "--scheduler", dask_cluster,
                 "--json"]) == 0
    capsys.readouterr()
    local = (tmp_path / "local" / "results.csv").read_bytes()
    assert local == (tmp_path / "dask" / "results.csv").read_bytes()
    assert local.count(b"\n") == 7            # a header and six variants


def test_no_scheduler_is_a_usage_error(write_campaign, tmp_path, capsys):
    path = write_campaign(MONTE_CARLO)
    port = free_port()
    assert main(["campaign", "run", str(path), "--out", str(tmp_path / "o"), "--scheduler",
                 f"tcp://127.0.0.1:{port}"]) == 2
    assert "no Dask scheduler answered" in capsys.readouterr().err
