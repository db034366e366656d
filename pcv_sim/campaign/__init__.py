"""Campaigns: one rig scenario over many variants of its valves, plant, inputs and faults.

    spec.py         the campaign file and its validation (CampaignError naming the key)
    targets.py      what a varied key names; a variant's values written into the scenario's files
    variants.py     variant k's values, a pure function of (campaign file, k)
    sensitivity.py  SALib's Sobol / Morris design and indices
    runner.py       running variants in one worker process (prepared once per process)
    executors.py    this process, forked local workers, or a Dask cluster
    results.py      the output directory (results.csv, --resume), the summary and the gate
    report.py       report.html and the worst variants' scenario reports
    run.py          run_campaign: all of it, for `pcv-sim campaign run` and pcv_sim.testing
"""

from pcv_sim.campaign.run import CampaignResult, run_campaign
from pcv_sim.campaign.spec import Campaign, load_campaign
from pcv_sim.campaign.targets import CampaignError

__all__ = ["Campaign", "CampaignError", "CampaignResult", "load_campaign", "run_campaign"]
