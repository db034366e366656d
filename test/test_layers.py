"""The layer order of docs/architecture.md holds over the package's real import graph.

Every `import` and `from ... import` in `pcv_sim/` counts, also those inside functions and under
`TYPE_CHECKING` (a lazy import is still a dependency). The layers are read from the table in
docs/architecture.md, so the document and the check cannot drift apart. Two rules:

- a module imports only from its own layer or the layers below it (no upward import);
- no circle of imports between modules, nor between the packages (and top-level modules) of
  the table, e.g. `rig/` -> `node/` -> `rig/`.

The checker is tested on a small package built with a circle and an upward import.
"""
from __future__ import annotations

import ast
import re
from dataclasses import dataclass, field
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
PACKAGE = "pcv_sim"


def read_layers(doc: Path) -> list[list[str]]:
    """The `package` column of the layer table, top layer first: each entry a list of units
    (`cli`, `commands`, ...: a top-level module or subpackage of the package)."""
    layers: list[list[str]] = []
    in_table = False
    for line in doc.read_text(encoding="utf-8").splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if line.startswith("|") and len(cells) >= 2 and cells[:2] == ["layer", "package"]:
            in_table = True
            continue
        if not in_table:
            continue
        if not line.startswith("|"):
            break
        if set(cells[0]) <= {"-", ":", " "}:
            continue
        units = [re.sub(r"(\.py|/)$", "", name) for name in re.findall(r"`([^`]+)`", cells[1])]
        layers.append(units)
    if not layers:
        raise AssertionError(f"{doc} has no table with the columns 'layer | package'")
    return layers


