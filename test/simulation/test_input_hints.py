"""Hints in the input checks name a unit mix-up only where it is plausible (issue 11, item 13):
percent for a duty of 2..100, bar for a supply pressure that is in range when read as bar,
L/min for a load flow that is in range when read as L/min."""

from __future__ import annotations

import pytest

from pcv_sim.errors import CommandError
from pcv_sim.simulation.duty import check_duty
from pcv_sim.simulation.valve import check_load_flow, check_supply_pressure


@pytest.mark.parametrize(("value", "hint"), [(70.0, "0.7"), (2.0, "0.02"), (100.0, "1")])
def test_duty_that_reads_as_percent_gets_the_fraction(value: float, hint: str) -> None:
    with pytest.raises(CommandError, match=rf"not percent \(did you mean {hint}\?\)"):
        check_duty(value)


@pytest.mark.parametrize("value", [1.5, 1.01, 150.0, 1e4])
def test_duty_that_is_no_percent_gets_the_range_only(value: float) -> None:
    with pytest.raises(CommandError, match=r"is out of range: accepted is a fraction 0\.\.1$") as info:
        check_duty(value)
    assert "percent" not in str(info.value) and "did you mean" not in str(info.value)


def test_supply_pressure_names_bar_only_when_it_reads_as_bar() -> None:
    with pytest.raises(CommandError, match=r"not bar: 200 bar is 2e\+07 Pa\)$"):
        check_supply_pressure(200.0)
    for value in (5e8, 5e7, 0.5, -200e5):   # as bar: 5e13, 5e12, 0.5 bar, negative: none in range
        with pytest.raises(CommandError, match=r"accepted is 1e\+05 \.\. 4e\+07 Pa \(1 \.\. 400 bar\)$") as info:
            check_supply_pressure(value)
        assert "not bar" not in str(info.value)


def test_load_flow_names_l_per_min_only_when_it_reads_as_l_per_min() -> None:
    with pytest.raises(CommandError, match=r"not L/min: 30 L/min is 0\.0005 m\^3/s$"):
        check_load_flow(30.0)
    with pytest.raises(CommandError, match=r"\(100 L/min\)$") as info:
        check_load_flow(500.0)
    assert "not L/min" not in str(info.value)
