"""Analysis on the model: static characteristic, linearisation, step metrics, calibration."""
