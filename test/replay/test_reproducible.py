"""bags/ regenerates bit-for-bit (the child process was started by conftest.regeneration)."""

from __future__ import annotations

import hashlib

from .conftest import BAGS, REFERENCE_BAGS


def _digest(path) -> str:  # noqa: ANN001
    return hashlib.sha256(path.read_bytes()).hexdigest()[:16]


def test_reference_bags_regenerate_bit_for_bit(regeneration):  # noqa: ANN001
    out, _ = regeneration.proc.communicate(timeout=240)
    assert regeneration.proc.returncode == 0, out
    for name in REFERENCE_BAGS:
        committed = sorted(p.name for p in (BAGS / name).iterdir())
        fresh = sorted(p.name for p in (regeneration.out / name).iterdir())
        assert committed == fresh == ["metadata.yaml", f"{name}_0.mcap"]
        for fname in committed:
            a, b = BAGS / name / fname, regeneration.out / name / fname
            assert a.read_bytes() == b.read_bytes(), (
                f"{name}/{fname} differs from a fresh regeneration (sha256 {_digest(a)} vs {_digest(b)}). "
                f"If the model, config/valve.yaml or a pinned package changed on purpose, run "
                f"`pcv-sim reference-bags` and commit bags/ (bags/README.md)"
            )
