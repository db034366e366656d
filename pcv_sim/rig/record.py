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

from pcv_sim.io import FLOAT64, FLUID_PRESSURE, BagWriter
from pcv_sim.io.topics import CURRENT, DUTY_CYCLE, PRESSURE, ROLE_TYPES, SETPOINT, SPOOL_POSITION, bag_topic
from pcv_sim.rig.bag import JOINT_NAME, JOINT_STATE, STRING, RigBagLayout
from pcv_sim.rig.lockstep import RigRun
from pcv_sim.rig.rig import CYLINDER_SIGNALS

__all__ = ["JOINT_STATE", "STRING", "read_signals", "signal_unit", "write_bag", "write_csv"]

_NS = 1_000_000_000


def write_bag(run: RigRun, path: str | Path, *, chambers: dict[str, str] | None = None) -> Path:
    """Write `run` as a rosbag2/MCAP bag at `path` (must not exist); `chambers` maps valve -> a|b.
    The topics are the rig's bag layout (`pcv_sim.rig.bag.RigBagLayout`, the live recording's)."""
    chambers = chambers or {}
    layout = RigBagLayout()
    topics: dict[str, str] = {}
    for v in run.valves:
        topics.update({layout.valve(v, role): ROLE_TYPES[role] for role in (DUTY_CYCLE, PRESSURE, CURRENT, SPOOL_POSITION)})
        if v in chambers:
            topics[layout.chamber(chambers[v])] = FLUID_PRESSURE
    topics[layout.joint_states] = JOINT_STATE
    topics[layout.events] = STRING
    has_sp = bool(np.any(np.isfinite(run.setpoint)))
    if has_sp:
        topics[bag_topic(SETPOINT)] = FLOAT64
    for flag in run.flags:
        topics[f"/controller/{flag.removeprefix('controller.')}"] = FLOAT64
    t_ns = np.round(run.times * _NS).astype(np.int64)
    m = run.measured

    def column(topic: str, values: np.ndarray, w: BagWriter, frame: str = "") -> None:
        ok = np.isfinite(values)       # dropped samples: no message (never a NaN measurement)
        if np.any(ok):
            w.write_samples(t_ns[ok], {topic: values[ok]}, frame_id=frame)

    with BagWriter(path, topics=topics, flush_thread=False) as w:
        for k, v in enumerate(run.valves):
            column(layout.valve(v, DUTY_CYCLE), run.duties[:, k], w)
            p = m[:, run.signals.index(f"{v}.pressure")]
            column(layout.valve(v, PRESSURE), p, w, "load_port")
            if v in chambers:
                column(layout.chamber(chambers[v]), p, w, f"chamber_{chambers[v]}")
            column(layout.valve(v, CURRENT), m[:, run.signals.index(f"{v}.current")], w)
            column(layout.valve(v, SPOOL_POSITION), m[:, run.signals.index(f"{v}.spool_position")], w)
        if has_sp:
            column(bag_topic(SETPOINT), run.setpoint, w)
        for flag, values in run.flags.items():
            column(f"/controller/{flag.removeprefix('controller.')}", values, w)
        pos, vel, eff = (m[:, run.signals.index(f"cylinder.{s}")] for s in CYLINDER_SIGNALS)
        for j in range(len(t_ns)):
            # A dropped signal is left out of the message (JointState allows empty arrays per field).
            fields = [(a[j],) if math.isfinite(a[j]) else () for a in (pos, vel, eff)]
            sec, nsec = divmod(int(t_ns[j]), _NS)
            w.write(layout.joint_states, int(t_ns[j]), {
                "header": {"stamp": {"sec": sec, "nanosec": nsec}, "frame_id": "cylinder"},
                "name": [JOINT_NAME],
                "position": np.array(fields[0], dtype=np.float64), "velocity": np.array(fields[1], dtype=np.float64),
                "effort": np.array(fields[2], dtype=np.float64)})
        for t, text in sorted(run.log + [(t, f"rejected: {r}") for t, r in run.rejected]):
            w.write(layout.events, round(t * _NS), {"data": text})
    return Path(path)


def signal_unit(signal: str) -> str:
    """The SI unit of a run's signal (its column header in a CSV)."""
    from pcv_sim.rig.rig import signal_kind
    from pcv_sim.units import KINDS

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

    from pcv_sim.errors import BagError
    from pcv_sim.rig.rig import signal_kind
    from pcv_sim.units import quantity

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
            if topic == "/rig/events" or topic.startswith("/cylinder/pressure_"):
                continue
            msg = reader.deserialize(raw, conn.msgtype)
            if topic == "/cylinder/joint_states":
                for field in ("position", "velocity", "effort"):
                    vals = getattr(msg, field)
                    if len(vals):
                        add(f"cylinder.{field}", t, float(vals[0]))
                continue
            decoded: Any = msg
            value = float(decoded.fluid_pressure) if conn.msgtype == FLUID_PRESSURE else float(decoded.data)
            parts = topic.strip("/").split("/")
            if parts[0] == "controller":
                add(f"controller.{parts[1]}", t, value)
            elif parts == ["setpoint"]:
                add("setpoint", t, value)
            elif len(parts) == 2:
                add(f"{parts[0]}.{'duty' if parts[1] == 'duty_cycle' else parts[1]}", t, value)
    return {k: (np.array(ts), np.array(vs)) for k, (ts, vs) in series.items()}
