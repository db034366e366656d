"""The linter and the type checker configured in pyproject.toml pass: part of the test command,
so CI runs them too. Each prints what it found when it fails."""
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent


def _tool(name: str) -> str:
    exe = Path(sys.executable).parent / name
    found = str(exe) if exe.exists() else shutil.which(name)
    if found is None:
        pytest.fail(f'{name} is not installed: it is in requirements/common.txt (make venv installs it)')
    return found


def test_ruff_finds_nothing():
    proc = subprocess.run([_tool('ruff'), 'check', '.'], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stdout + proc.stderr


def test_mypy_finds_nothing():
    """mypy's incremental cache is kept beside the kernel cache, outside the clone: a fresh clone (CI's)
    then checks only the modules whose contents changed (~1 s instead of ~12 s of CPU). mypy keys each
    cached module on its source's hash and mypy's version and options, so a stale entry is not reused."""
    from pcv_sim.jit import cache_root

    proc = subprocess.run([_tool('mypy'), '--cache-dir', str(cache_root() / 'mypy')], cwd=REPO, capture_output=True,
                          text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout + proc.stderr


def test_mypy_is_strict_with_only_the_numba_kernels_exempt():
    """strict holds for the package; the overrides that relax it name modules of the numba
    kernels or of the ROS adapter only, and relax no more than the untyped-function rules."""
    import tomllib

    mypy = tomllib.loads((REPO / 'pyproject.toml').read_text(encoding='utf-8'))['tool']['mypy']
    assert mypy['strict'] is True
    relaxable = {'disallow_untyped_defs', 'disallow_incomplete_defs', 'disallow_untyped_decorators',
                 'disallow_untyped_calls', 'warn_return_any'}
    for override in mypy.get('overrides', []):
        modules = override['module'] if isinstance(override['module'], list) else [override['module']]
        assert all(m.startswith(('pcv_sim.model.', 'pcv_sim.plant.', 'pcv_sim.node.')) for m in modules), modules
        assert set(override) - {'module'} <= relaxable, override
