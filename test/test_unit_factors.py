"""Units are converted in one place: no bar or L/min factor is typed outside pcv_sim/units.py."""
import re
from pathlib import Path

import pytest

from pcv_sim import units

PACKAGE = Path(__file__).resolve().parent.parent / "pcv_sim"

#: A pressure scaled by 1e5 / 1e-5 (Pa <-> bar), a "bar": 1e5 table entry, a flow by 1e-3 / 60, 60000, 6e4
#: or 60e3 (m^3/s <-> L/min).
FACTOR = re.compile(r"([/*]\s*1(\.0)?e-?5\b|\"bar\":\s*1e5|1(\.0)?e-3\s*/\s*60|[/*]\s*60_?000|[/*]\s*(6(\.0)?e4|60e3)\b)")


def factors(text: str) -> list[str]:
    return [f"{k}: {line.strip()}" for k, line in enumerate(text.splitlines(), 1)
            if FACTOR.search(line.split("#")[0])]


def test_the_pattern_finds_the_factors_it_is_for():
    assert factors('y = p / 1e5\nz = q * 1e-3 / 60.0\nu = {"bar": 1e5}\nw = 1e-5 * p\nq / 60000.0\n') != []
    assert len(factors('y = p / 1e5\nz = q * 1e-3 / 60.0\nu = {"bar": 1e5}\nv = p * 1.0e5\nq / 60000.0\n')) == 5
    assert len(factors('a = q * 6e4\nb = q * 60e3\nc = q * 60000\nd = q * 6.0e4\n')) == 4
    assert factors("f = _range(10.0, 1e5)\nr = 1e-5\np = 120.4e5  # Pa\n") == []


@pytest.mark.parametrize("path", sorted(p for p in PACKAGE.rglob("*.py") if p.name != "units.py"),
                         ids=lambda p: str(p.relative_to(PACKAGE)))
def test_no_unit_factor_outside_the_units_module(path):
    assert factors(path.read_text(encoding="utf-8")) == []


def test_the_conversions():
    assert units.bar(2.5e5) == 2.5
    assert units.lpm(1e-3 / 60.0) == 1.0
    assert units.to_fit_mm(0.25e-3) == 0.25
