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


KELVIN_AT_0C = 273.15   # temperatures are kelvin inside; the YAML and reports give degC (keys *_c)


def kelvin(celsius: float) -> float:
    """degC (the YAML's *_c keys, scenario profiles) -> K (inside the model)."""
    return celsius + KELVIN_AT_0C


CST_PER_M2S = 1.0e6     # kinematic viscosity: 1 cSt = 1 mm^2/s (oil grades, Walther's relation)