def _module_name(root: Path, path: Path) -> str:
    parts = list(path.relative_to(root.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


@dataclass
class Graph:
    modules: dict[str, Path] = field(default_factory=dict)
    #: (importer, imported, line) over modules of the package
    edges: list[tuple[str, str, int]] = field(default_factory=list)


def import_graph(root: Path) -> Graph:
    """Modules of the package at `root` and their imports of each other. `from a.b import c`
    counts as an import of `a.b.c` when that is a module, else of `a.b`."""
    graph = Graph()
    for path in sorted(root.rglob("*.py")):
        graph.modules[_module_name(root, path)] = path
    for name, path in graph.modules.items():
        is_package = path.name == "__init__.py"
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        for node in ast.walk(tree):
            targets: list[str] = []
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    anchor = name.split(".")
                    if not is_package:
                        anchor = anchor[:-1]
                    anchor = anchor[:len(anchor) - (node.level - 1)]
                    base = ".".join([*anchor, base] if base else anchor)
                for alias in node.names:
                    sub = f"{base}.{alias.name}"
                    targets.append(sub if sub in graph.modules else base)
            for target in targets:
                module = target
                while module and module not in graph.modules:
                    module = module.rpartition(".")[0]     # `import a.b.c` of a name inside a.b
                if module and module != name:
                    graph.edges.append((name, module, node.lineno))
    return graph


def unit_of(module: str) -> str | None:
    """The table's unit of a module (`pcv_sim.rig.scenario` -> `rig`); None for the package's face."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else None


def cycles(edges: set[tuple[str, str]]) -> list[list[str]]:
    """The strongly connected components with more than one member (Tarjan), each sorted."""
    succ: dict[str, list[str]] = {}
    for a, b in edges:
        succ.setdefault(a, []).append(b)
        succ.setdefault(b, [])
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in succ[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(succ):
        if v not in index:
            visit(v)
    return sorted(found)


@dataclass
class Findings:
    modules: int
    imports: int
    upward: list[str]
    unplaced: list[str]
    module_cycles: list[list[str]]
    unit_cycles: list[list[str]]


def check(root: Path, doc: Path) -> Findings:
    layers = read_layers(doc)
    level = {unit: k for k, units in enumerate(layers) for unit in units}     # 0: the top
    graph = import_graph(root)
    upward = []
    unplaced = sorted({unit for m in graph.modules if (unit := unit_of(m)) is not None and unit not in level})
    for a, b, line in graph.edges:
        ua, ub = unit_of(a), unit_of(b)
        if ua is None or ub is None or ua not in level or ub not in level:
            continue
        if level[ub] < level[ua]:
            upward.append(f"{graph.modules[a].relative_to(root.parent)}:{line}: {a} imports {b} "
                          f"({ub} is a layer above {ua})")
    module_edges = {(a, b) for a, b, _ in graph.edges}
    unit_edges = {(ua, ub) for a, b in module_edges
                  if (ua := unit_of(a)) and (ub := unit_of(b)) and ua != ub}
    return Findings(len(graph.modules), len(module_edges), upward, unplaced,
                    cycles(module_edges), cycles(unit_edges))


def test_every_unit_of_the_package_has_a_layer():
    assert check(REPO / PACKAGE, REPO / "docs" / "architecture.md").unplaced == []


def test_no_upward_import():
    assert check(REPO / PACKAGE, REPO / "docs" / "architecture.md").upward == []


def test_no_circle_of_imports():
    found = check(REPO / PACKAGE, REPO / "docs" / "architecture.md")
    assert found.module_cycles == []
    assert found.unit_cycles == []


# --- the checker itself, on a package built with the faults it must find ------------------

DOC = """# Architecture

| layer | package | what it holds |
|---|---|---|
| top | `cli.py`, `front/` | entry points |
| middle | `rig/` | uses |
| bottom | `units.py`, `io/` | base |
"""


def _package(tmp_path: Path, files: dict[str, str]) -> tuple[Path, Path]:
    root = tmp_path / PACKAGE
    for rel, text in {"__init__.py": "", **files}.items():
        path = root / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text, encoding="utf-8")
    doc = tmp_path / "architecture.md"
    doc.write_text(DOC, encoding="utf-8")
    return root, doc


GOOD = {
    "cli.py": "from pcv_sim.front import main\n",
    "front/__init__.py": "from pcv_sim.front.app import main\n",
    "front/app.py": "from . import helpers\nfrom pcv_sim.rig import scenario\n\ndef main(): ...\n",
    "front/helpers.py": "import pcv_sim.units\n",
    "rig/__init__.py": "",
    "rig/scenario.py": "from ..io.bag import writer\nfrom pcv_sim.units import PA_PER_BAR\n",
    "io/__init__.py": "",
    "io/bag/__init__.py": "from pcv_sim.io.bag.writer import Writer\n",
    "io/bag/writer.py": "from pcv_sim.io.bag import cdr\nclass Writer: ...\n",
    "io/bag/cdr.py": "",
    "units.py": "PA_PER_BAR = 1e5\n",
}


def test_checker_passes_a_layered_package(tmp_path):
    found = check(*_package(tmp_path, GOOD))
    assert found.modules == len(GOOD) + 1
    assert (found.upward, found.unplaced, found.module_cycles, found.unit_cycles) == ([], [], [], [])
    # the relative imports resolve: front.app -> front.helpers, rig.scenario -> io.bag.writer
    edges = {(a, b) for a, b, _ in import_graph(tmp_path / PACKAGE).edges}
    assert ("pcv_sim.front.app", "pcv_sim.front.helpers") in edges
    assert ("pcv_sim.rig.scenario", "pcv_sim.io.bag.writer") in edges


def test_checker_finds_a_lazy_upward_import(tmp_path):
    bad = {**GOOD, "rig/scenario.py": "def plot():\n    from pcv_sim.front.helpers import x\n"}
    found = check(*_package(tmp_path, bad))
    assert len(found.upward) == 1
    assert "rig/scenario.py:2: pcv_sim.rig.scenario imports pcv_sim.front.helpers" in found.upward[0]


def test_checker_finds_a_circle_across_packages(tmp_path):
    # rig -> io -> rig: io imports upward, and the two packages form a circle
    bad = {**GOOD, "io/bag/cdr.py": "from pcv_sim.rig import scenario\n"}
    found = check(*_package(tmp_path, bad))
    assert found.unit_cycles == [["io", "rig"]]
    assert ["pcv_sim.io.bag.cdr", "pcv_sim.io.bag.writer", "pcv_sim.rig.scenario"] in found.module_cycles


def test_checker_finds_a_circle_inside_one_layer(tmp_path):
    # not upward (one layer), but still a circle: front.app -> front.helpers -> front.app
    bad = {**GOOD, "front/helpers.py": "from pcv_sim.front.app import main\n"}
    found = check(*_package(tmp_path, bad))
    assert found.upward == []
    assert found.module_cycles == [["pcv_sim.front.app", "pcv_sim.front.helpers"]]


def test_checker_finds_a_unit_the_table_does_not_place(tmp_path):
    found = check(*_package(tmp_path, {**GOOD, "extra.py": ""}))
    assert found.unplaced == ["extra"]


def test_checker_refuses_a_document_without_the_table(tmp_path):
    doc = tmp_path / "empty.md"
    doc.write_text("# nothing\n", encoding="utf-8")
    with pytest.raises(AssertionError, match="no table"):
        read_layers(doc)
