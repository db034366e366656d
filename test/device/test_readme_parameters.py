"""The README's table of node parameters agrees with their one declaration (NodeSettings, declared
with pcv_sim.params.parameter): the same names, defaults, units and read-only flags."""
import dataclasses
import re
from pathlib import Path

from pcv_sim.device.settings import NodeSettings

README = Path(__file__).resolve().parents[2] / "README.md"


def readme_rows(text: str) -> dict[str, tuple[str, str]]:
    """name -> (default cell, meaning cell) of the table headed 'parameter | default | meaning'."""
    rows, inside = {}, False
    for line in text.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")] if line.startswith("|") else None
        if cells and cells[:3] == ["parameter", "default", "meaning"]:
            inside = True
        elif cells is None:
            inside = False
        elif inside and not set(cells[0]) <= {"-", ":", " "}:
            rows[cells[0].strip("`")] = (cells[1], "|".join(cells[2:]))
    return rows


def schema() -> dict[str, dataclasses.Field]:
    return {f.metadata["name"] or f.name: f for f in dataclasses.fields(NodeSettings)}


def differences(rows: dict[str, tuple[str, str]]) -> list[str]:
    declared = schema()
    rows = {k: v for k, v in rows.items() if not k.startswith("model.")}
    found = [f"{n}: declared, not in the README" for n in declared if n not in rows]
    found += [f"{n}: in the README, not declared" for n in rows if n not in declared]
    for name, f in declared.items():
        if name not in rows:
            continue
        cell, meaning = rows[name]
        default, unit = f.default, f.metadata["unit"]
        if isinstance(default, bool):
            ok = cell == str(default).lower()
        elif isinstance(default, (int, float)):
            try:
                ok = float(cell) == float(default)
            except ValueError:
                ok = False
        elif isinstance(default, str):
            ok = cell.strip("`").strip("'") == default
        else:
            ok = True                          # a list: described in words ("all six")
        if not ok:
            found.append(f"{name}: default {cell} in the README, {default!r} declared")
        if unit not in ("-", "") and not re.search(rf"(^|[\s(,]){re.escape(unit)}([\s,;)]|$)", meaning):
            found.append(f"{name}: unit {unit} not in {meaning!r}")
        says_read_only = "read-only" in meaning or name.startswith("record.")   # "read-only, as all record.*"
        if says_read_only != f.metadata["read_only"]:
            found.append(f"{name}: read-only {f.metadata['read_only']} declared, the README says {says_read_only}")
    return found


def test_the_readme_table_matches_the_declarations():
    assert differences(readme_rows(README.read_text(encoding="utf-8"))) == []


def test_a_difference_is_found():
    rows = readme_rows(README.read_text(encoding="utf-8"))
    rows["publish_rate"] = ("500.0", rows["publish_rate"][1])
    rows["wake_period"] = (rows["wake_period"][0], "loop grid")
    rows.pop("safe_duty")
    rows["no_such"] = ("1", "s")
    found = differences(rows)
    assert "publish_rate: default 500.0 in the README, 1000.0 declared" in found
    assert "wake_period: unit s not in 'loop grid'" in found
    assert "wake_period: read-only True declared, the README says False" in found
    assert "safe_duty: declared, not in the README" in found
    assert "no_such: in the README, not declared" in found
