"""Small bags for the replay tests, written with pcv_sim's BagWriter from a reference bag."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from pcv_sim.io.bag import FLOAT64, FLUID_PRESSURE, BagWriter, read_bag

from .conftest import BAGS

SOURCE = BAGS / "pcv_step_levels"
DEVICE = {"duty": "/duty_cycle", "pressure": "/pressure", "current": "/current", "position": "/spool_position"}


def write_bag(path: Path, names: dict[str, str], *, until_s: float = 1.0, types: dict[str, str] | None = None,
              close: bool = True, mangle: Any = None) -> Path:
    """Copy the first `until_s` of the levels bag, signal -> topic name per `names`.

    `types` may turn a topic into Float64 (pressure) or another type; `mangle(signal, rows)`
    may edit the (t_ns, value) rows before writing.
    """
    src = read_bag(SOURCE)
    t0 = int(src["/duty_cycle"].t_ns[0])
    types = types or {}
    decl = {}
    for sig, topic in names.items():
        decl[topic] = types.get(sig, FLUID_PRESSURE if sig == "pressure" else FLOAT64)
    w = BagWriter(path, topics=decl, flush_thread=False, clock=lambda: 0.0)
    rows = {}
    for sig in names:
        s = src[DEVICE[sig]]
        keep = s.t_ns <= t0 + int(until_s * 1e9)
        rows[sig] = list(zip(s.t_ns[keep].tolist(), s.value[keep].tolist()))
        if mangle is not None:
            rows[sig] = mangle(sig, rows[sig])
    for sig, topic in names.items():
        for t, v in rows[sig]:
            if decl[topic] == FLUID_PRESSURE:
                w.write_fluid_pressure(topic, t, v, 0.0)
            elif decl[topic] == FLOAT64:
                w.write_float64(topic, t, v)
            else:
                w.write(topic, t, {"header": {"stamp": {"sec": t // 1_000_000_000, "nanosec": t % 1_000_000_000}, "frame_id": ""},
                                 "temperature": v, "variance": 0.0})
    if close:
        w.close()
    else:
        w.flush()  # chunks on disk, no summary/footer: as after a SIGKILL
    return path
