"""A lockstep run as a bag and as CSV (the HTML report: `pcv_sim.rig.report`). Every number is the run's.

Bag topics (what the devices publish: the measured values, sensor faults included; a dropped
sample has no message), one namespace per valve, SI units:

    /<valve>/duty_cycle       std_msgs/Float64        the duty in force, fraction
    /<valve>/pressure         sensor_msgs/FluidPressure  Pa (the chamber's pressure)
    /<valve>/current          std_msgs/Float64        A
    /<valve>/spool_position   std_msgs/Float64        m
    /cylinder/joint_states    sensor_msgs/JointState  prismatic joint `steering`: position m,
                                                      velocity m/s, effort N
    /cylinder/pressure_a|b    sensor_msgs/FluidPressure  Pa, the chambers (= their valves')
    /setpoint                 std_msgs/Float64        m (when the scenario has one)
    /rig/events               std_msgs/String         faults, clears, watchdog, rejected commands
    /controller/<flag>        std_msgs/Float64        each flag the controller reported (`controller.<flag>`)

`write_csv` writes every signal of a run as one CSV (time + columns, `name [unit]` headers, SI;
`<signal> measured` columns where a sensor fault made the measurement differ); `read_signals`
reads a bag or such a CSV back (a baseline run for `pcv_sim.rig.assertions`).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from pcv_sim.device.recording import BagLayout, DeviceRecorder
from pcv_sim.errors import BagError
from pcv_sim.io import FLUID_PRESSURE
from pcv_sim.io.recorder import WriterSettings
from pcv_sim.io.topics import (
    CURRENT,
    CYLINDER,
    DUTY_CYCLE,
    EVENTS,
    JOINT_FIELDS,
    JOINT_STATES,
    PRESSURE,
    SETPOINT,
    SPOOL_POSITION,
    bag_topic,
    chamber_topic,
    cylinder_topic,
    valve_topic,
)
from pcv_sim.rig.lockstep import RigRun
from pcv_sim.units import KINDS, NS_PER_S, quantity

__all__ = ["read_signals", "signal_unit", "write_bag", "write_csv"]

#: The controller's flags (`controller.<flag>`) in a run's bag: `/controller/<flag>`.
_FLAGS = "controller"


def write_bag(run: RigRun, path: str | Path, *, chambers: dict[str, str] | None = None) -> Path:
    """Write `run` as a rosbag2/MCAP bag at `path` (must not exist); `chambers` maps valve -> a|b.
    The rig's bag layout (`pcv_sim.device.recording.BagLayout`, the live recording's) with a row
    per sample: the measured signals, each valve's duty, the setpoint (when the run has one) and
    the controller's flags; the log and the rejected commands as events."""
    extra = [(f"{v}.{DUTY_CYCLE}", valve_topic(v, DUTY_CYCLE)) for v in run.valves]
    columns = [run.measured, run.duties]
    if np.any(np.isfinite(run.setpoint)):
        extra.append((SETPOINT, SETPOINT))
        columns.append(run.setpoint[:, None])
    for flag, values in run.flags.items():
        extra.append((flag, f"{_FLAGS}/{flag.removeprefix(_FLAGS + '.')}"))
        columns.append(np.asarray(values, dtype=np.float64)[:, None])
    layout = BagLayout.of_names(run.valves, run.signals, (), chambers=chambers or {}, faults=False, options=False,
                                record=(DUTY_CYCLE, PRESSURE, CURRENT, SPOOL_POSITION), extra=extra)
    p = Path(path)
    rec = DeviceRecorder(p.parent, layout, name=p.name, offered_qos=False,
                         writing=WriterSettings(writer="inline", fsync=False))
    rec.rows(np.round(run.times * NS_PER_S).astype(np.int64), np.column_stack(columns))
    assert rec.events_topic is not None
    for t, text in sorted(run.log + [(t, f"rejected: {r}") for t, r in run.rejected]):
        rec.text(rec.events_topic, round(t * NS_PER_S), text)
    st = rec.close()
    if st.error:
        raise BagError(f"{p}: {st.error}")
    return p


