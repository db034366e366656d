"""Unit conversions, in one place. SI inside the model; the paper's curve fits take mm; bar,
L/min and percent only at the edges (CLI, reports)."""

MM_PER_M = 1.0e3        # the paper's fits (Eqs. 5-13, 21-25, 27, 31-32) take the position in mm
PA_PER_BAR = 1.0e5
M3S_PER_LPM = 1.0e-3 / 60.0


def to_fit_mm(x_m: float) -> float:
    """Spool position in m -> the paper's fit coordinate in mm (the one conversion of x)."""
    return x_m * MM_PER_M


def bar(p_pa: float) -> float:
    return p_pa / PA_PER_BAR


def lpm(q_m3s: float) -> float:
    return q_m3s / M3S_PER_LPM
