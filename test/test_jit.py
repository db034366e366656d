"""The kernel cache's key: every source compiled code can depend on, and nothing else."""

from __future__ import annotations

from pathlib import Path

from pcv_sim import jit

PKG = Path(jit.__file__).resolve().parent


def _rel(paths: list[Path]) -> set[str]:
    return {p.relative_to(PKG).as_posix() for p in paths}


def test_every_kernel_module_and_what_it_imports_is_in_the_key() -> None:
    keyed = _rel(jit.kernel_sources())
    defining = {p.relative_to(PKG).as_posix() for p in PKG.rglob("*.py")
                if "@jit" in p.read_text(encoding="utf-8")}
    assert defining and defining <= keyed
    # imported by the valve kernel (constants and the stop law), and their parent packages
    assert {"model/kernel.py", "model/stops.py", "units.py", "model/__init__.py", "__init__.py"} <= keyed
    # the generated composite imports the systems' kernels through compile.py
    assert "simulation/compile.py" in keyed


def test_an_edit_outside_the_kernels_keeps_the_compiled_code() -> None:
    keyed = _rel(jit.kernel_sources())
    assert not keyed & {"node/base.py", "cli.py", "campaign/runner.py", "rig/scenario.py"}


def test_the_key_follows_a_relative_import(tmp_path: Path) -> None:
    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "sub" / "__init__.py").write_text("")
    (pkg / "sub" / "k.py").write_text("from ..c import X\nfrom . import h\n@jit\ndef f(): return X\n")
    (pkg / "sub" / "h.py").write_text("")
    (pkg / "c.py").write_text("X = 1\n")
    (pkg / "other.py").write_text("import os\n")
    modules = {jit._module_name(pkg, p): p for p in pkg.rglob("*.py")}
    got = jit._imported("pkg.sub.k", pkg / "sub" / "k.py", (pkg / "sub" / "k.py").read_text(), modules)
    assert got == {"pkg", "pkg.c", "pkg.sub", "pkg.sub.h"}
