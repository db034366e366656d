"""The kernel cache's key: every source compiled code can depend on, and nothing else."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import pytest

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


PROBE = '''
from pcv_sim.jit import jit


@jit
def double(x):
    return x + x
'''


@pytest.mark.skipif(not jit.enabled(), reason="numba's cache")
def test_the_cache_is_written_under_the_directorys_lock(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """While numba writes a function's index, no other process can take the cache directory's lock:
    numba alone numbers a function's data files from the index each writer read, so two processes
    saving two signatures at once could both write file 1, and an index could then name the other
    signature's machine code (the session's warm-up compiles in two processes into one cache)."""
    import fcntl

    from numba.core import caching

    tried: list[bool] = []
    save_index = caching.IndexDataCacheFile._save_index

    def probe(self: Any, overloads: Any) -> None:
        fd = os.open(os.path.join(self._cache_path, ".lock"), os.O_RDWR)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            tried.append(True)
        except BlockingIOError:
            tried.append(False)
        finally:
            os.close(fd)
        save_index(self, overloads)

    monkeypatch.setattr(caching.IndexDataCacheFile, "_save_index", probe)
    (tmp_path / "locked_probe.py").write_text(PROBE)      # a new source file: not in the cache yet
    monkeypatch.syspath_prepend(str(tmp_path))
    import locked_probe  # type: ignore[import-not-found]

    assert locked_probe.double(1.5) == 3.0
    assert tried == [False]
