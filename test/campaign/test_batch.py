"""Campaigns in batches (`--batch B`: B variants stepped in one compiled call per control period,
pcv_sim.rig.batch): the same table as each variant alone, byte for byte, with faults at different
onsets, a variant that runs away and one whose controller raises inside a batch."""
import pytest

from pcv_sim.cli import main

from .conftest import SCENARIO

#: the short scenario with a coil fault whose onset the campaigns vary
FAULTED = {**SCENARIO, "timeline": [*SCENARIO["timeline"],
                                    {"t": 0.15, "fault": "coil_short", "target": "left", "resistance_factor": 0.5}]}

SWEEP = {"sweep": {"combine": "zip", "parameters": {
    "scenario.timeline[1].t": [0.06, 0.12, 0.2, 0.25, 0.08],
    # 0.1 kg: a piston too light for the explicit step: that variant runs away after the setpoint's step
    "cylinder.mass": [50.0, 0.1, 40.0, 60.0, 55.0]}}, "worst": 0}
MONTE_CARLO = {"monte_carlo": {"samples": 5, "seed": 11, "parameters": {
    "valves.spool.spring_preload": {"distribution": "normal", "sd": "2.5%", "truncate": "5%"},
    "scenario.timeline[1].t": {"distribution": "uniform", "low": 0.05, "high": 0.28}}}, "worst": 0}


def run(path, out, *extra):
    return main(["campaign", "run", str(path), "--out", str(out), "--json", "--workers", "1", *extra])


def batches_seen(monkeypatch):
    """Each batch the campaign ran: (copies, the periods taken together / alone / taken again)."""
    from pcv_sim.campaign import runner

    seen = []
    real = runner.run_lockstep_batch

    def counted(rigs, *args, **kwargs):
        counts = {}
        out = real(rigs, *args, counts=counts, **kwargs)
        seen.append((len(rigs), counts))
        return out

    monkeypatch.setattr(runner, "run_lockstep_batch", counted)
    return seen


@pytest.mark.parametrize("body", [SWEEP, MONTE_CARLO], ids=["sweep", "monte_carlo"])
def test_a_batched_campaign_gives_the_table_of_each_variant_alone(body, write_campaign, tmp_path, capsys,
                                                                  monkeypatch):
    path = write_campaign(body, FAULTED)
    alone = run(path, tmp_path / "alone", "--batch", "1")
    seen = batches_seen(monkeypatch)
    assert run(path, tmp_path / "batched", "--batch", "2") == alone
    capsys.readouterr()
    table = (tmp_path / "alone" / "results.csv").read_text()
    assert (tmp_path / "batched" / "results.csv").read_text() == table
    # two batches of two, the fifth variant alone; most periods of each batch in one call
    n = round(FAULTED["duration"] / 1e-3)
    assert [copies for copies, _ in seen] == [2, 2], seen
    assert seen[1][1]["together"] > 0.8 * n, seen
    if body is SWEEP:
        rows = table.splitlines()
        assert rows[2].startswith("1,error,") and "model step failed" in rows[2]     # the 0.1 kg piston
        # it ran away inside the batch's call: that period taken again alone, its partner alone from there
        assert seen[0][1]["retaken"] == 1 and seen[0][1]["together"] >= 1, seen
        assert all(",error," not in r for r in rows[1:] if not r.startswith("1,"))
    else:
        assert seen[0][1]["together"] > 0.8 * n, seen


def test_a_controller_that_raises_inside_a_batch_is_a_failed_variant(write_campaign, tmp_path, capsys, monkeypatch,
                                                                       fragile_controller):
    # fragile_controller: fragile.py beside the campaign
    scenario = {**FAULTED, "controller": "fragile:Fragile", "controller_params": {"fail_at": -1.0}}
    path = write_campaign({"sweep": {"parameters": {"scenario.controller_params.fail_at": [-1.0, 0.15, -1.0, -1.0]}},
                           "worst": 0}, scenario)
    alone = run(path, tmp_path / "alone", "--batch", "1")
    seen = batches_seen(monkeypatch)
    assert run(path, tmp_path / "batched", "--batch", "2") == alone
    capsys.readouterr()
    table = (tmp_path / "batched" / "results.csv").read_text()
    assert table == (tmp_path / "alone" / "results.csv").read_text()
    assert "ZeroDivisionError" in table.splitlines()[2] and len(seen) == 2


def test_a_negative_batch_exits_2_naming_what_is_accepted(write_campaign, tmp_path, capsys):
    path = write_campaign({"sweep": {"parameters": {"scenario.timeline[0].force": [0.0, 100.0]}}})
    assert run(path, tmp_path / "out", "--batch", "-1") == 2
    err = capsys.readouterr().err
    assert "--batch -1" in err and "0: auto" in err
    assert not (tmp_path / "out").exists()


def test_dask_tasks_in_batches_give_the_table_of_each_variant_alone(write_campaign, tmp_path, capsys,
                                                                   dask_cluster):
    """The Dask workers (real `dask scheduler` and `dask worker` processes) run their chunks in
    batches of two: the table of the variants alone, byte for byte."""
    path = write_campaign(MONTE_CARLO, FAULTED)
    alone = run(path, tmp_path / "alone", "--batch", "1")
    assert main(["campaign", "run", str(path), "--out", str(tmp_path / "batched"), "--json",
                 "--scheduler", dask_cluster, "--batch", "2"]) == alone
    capsys.readouterr()
    assert (tmp_path / "batched" / "results.csv").read_text() == (tmp_path / "alone" / "results.csv").read_text()
