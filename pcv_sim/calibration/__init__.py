"""Calibration: fit named valve parameters to recorded bags (:mod:`.fit`), render the result
(:mod:`.report`), and make rig-style recordings with the model to check it (:mod:`.synthetic`)."""

from pcv_sim.calibration.fit import (
    CORRELATION_LIMIT,
    CalibrationError,
    CalibrationResult,
    Estimate,
    FitParameter,
    SignalFit,
    calibrate,
    first_order,
    fit_parameter,
    noise_level,
)
from pcv_sim.calibration.synthetic import RIG_HEADER, write_rig_csv

__all__ = [
    "CORRELATION_LIMIT",
    "RIG_HEADER",
    "CalibrationError",
    "CalibrationResult",
    "Estimate",
    "FitParameter",
    "SignalFit",
    "calibrate",
    "first_order",
    "fit_parameter",
    "noise_level",
    "write_rig_csv",
]
