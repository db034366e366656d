"""docs/files.md's tables of the keys of scenario and campaign files (and of the example
controller's `controller_params`) are their declarations
(pcv_sim.params.key_table of each declaring dataclass), and every declaring dataclass of those
files has its table there; its table of faults is the faults' declarations
(pcv_sim.device.faults.fault_table)."""
import dataclasses
import importlib
import re
from pathlib import Path

from pcv_sim.device.faults import fault_table
from pcv_sim.params import key_table

DOC = Path(__file__).resolve().parents[1] / "docs" / "files.md"
MARK = re.compile(r"^<!-- keys: ([\w.]+) -->$")
FAULTS_MARK = "<!-- faults: pcv_sim.device.faults.fault_table -->"
#: The modules that declare the keys of scenario and campaign files.
MODULES = ("pcv_sim.rig.scenario", "pcv_sim.rig.profiles", "pcv_sim.rig.assertions", "pcv_sim.campaign.spec",
           "pcv_sim.control.params")


def table_after(lines: list[str], k: int) -> str:
    """The Markdown table that starts at line k + 1."""
    rows = []
    for row in lines[k + 1:]:
        if not row.startswith("|"):
            break
        rows.append(row)
    return "\n".join(rows)


def tables(text: str) -> dict[str, str]:
    """Dotted class name -> the Markdown table that follows its marker."""
    out, lines = {}, text.splitlines()
    for k, line in enumerate(lines):
        m = MARK.match(line.strip())
        if m:
            out[m.group(1)] = table_after(lines, k)
    return out


def faults_tables(text: str) -> list[str]:
    """The tables that follow the faults' marker (one expected)."""
    lines = text.splitlines()
    return [table_after(lines, k) for k, line in enumerate(lines) if line.strip() == FAULTS_MARK]


def declaring_classes() -> dict[str, type]:
    """Every dataclass of MODULES whose fields are all declared with pcv_sim.params.parameter."""
    out = {}
    for name in MODULES:
        module = importlib.import_module(name)
        for attr, obj in vars(module).items():
            if isinstance(obj, type) and dataclasses.is_dataclass(obj) and obj.__module__ == name and \
                    dataclasses.fields(obj) and all("check" in f.metadata for f in dataclasses.fields(obj)):
                out[f"{name}.{attr}"] = obj
    return out


def differences(text: str) -> list[str]:
    found = []
    doc = tables(text)
    declared = declaring_classes()
    for dotted, cls in declared.items():
        if dotted not in doc:
            found.append(f"{dotted}: declared, no table in docs/files.md")
        elif doc[dotted] != key_table(cls):
            found.append(f"{dotted}: the table differs from the declarations; it is:\n{key_table(cls)}")
    found += [f"{dotted}: a table in docs/files.md, no such declaration" for dotted in doc if dotted not in declared]
    return found


def test_the_tables_of_keys_are_the_declarations():
    assert differences(DOC.read_text(encoding="utf-8")) == []


def test_every_file_declaration_is_found():
    names = set(declaring_classes())
    assert {"pcv_sim.rig.scenario.ScenarioKeys", "pcv_sim.rig.scenario.RosController",
            "pcv_sim.rig.profiles.RampKeys", "pcv_sim.rig.assertions.AssertionKeys",
            "pcv_sim.campaign.spec.CampaignKeys", "pcv_sim.campaign.spec.DistributionKeys",
            "pcv_sim.control.params.PositionControllerParams"} <= names


def test_a_difference_is_found():
    text = DOC.read_text(encoding="utf-8")
    edited = text.replace("| `duration` | s | 0 .. 3600 | required |", "| `duration` | s | 0 .. 60 | required |")
    assert edited != text
    edited = edited.replace("<!-- keys: pcv_sim.campaign.spec.GateKeys -->", "<!-- keys: pcv_sim.campaign.spec.Gate -->")
    found = differences(edited)
    assert any(f.startswith("pcv_sim.rig.scenario.ScenarioKeys: the table differs") for f in found)
    assert "pcv_sim.campaign.spec.GateKeys: declared, no table in docs/files.md" in found
    assert "pcv_sim.campaign.spec.Gate: a table in docs/files.md, no such declaration" in found


def test_the_table_of_faults_is_their_declarations():
    assert faults_tables(DOC.read_text(encoding="utf-8")) == [fault_table()]


def test_a_difference_in_the_faults_table_is_found():
    text = DOC.read_text(encoding="utf-8")
    edited = text.replace("| `pressure` | Pa | 0 .. 4e+07 |", "| `pressure` | Pa | 0 .. 4e+06 |")
    assert edited != text and faults_tables(edited) != [fault_table()]
