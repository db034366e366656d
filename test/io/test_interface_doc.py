"""docs/interface.md agrees with the interface registry (pcv_sim/io/topics.py): every topic and
service of the emulator, the rig and a ROS scenario, its direction, message type, unit and QoS."""
import re
from pathlib import Path

import pytest

from pcv_sim.io.topics import EMULATOR_INTERFACE, OPTION_INTERFACE, RIG_INTERFACE, SCENARIO_INTERFACE, Endpoint

DOC = Path(__file__).resolve().parents[2] / "docs" / "interface.md"


def doc_tables(text: str) -> list[list[list[str]]]:
    """The tables whose columns start 'direction ... | topic | type': rows of cells."""
    tables, rows = [], None
    for line in text.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")] if line.startswith("|") else None
        if cells and cells[0].startswith("direction") and cells[1:3] == ["topic", "type"]:
            rows = []
            tables.append(rows)
        elif cells is None:
            rows = None
        elif rows is not None and not set(cells[0]) <= {"-", ":", " "}:
            rows.append(cells)
    return tables


def documented(rows: list[list[str]]) -> dict[str, tuple[str, str, str, str]]:
    """name -> (direction, type, meaning, QoS) from a table; `a/b_x`, `b_y` names b_y under a/."""
    out = {}
    for row in rows:          # a `|` inside the meaning splits it: the QoS is the last cell
        direction, names, msgtype, meaning, qos = *row[:3], "|".join(row[3:-1]), row[-1]
        prefix = ""
        for written in re.findall(r"`([^`]+)`", names):
            name = written
            if "/" in written.lstrip("/"):
                prefix = written.rpartition("/")[0] + "/" if not written.startswith("/") else ""
            elif prefix:
                name = prefix + written
            out[name] = (direction, msgtype, meaning, qos)
    return out


def qos_in(text: str) -> tuple[str | None, int | None]:
    """(reliability, depth) a QoS cell states; 'sensor data' alone is best effort, keep last 5."""
    if not text:
        return None, None
    reliability = "best_effort" if ("best effort" in text or "sensor data" in text) else "reliable"
    depth = re.search(r"keep last (\d+)", text)
    return reliability, int(depth.group(1)) if depth else (5 if "sensor data" in text else None)


def mismatches(endpoints: tuple[Endpoint, ...], rows: list[list[str]]) -> list[str]:
    doc = documented(rows)
    found = [f"{e.name}: in the registry, not in the document" for e in endpoints if e.name not in doc]
    names = {e.name for e in endpoints}
    found += [f"{n}: in the document, not in the registry" for n in doc if n not in names]
    for e in endpoints:
        if e.name not in doc:
            continue
        direction, msgtype, meaning, qos = doc[e.name]
        if direction.split(" ")[0] != e.direction:
            found.append(f"{e.name}: direction {direction!r} in the document, {e.direction!r} in the registry")
        if msgtype != e.type:
            found.append(f"{e.name}: type {msgtype} in the document, {e.type} in the registry")
        if e.unit not in ("", "1", "s") and not re.search(rf"(^|[\s(,]){re.escape(e.unit)}([\s,;)]|$)", meaning):
            found.append(f"{e.name}: unit {e.unit} not in {meaning!r}")
        if e.unit == "1" and "fraction" not in meaning:
            found.append(f"{e.name}: a fraction, not said in {meaning!r}")
        want = (e.qos.reliability, e.qos.depth) if e.qos is not None else (None, None)
        if qos_in(qos) != want:
            found.append(f"{e.name}: QoS {qos!r} in the document, {want} in the registry")
    return found


@pytest.mark.parametrize(("k", "endpoints"), [(0, EMULATOR_INTERFACE), (1, RIG_INTERFACE), (2, SCENARIO_INTERFACE),
                                               (3, OPTION_INTERFACE)],
                         ids=["emulator", "rig", "scenario", "options"])
def test_the_document_matches_the_registry(k, endpoints):
    tables = doc_tables(DOC.read_text(encoding="utf-8"))
    assert len(tables) == 4
    assert mismatches(endpoints, tables[k]) == []


def test_a_difference_is_found():
    rows = [["in", "`duty_cycle`", "std_msgs/msg/Float64", "PWM duty, a fraction 0..1", "reliable, keep last 10, volatile"],
            ["out", "`pressure`", "std_msgs/msg/Float64", "load pressure, bar", "sensor data"],
            ["out", "`extra`", "std_msgs/msg/Float64", "m", "sensor data"]]
    found = mismatches(EMULATOR_INTERFACE[:2] + EMULATOR_INTERFACE[3:4], rows)
    assert "load_flow: in the registry, not in the document" in found
    assert "extra: in the document, not in the registry" in found
    assert "pressure: type std_msgs/msg/Float64 in the document, sensor_msgs/msg/FluidPressure in the registry" in found
    assert "pressure: unit Pa not in 'load pressure, bar'" in found
    assert not any(f.startswith("duty_cycle") for f in found)
