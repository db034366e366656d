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
    proc = subprocess.run([_tool('mypy')], cwd=REPO, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout + proc.stderr
