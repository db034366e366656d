"""A lockstep run as a bag and as an HTML report. Rendering only: every number is the run's.

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
"""

from __future__ import annotations

import base64
import html
import io
import math
from pathlib import Path
from typing import Any

import numpy as np

from pcv_sim.io import FLOAT64, FLUID_PRESSURE, BagWriter
from pcv_sim.io.topics import (
    CURRENT,
    DUTY_CYCLE,
    JOINT_STATES,
    PRESSURE,
    ROLE_TYPES,
    SETPOINT,
    SPOOL_POSITION,
    bag_topic,
    chamber_topic,
    cylinder_topic,
    valve_topic,
)
from pcv_sim.rig.lockstep import RigRun
from pcv_sim.units import PA_PER_BAR

__all__ = ["JOINT_STATE", "STRING", "plot_run", "render_html", "write_bag"]

JOINT_STATE = "sensor_msgs/msg/JointState"
STRING = "std_msgs/msg/String"
_NS = 1_000_000_000
JOINTS = bag_topic(cylinder_topic(JOINT_STATES))
EVENTS = "/rig/events"          # the run's log and refused commands (offline bags only)


def write_bag(run: RigRun, path: str | Path, *, chambers: dict[str, str] | None = None) -> Path:
    """Write `run` as a rosbag2/MCAP bag at `path` (must not exist); `chambers` maps valve -> a|b."""
    chambers = chambers or {}
    topics: dict[str, str] = {}
    for v in run.valves:
        topics.update({bag_topic(valve_topic(v, role)): ROLE_TYPES[role]
                       for role in (DUTY_CYCLE, PRESSURE, CURRENT, SPOOL_POSITION)})
        if v in chambers:
            topics[bag_topic(chamber_topic(chambers[v]))] = FLUID_PRESSURE
    topics[JOINTS] = JOINT_STATE
    topics[EVENTS] = STRING
    has_sp = bool(np.any(np.isfinite(run.setpoint)))
    if has_sp:
        topics[bag_topic(SETPOINT)] = FLOAT64
    t_ns = np.round(run.times * _NS).astype(np.int64)
    m = run.measured

    def column(topic: str, values: np.ndarray, w: BagWriter, frame: str = "") -> None:
        ok = np.isfinite(values)       # dropped samples: no message (never a NaN measurement)
        if np.any(ok):
            w.write_samples(t_ns[ok], {topic: values[ok]}, frame_id=frame)

    with BagWriter(path, topics=topics, flush_thread=False) as w:
        for k, v in enumerate(run.valves):
            column(bag_topic(valve_topic(v, DUTY_CYCLE)), run.duties[:, k], w)
            p = m[:, run.signals.index(f"{v}.pressure")]
            column(bag_topic(valve_topic(v, PRESSURE)), p, w, "load_port")
            if v in chambers:
                column(bag_topic(chamber_topic(chambers[v])), p, w, f"chamber_{chambers[v]}")
            column(bag_topic(valve_topic(v, CURRENT)), m[:, run.signals.index(f"{v}.current")], w)
            column(bag_topic(valve_topic(v, SPOOL_POSITION)), m[:, run.signals.index(f"{v}.spool_position")], w)
        if has_sp:
            column(bag_topic(SETPOINT), run.setpoint, w)
        pos, vel, eff = (m[:, run.signals.index(f"cylinder.{s}")] for s in ("position", "velocity", "effort"))
        for j in range(len(t_ns)):
            # A dropped signal is left out of the message (JointState allows empty arrays per field).
            fields = [(a[j],) if math.isfinite(a[j]) else () for a in (pos, vel, eff)]
            sec, nsec = divmod(int(t_ns[j]), _NS)
            w.write(JOINTS, int(t_ns[j]), {
                "header": {"stamp": {"sec": sec, "nanosec": nsec}, "frame_id": "cylinder"},
                "name": ["steering"],
                "position": np.array(fields[0], dtype=np.float64), "velocity": np.array(fields[1], dtype=np.float64),
                "effort": np.array(fields[2], dtype=np.float64)})
        for t, text in sorted(run.log + [(t, f"rejected: {r}") for t, r in run.rejected]):
            w.write(EVENTS, round(t * _NS), {"data": text})
    return Path(path)


def plot_run(run: RigRun, path: str | Path | None = None, *, title: str = "") -> bytes:
    """A PNG of the run: position vs setpoint, chamber pressures, duties, currents (bytes; also
    written to `path` when given)."""
    from pcv_sim.plotting import pyplot

    plt = pyplot()
    fig, ax = plt.subplots(4, 1, figsize=(8, 9), sharex=True)
    t = run.times
    ax[0].plot(t, run.signal("cylinder.position") * 1e3, label="position")
    if np.any(np.isfinite(run.setpoint)):
        ax[0].plot(t, run.setpoint * 1e3, "--", label="setpoint")
    ax[0].set_ylabel("piston [mm]")
    for v in run.valves:
        ax[1].plot(t, run.signal(f"{v}.pressure") / PA_PER_BAR, label=v)
        ax[2].plot(t, run.signal(f"{v}.duty"), label=v)
        ax[3].plot(t, run.signal(f"{v}.current"), label=v)
    ax[1].set_ylabel("pressure [bar]")
    ax[2].set_ylabel("duty [-]")
    ax[3].set_ylabel("current [A]")
    ax[3].set_xlabel("time [s]")
    for a in ax:
        a.grid(True, alpha=0.3)
        a.legend(loc="best", fontsize=8)
    for t_ev, _text in run.log:
        for a in ax:
            a.axvline(t_ev, color="0.6", lw=0.8, ls=":")
    if title:
        ax[0].set_title(title)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    plt.close(fig)
    data = buf.getvalue()
    if path is not None:
        Path(path).write_bytes(data)
    return data


def render_html(result: Any) -> str:
    """An HTML report of a `ScenarioResult`: verdict, assertions, events, plots."""
    esc = html.escape
    rows = "".join(
        f"<tr><td>{esc(o.name)}</td><td style='color:{'green' if o.passed else 'red'}'>"
        f"{'pass' if o.passed else 'FAIL'}</td><td>{esc(o.detail)}</td></tr>" for o in result.outcomes)
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>{esc(result.name)}</title></head><body>",
             f"<h1>Scenario {esc(result.name)}: {'passed' if result.passed else 'FAILED'}</h1>",
             f"<p>{esc(result.path)}; real-time factor {result.real_time_factor:.1f}x "
             f"({result.wall_time:.3f} s wall)</p>"]
    if result.error:
        parts.append(f"<p style='color:red'>{esc(result.error)}</p>")
    parts.append("<table border='1' cellpadding='4'><tr><th>assertion</th><th>result</th><th>found</th></tr>"
                 f"{rows}</table>")
    run = result.run
    if run is not None:
        events = "".join(f"<li>{t:.4f} s: {esc(text)}</li>" for t, text in run.log)
        rejected = len(run.rejected)
        parts.append(f"<h2>Events</h2><ul>{events or '<li>none</li>'}</ul><p>rejected commands: {rejected}</p>")
        png = base64.b64encode(plot_run(run, title=result.name)).decode()
        parts.append(f"<h2>Run</h2><img alt='run' src='data:image/png;base64,{png}'>")
    parts.append("</body></html>")
    return "\n".join(parts)
