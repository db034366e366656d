"""BagWriter.write_samples (bulk path used by the recorder): the same bytes as message by message."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from pcv_sim.errors import BagError
from pcv_sim.io import FLOAT64, FLUID_PRESSURE, BagWriter, read_bag
from pcv_sim.io.bag import mcap_chunks

T0 = 1_700_000_000_000_000_000
TOPICS = {"/p": FLUID_PRESSURE, "/i": FLOAT64, "/x": FLOAT64, "/diag": "diagnostic_msgs/msg/DiagnosticArray"}
N, BATCH = 3000, 137


def _data() -> tuple[np.ndarray, np.ndarray]:
    t = T0 + np.arange(N, dtype=np.int64) * 100_000
    return t, np.random.default_rng(1).normal(size=(3, N)) * np.array([[1e7], [1.0], [1e-3]])


def _writer(path: Path) -> BagWriter:
    # Chunks end only where the test flushes, so both files have the same chunk boundaries.
    return BagWriter(path, topics=TOPICS, flush_thread=False, clock=lambda: 0.0, chunk_size=1 << 40)


def _one_by_one(path: Path, frame_id: str) -> bytes:
    t, (p, i, x) = _data()
    with _writer(path) as w:
        for k in range(N):
            w.write_fluid_pressure("/p", int(t[k]), float(p[k]), 0.0, frame_id)
            w.write_float64("/i", int(t[k]), float(i[k]))
            w.write_float64("/x", int(t[k]), float(x[k]))
            if k % (5 * BATCH) == 5 * BATCH - 1:
                w.flush()
    return w.files[0].read_bytes()


def _bulk(path: Path, frame_id: str, *, bulk: bool = True) -> bytes:
    t, (p, i, x) = _data()
    with _writer(path) as w:
        assert w.bulk is bulk
        for s in range(0, N, BATCH):
            sl = slice(s, s + BATCH)
            w.write_samples(t[sl], {"/p": p[sl], "/i": i[sl], "/x": x[sl]}, frame_id=frame_id)
            if (s // BATCH) % 5 == 4:
                w.flush()
    return w.files[0].read_bytes()


@pytest.mark.parametrize("frame_id", ["", "load_port", "frame"])
def test_bulk_bytes_equal_message_by_message(tmp_path: Path, frame_id: str) -> None:
    a = _one_by_one(tmp_path / "a", frame_id)
    b = _bulk(tmp_path / "b", frame_id)
    # The files differ only in the bag's name inside the rosbag2 metadata record.
    assert a == b.replace(b"b_0.mcap", b"a_0.mcap")


@pytest.mark.parametrize("differs", ["version", "layout"])
def test_fallback_writes_the_same_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, differs: str) -> None:
    """With an mcap release other than the checked one, or a Writer laid out differently, the
    bulk path goes message by message through mcap's public API: the same file, read back."""
    t, (p, _, x) = _data()
    files = {"u": _bulk(tmp_path / "u", "load_port")}
    if differs == "version":
        monkeypatch.setattr(mcap_chunks, "MCAP_VERSION", "1.7.0")
    else:  # no private chunk builder where 1.6 has it
        monkeypatch.setattr(mcap_chunks, "_BUILDER", "_Writer__no_such_builder")
    files["v"] = _bulk(tmp_path / "v", "load_port", bulk=False)
    for name in files:
        bag = read_bag(tmp_path / name, ["/p", "/i", "/x"])
        assert bag.closed_cleanly and not bag.warnings
        assert np.array_equal(bag["/p"].t_ns, t) and np.array_equal(bag["/p"].stamp_ns, t)
        assert np.array_equal(bag["/p"].value, p) and np.array_equal(bag["/x"].value, x)
        with open(tmp_path / name / f"{name}_0.mcap", "rb") as f:
            stats = make_reader(f).get_summary().statistics
        assert stats.message_count == 3 * N and stats.message_start_time == T0
    assert files["u"] == files["v"].replace(b"v_0.mcap", b"u_0.mcap")


def test_attach_checks_version_and_layout() -> None:
    import io

    from mcap.writer import Writer

    assert mcap_chunks.attach(Writer(io.BytesIO()), version="2.0.0") is None
    assert mcap_chunks.attach(Writer(io.BytesIO()), version="unknown") is None
    assert mcap_chunks.attach(object()) is None           # type: ignore[arg-type]
    assert isinstance(mcap_chunks.attach(Writer(io.BytesIO()), version="1.6.9"), mcap_chunks.BulkChunks)


def test_write_samples_refuses_bad_input(tmp_path: Path) -> None:
    t, (p, _, _) = _data()
    with _writer(tmp_path / "b") as w:
        with pytest.raises(BagError, match="'/q' was not declared"):
            w.write_samples(t, {"/q": p})
        with pytest.raises(BagError, match="write_samples takes std_msgs/msg/Float64"):
            w.write_samples(t, {"/diag": p})
        with pytest.raises(BagError, match="2999 values for 3000 times"):
            w.write_samples(t, {"/i": p[1:]})
        with pytest.raises(BagError, match="integer nanoseconds"):
            w.write_samples(t / 1e9, {"/i": p})
        with pytest.raises(BagError, match="outside the MCAP range"):
            w.write_samples(t - T0 - 1, {"/i": p})
        w.write_samples(t[:0], {"/i": p[:0]})             # nothing to write is fine
    assert read_bag(tmp_path / "b", ["/i"])["/i"].t_ns.size == 0
