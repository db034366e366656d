"""Topic names are written once, in the interface registry (pcv_sim/io/topics.py): no string in the
package spells one out again. The model's own signal names (model/, plant/: the paper's, which the
registry's roles are) are the other source, and held equal to the registry here. Names that are
ordinary words as well (pressure, current, reset, faults, setpoint: a unit kind, a file's key) are
not looked for."""
import ast
from pathlib import Path

import pytest

from pcv_sim.io import topics
from pcv_sim.model import kernel
from pcv_sim.plant import cylinder

PACKAGE = Path(__file__).resolve().parent.parent / "pcv_sim"
#: Where signal names are defined: the registry, and the model's (numba's) own tables.
SOURCES = ("io/topics.py", "model/", "plant/")
WORDS = {topics.PRESSURE, topics.CURRENT, topics.RESET, topics.FAULTS, topics.SETPOINT}


def registry_names() -> set[str]:
    endpoints = (*topics.EMULATOR_INTERFACE, *topics.OPTION_INTERFACE, *topics.RIG_INTERFACE,
                 *topics.SCENARIO_INTERFACE)
    return ({e.name for e in endpoints} | {topics.EVENTS, topics.JOINT_STATES, topics.EXTERNAL_FORCE}) - WORDS


def spelled_out(text: str, names: set[str]) -> list[tuple[int, str]]:
    """(line, name) of every string constant that is one of `names` (docstrings aside)."""
    tree = ast.parse(text)
    docs = {id(node.body[0].value) for node in ast.walk(tree)
            if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef))
            and node.body and isinstance(node.body[0], ast.Expr) and isinstance(node.body[0].value, ast.Constant)}
    parts = {id(part) for node in ast.walk(tree) if isinstance(node, ast.JoinedStr) for part in node.values}

    def name(node: ast.Constant) -> str:      # an f-string's literal part: f"{prefix}duty_cycle", f"{ns}/clock"
        return node.value.lstrip("/.") if id(node) in parts and node.value.lstrip("/.") in names else node.value

    found = [(node.lineno, name(node)) for node in ast.walk(tree)
             if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docs
             and name(node) in names]
    return sorted(found)


def test_the_registrys_roles_are_the_models_signal_names():
    assert kernel.INPUTS[:len(topics.INPUT_ROLES)] == topics.INPUT_ROLES
    assert kernel.OUTPUTS == topics.OUTPUT_ROLES
    # the kernels' named indices: each name at its signal's place
    assert [kernel.INPUTS[i] for i in (kernel.U_DUTY, kernel.U_LOAD_FLOW, kernel.U_SUPPLY_PRESSURE)] == list(
        topics.INPUT_ROLES)
    assert kernel.INPUTS[kernel.U_LOAD_VOLUME] == "load_volume"
    assert [kernel.OUTPUTS[i] for i in (kernel.Y_PRESSURE, kernel.Y_CURRENT, kernel.Y_SPOOL_POSITION)] == list(
        topics.OUTPUT_ROLES)
    assert topics.EXTERNAL_FORCE in cylinder.INPUTS


def test_the_search_finds_a_name_spelled_out():
    text = ('"""duty_cycle in a docstring"""\nx = "duty_cycle"\ny = f"{p}load_flow"\nz = f"{p}/{r}"\n'
            'w = topics.SUPPLY_PRESSURE\nv = "pressure"\n')
    assert spelled_out(text, registry_names()) == [(2, "duty_cycle"), (3, "load_flow")]


@pytest.mark.parametrize("path", sorted(p for p in PACKAGE.rglob("*.py")
                                        if not str(p.relative_to(PACKAGE)).startswith(SOURCES)),
                         ids=lambda p: str(p.relative_to(PACKAGE)))
def test_no_topic_name_is_spelled_out_again(path):
    found = spelled_out(path.read_text(encoding="utf-8"), registry_names())
    assert found == [], f"{path.relative_to(PACKAGE)}: use the names of pcv_sim.io.topics"
