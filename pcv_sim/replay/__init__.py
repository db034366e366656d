"""Replay comparison: drive a model with a bag's recorded inputs and compare its outputs.

``load_recording`` reads and validates a bag, ``replay`` returns typed metrics (a pure function
of the recording and the parameters), ``check_thresholds`` applies limits, ``report`` renders.
"""

from pcv_sim.replay.compare import (
    ReplayResult,
    SignalResult,
    Step,
    StepComparison,
    ThresholdFailure,
    check_thresholds,
    detect_steps,
    replay,
)
from pcv_sim.replay.errors import ReplayError
from pcv_sim.replay.recording import Gap, Recording, Series, find_gaps, load_recording, parse_topic_map
from pcv_sim.replay.simulate import InputTimeline, ModelRun, input_timeline, run_model

__all__ = [
    "Gap",
    "InputTimeline",
    "ModelRun",
    "Recording",
    "ReplayError",
    "ReplayResult",
    "Series",
    "SignalResult",
    "Step",
    "StepComparison",
    "ThresholdFailure",
    "check_thresholds",
    "detect_steps",
    "find_gaps",
    "input_timeline",
    "load_recording",
    "parse_topic_map",
    "replay",
    "run_model",
]