def signal_unit(signal: str) -> str:
    """The SI unit of a run's signal (its column header in a CSV)."""
    from pcv_sim.rig.rig import signal_kind

    return KINDS[signal_kind(signal)].si


def _columns(run: RigRun) -> list[tuple[str, np.ndarray]]:
    cols = [(s, run.signal(s)) for s in run.signals]
    cols += [(f"{v}.duty", run.duties[:, k]) for k, v in enumerate(run.valves)]
    if np.any(np.isfinite(run.setpoint)):
        cols.append(("setpoint", run.setpoint))
    cols += list(run.flags.items())
    for s in run.signals:
        m = run.signal(s, measured=True)
        if not np.array_equal(m, run.signal(s), equal_nan=True):
            cols.append((f"{s} measured", m))
    return cols


def write_csv(run: RigRun, path: str | Path) -> Path:
    """Every signal of `run` as CSV at `path` (SI; an empty cell where a sample is missing)."""
    cols = _columns(run)
    header = ["time [s]"] + [f"{name} [{signal_unit(name.split(' ')[0])}]" for name, _ in cols]
    data = np.column_stack([run.times] + [c for _, c in cols])
    lines = [",".join(header)]
    for row in data:
        lines.append(",".join("" if not math.isfinite(x) else repr(float(x)) for x in row))
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return p


def read_signals(path: str | Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The signals of an earlier run: `signal -> (times s, values SI)` from a bag (as `write_bag`
    writes it: the measured values) or a CSV of `write_csv` (a file, or a directory with one)."""
    import csv
    import re

    from pcv_sim.rig.rig import signal_kind

    p = Path(path)
    if p.is_dir() and not (p / "metadata.yaml").exists() and not list(p.glob("*.mcap")):
        found = sorted(p.glob("*.csv"))
        if len(found) != 1:
            raise BagError(f"{p}: neither a bag nor a directory with one CSV ({len(found)} found)")
        p = found[0]
    if p.suffix == ".csv":
        with p.open(newline="", encoding="utf-8") as fh:
            rows = list(csv.reader(fh))
        head = [re.match(r"^(.*?)\s*\[(.*)\]$", h) for h in rows[0]]
        data = np.array([[float(x) if x else math.nan for x in r] for r in rows[1:]])
        out = {}
        for j, m in enumerate(head[1:], start=1):
            if m is None or m.group(1).endswith(" measured"):
                continue
            name = m.group(1)
            out[name] = (data[:, 0], data[:, j] * quantity(f"1 {m.group(2)}", signal_kind(name), p.name)
                         if m.group(2) != "-" else data[:, j])
        return out
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    series: dict[str, tuple[list[float], list[float]]] = {}

    def add(name: str, t: float, v: float) -> None:
        ts, vs = series.setdefault(name, ([], []))
        ts.append(t)
        vs.append(v)
    with AnyReader([p], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        for conn, t_ns, raw in reader.messages():
            topic, t = conn.topic, t_ns * 1e-9
            if topic == bag_topic(EVENTS) or topic.startswith(bag_topic(chamber_topic(""))):
                continue
            msg = reader.deserialize(raw, conn.msgtype)
            if topic == bag_topic(cylinder_topic(JOINT_STATES)):
                for field in JOINT_FIELDS:
                    vals = getattr(msg, field)
                    if len(vals):
                        add(f"{CYLINDER}.{field}", t, float(vals[0]))
                continue
            decoded: Any = msg
            value = float(decoded.fluid_pressure) if conn.msgtype == FLUID_PRESSURE else float(decoded.data)
            parts = topic.strip("/").split("/")
            if parts[0] == _FLAGS:
                add(f"{_FLAGS}.{parts[1]}", t, value)
            elif parts == [SETPOINT]:
                add(SETPOINT, t, value)
            elif len(parts) == 2:
                add(f"{parts[0]}.{'duty' if parts[1] == DUTY_CYCLE else parts[1]}", t, value)
    return {k: (np.array(ts), np.array(vs)) for k, (ts, vs) in series.items()}
