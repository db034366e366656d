"""docs/interface.md agrees with the interface registry (pcv_sim/io/topics.py): every topic and
service of the emulator, the rig and a ROS scenario, its direction, message type, unit and QoS."""
import re
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from pcv_sim.io.topics import EMULATOR_INTERFACE, OPTION_INTERFACE, RIG_INTERFACE, SCENARIO_INTERFACE, Endpoint

DOC = Path(__file__).resolve().parents[2] / "docs" / "interface.md"


def tables_headed(text: str, is_header: Callable[[list[str]], bool]) -> list[list[list[str]]]:
    """The Markdown tables whose header's cells `is_header` accepts: rows of cells."""
    tables, rows = [], None
    for line in text.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")] if line.startswith("|") else None
        if cells and is_header(cells):
            rows = []
            tables.append(rows)
        elif cells is None:
            rows = None
        elif rows is not None and not set(cells[0]) <= {"-", ":", " "}:
            rows.append(cells)
    return tables


def doc_tables(text: str) -> list[list[list[str]]]:
    """The tables whose columns start 'direction ... | topic | type'."""
    return tables_headed(text, lambda cells: cells[0].startswith("direction") and cells[1:3] == ["topic", "type"])


def named_rows(rows: list[list[str]]) -> Iterator[tuple[str, str, str, str, str]]:
    """(name, direction, type, meaning, QoS) per name a table's rows give; `a/b_x`, `b_y` names b_y under a/."""
    for row in rows:          # a `|` inside the meaning splits it: the QoS is the last cell
        direction, names, msgtype, meaning, qos = *row[:3], "|".join(row[3:-1]), row[-1]
        prefix = ""
        for written in re.findall(r"`([^`]+)`", names):
            name = written
            if "/" in written.lstrip("/"):
                prefix = written.rpartition("/")[0] + "/" if not written.startswith("/") else ""
            elif prefix:
                name = prefix + written
            yield name, direction, msgtype, meaning, qos


def documented(rows: list[list[str]]) -> dict[str, tuple[str, str, str, str]]:
    """name -> (direction, type, meaning, QoS) from a table."""
    return {name: rest for name, *rest in named_rows(rows)}


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


# --- the README's tables of topics: the same facts, in its shorter words --------------------------

README = DOC.parents[1] / "README.md"
#: The QoS as the README words it.
README_QOS = {"sensor data": ("best_effort", 5), "": (None, None)}


def readme_tables(text: str) -> list[list[list[str]]]:
    """The README's tables headed '| | topic ... | type | ...'."""
    return tables_headed(text, lambda cells: cells[0] == "" and cells[1].startswith("topic") and cells[2:3] == ["type"])


def readme_mismatches(rows: list[list[str]], registry: dict[str, Endpoint], valve_roles: dict[str, Endpoint]) -> list[str]:
    """What a README table says that the registry does not: names (`<valve>/x` a valve's role x, a bare
    name after `a/b` under a/), direction, type (written without `/msg/`), unit and QoS."""
    found = []
    listed = set()
    for name, direction, msgtype, meaning, qos in named_rows(rows):
        listed.add(name)
        e = valve_roles.get(name.removeprefix("<valve>/")) if name.startswith("<valve>/") else registry.get(name)
        if e is None:
            found.append(f"{name}: in the README, not in the registry")
            continue
        if direction not in e.direction.split("/"):
            found.append(f"{name}: direction {direction!r} in the README, {e.direction!r} in the registry")
        if msgtype != e.type.replace("/msg/", "/").replace("/srv/", "/"):
            found.append(f"{name}: type {msgtype} in the README, {e.type} in the registry")
        if e.unit not in ("", "1", "s") and not re.search(rf"(^|[\s(,:]){re.escape(e.unit)}([\s,;:)]|$)", meaning):
            found.append(f"{name}: unit {e.unit} not in {meaning!r}")
        if e.unit == "1" and "fraction" not in meaning:
            found.append(f"{name}: a fraction, not said in {meaning!r}")
        depth = re.fullmatch(r"reliable, depth (\d+)", qos)
        said = ("reliable", int(depth.group(1))) if depth else README_QOS.get(qos, (qos, None))
        want = (e.qos.reliability, e.qos.depth) if e.qos is not None else (None, None)
        if said != want:
            found.append(f"{name}: QoS {qos!r} in the README, {want} in the registry")
    found += [f"{n}: in the registry, not in the README" for n in registry if n not in listed]
    return found


def _by_name(*endpoints: Endpoint) -> dict[str, Endpoint]:
    return {e.name: e for e in endpoints}


VALVE_ROLES = _by_name(*EMULATOR_INTERFACE, *OPTION_INTERFACE)


@pytest.mark.parametrize(("k", "registry"), [(0, _by_name(*EMULATOR_INTERFACE)), (1, _by_name(*RIG_INTERFACE))],
                         ids=["emulator", "rig"])
def test_the_readme_topics_match_the_registry(k, registry):
    tables = readme_tables(README.read_text(encoding="utf-8"))
    assert len(tables) == 2
    assert readme_mismatches(tables[k], registry, VALVE_ROLES) == []


def test_a_difference_in_the_readme_is_found():
    rows = [["in", "`<valve>/duty_cycle`", "std_msgs/Float64", "fraction 0..1", "reliable, depth 10"],
            ["out", "`<valve>/pressure`", "std_msgs/Float64", "bar", "reliable, depth 10"],
            ["out", "`cylinder/joint_states`, `pressure_c`", "sensor_msgs/JointState", "m", "sensor data"],
            ["in", "`/clock`", "rosgraph_msgs/Clock", "model time", "reliable, depth 10"]]
    found = readme_mismatches(rows, _by_name(*RIG_INTERFACE[:1], *RIG_INTERFACE[7:]), VALVE_ROLES)
    assert "<valve>/pressure: type std_msgs/Float64 in the README, sensor_msgs/msg/FluidPressure in the registry" in found
    assert "<valve>/pressure: unit Pa not in 'bar'" in found
    assert "<valve>/pressure: QoS 'reliable, depth 10' in the README, ('best_effort', 5) in the registry" in found
    assert "cylinder/pressure_c: in the README, not in the registry" in found
    assert "lockstep/sample: in the registry, not in the README" in found
    assert not any(f.startswith(("<valve>/duty_cycle", "/clock", "cylinder/joint_states")) for f in found), found
