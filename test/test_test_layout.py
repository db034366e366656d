"""The tests mirror the package: each package directory of pcv_sim has its test directory of the same
path under test/ (`pcv_sim/io/bag` -> `test/io/bag`), holding tests, and test/ has no directory the
package does not (the top-level modules' tests are test/*.py)."""
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
#: Test directories of data, not of tests.
DATA = {"data"}


def package_dirs(root: Path) -> set[str]:
    return {str(p.parent.relative_to(root)) for p in root.rglob("__init__.py") if p.parent != root}


def dirs_of_tests(root: Path) -> set[str]:
    return {str(p.relative_to(root)) for p in root.rglob("*") if p.is_dir() and not DATA & set(p.relative_to(root).parts)
            and p.name != "__pycache__"}


def test_every_package_directory_has_its_test_directory():
    packages = package_dirs(REPO / "pcv_sim")
    tests = dirs_of_tests(REPO / "test")
    assert "io/bag" in packages
    assert sorted(packages - tests) == []
    assert sorted(tests - packages) == []
    assert all(any((REPO / "test" / d).glob("test_*.py")) for d in packages)
