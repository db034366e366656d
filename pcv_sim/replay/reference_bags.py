"""The reference bags in ``bags/``: the paper's dynamic test (Sec. 3.2) on the full model.

    pcv-sim reference-bags            # rewrite bags/
    pcv-sim reference-bags --out DIR  # elsewhere

Protocol (Sec. 3.2): zero load flow, 200 bar supply, duty steps at several levels and
amplitudes, decreasing steps rate-limited. The paper gives no rate; its limiter was "tuned so
that the core and spool stay in contact". The model treats core and spool as one body, so it
cannot show a separation; we choose :data:`FALL_RATE` = 2 /s (a fall of 0.1 duty takes 50 ms):
slower than the valve's slowest mode (-45 1/s, 22 ms, docs/model.md), so the spool follows the
falling solenoid force nearly quasi-statically instead of being thrown toward the tank side.
The limiter runs in the 1 kHz command generator, as on a rig, so the bag records the limited
command: replaying it needs no limiter (``command.duty_fall_rate_limit: null``).

Each bag: ``/duty_cycle`` at t0 and at every change (ramps at 1 ms), ``/load_flow`` (0) and
``/supply_pressure`` (200 bar) once at t0, and the full model's ``/pressure``, ``/current`` and
``/spool_position`` every 1 ms (simulate_reference, Radau, rtol 1e-8), quantised to binary steps
near a rig's resolution (pressure 1 Pa, current 2^-20 A ~ 0.95 uA, position 2^-30 m ~ 0.93 nm).

Bit-for-bit: timestamps are integers from a fixed start (2024-01-01T00:00:00Z); chunks end by
size only (no wall-clock flushes: no flush thread, a frozen clock); the MCAP header names the
library ``pcv_sim``; ``metadata.yaml``'s ``ros_distro`` is pinned to ``jazzy`` (the type store
the message definitions come from) whatever ``ROS_DISTRO`` says; the offered QoS is the
emulator's (:data:`pcv_sim.io.topics.ROLE_QOS`). The bytes then depend only on
the code, the default config and the pinned packages (numpy, scipy for the numbers; mcap,
zstandard/libzstd for the container and compression).
"""

from __future__ import annotations

import shutil
from bisect import bisect_right
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Final

import numpy as np

from pcv_sim.io.bag import BagWriter
from pcv_sim.io.topics import (
    BAG_TOPICS,
    CURRENT,
    DUTY_CYCLE,
    LOAD_FLOW,
    PRESSURE,
    ROLE_QOS,
    SPOOL_POSITION,
    SUPPLY_PRESSURE,
    bag_topic,
)
from pcv_sim.model.valve import ValveModel
from pcv_sim.params import ValveParams, load_params
from pcv_sim.simulation.duty import DutyProfile
from pcv_sim.simulation.reference import simulate_reference

__all__ = ["FALL_RATE", "PROTOCOLS", "Protocol", "command_staircase", "deterministic_writer", "write_reference_bag",
           "write_reference_bags"]

FALL_RATE: Final = 2.0                     # 1/s: decreasing duty falls at most 0.002 per 1 ms tick
TICK_NS: Final = 1_000_000                 # command generator and output sample period, 1 ms
START_NS: Final = 1_704_067_200 * 1_000_000_000   # 2024-01-01T00:00:00Z
ROS_DISTRO: Final = "jazzy"
QUANTUM: Final = {PRESSURE: 1.0, CURRENT: 2.0**-20, SPOOL_POSITION: 2.0**-30}
CHUNK_SIZE: Final = 128 * 1024           # uncompressed bytes per MCAP chunk: ~6 chunks per bag
DEFAULT_OUT: Final = Path(__file__).resolve().parents[2] / "bags"


@dataclass(frozen=True)
class Protocol:
    """Duty levels, each held for ``hold_ms`` after it is reached (ramps add their length)."""

    name: str
    description: str
    levels: tuple[float, ...]
    hold_ms: int
    settle_ms: int = 200                   # at the first level before the first step


PROTOCOLS: Final = {
    p.name: p
    for p in (
        Protocol(
            "pcv_step_levels",
            "steps of 0.1 duty at every level: 0.3 up to 1.0, then back down to 0.3",
            (0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0, 0.9, 0.8, 0.7, 0.6, 0.5, 0.4, 0.3),
            300,
        ),
        Protocol(
            "pcv_step_amplitudes",
            "up and down steps of 0.2 to 0.7 duty between levels 0.3 and 1.0",
            (0.5, 0.7, 0.5, 0.3, 1.0, 0.3, 0.6, 0.9, 0.4, 0.8, 0.5),
            400,
        ),
    )
}


def command_staircase(protocol: Protocol, fall_rate: float = FALL_RATE) -> tuple[list[int], list[float], int]:
    """(tick index of each command change, value, total ticks) of the 1 kHz command generator.

    Rises are steps; falls are limited to ``fall_rate`` per second: at tick m after a fall is
    commanded the command is max(target, start - (m + 1) * fall_rate * 1 ms).
    """
    step = fall_rate * TICK_NS / 1e9
    ticks, values = [0], [protocol.levels[0]]
    tick = protocol.settle_ms
    for level in protocol.levels[1:]:
        start = values[-1]
        if level >= start:
            ticks.append(tick)
            values.append(level)
            tick += 1
        else:
            m = 0
            while True:
                v = max(level, round(start - (m + 1) * step, 12))
                ticks.append(tick)
                values.append(v)
                tick += 1
                m += 1
                if v == level:
                    break
        tick += protocol.hold_ms - 1
    return ticks, values, tick


class _Staircase(DutyProfile):
    """A DutyProfile with many breakpoints: O(log n) lookups (DutyProfile's are O(n))."""

    def effective(self, t: float) -> float:
        return self.values[max(bisect_right(self.times, t) - 1, 0)]

    def command(self, t: float) -> float:
        return self.effective(t)

    def breakpoints(self, t_end: float) -> list[float]:
        return sorted({0.0, t_end, *(tk for tk in self.times if tk < t_end)})


def deterministic_writer(path: Path, topics: dict[str, str]) -> BagWriter:
    """A BagWriter whose bytes depend only on what is written: chunks end by size, never by
    wall-clock time. For offline writing (no durability period is needed)."""
    qos = {bag_topic(role): q for role, q in ROLE_QOS.items() if bag_topic(role) in topics}
    return BagWriter(path, topics=topics, qos=qos, ros_distro=ROS_DISTRO, flush_thread=False,
                     clock=lambda: 0.0, chunk_size=CHUNK_SIZE)


def _quantise(x: np.ndarray, q: float) -> np.ndarray:
    return np.round(x / q) * q


def write_reference_bag(protocol: Protocol, out_dir: Path, params: ValveParams | None = None) -> Path:
    """Simulate ``protocol`` on the full model and write ``out_dir/<name>`` (must not exist)."""
    params = params or load_params()
    ticks, values, n_ticks = command_staircase(protocol)
    dt = TICK_NS / 1e9
    profile = _Staircase(tuple(k * dt for k in ticks), tuple(values))
    traj = simulate_reference(ValveModel(params, "full"), profile, n_ticks * dt, sample_time=dt)
    if len(traj.t) != n_ticks + 1 or not np.array_equal(traj.t, np.arange(n_ticks + 1) * dt):
        msg = f"simulate_reference returned {len(traj.t)} samples, expected {n_ticks + 1} on the 1 ms grid"
        raise RuntimeError(msg)
    outputs = {
        PRESSURE: _quantise(traj.pressure, QUANTUM[PRESSURE]),
        CURRENT: _quantise(traj.current, QUANTUM[CURRENT]),
        SPOOL_POSITION: _quantise(traj.spool_position, QUANTUM[SPOOL_POSITION]),
    }
    path = out_dir / protocol.name
    changes = dict(zip(ticks, values))
    duty_t, p_t, i_t, x_t = (bag_topic(r) for r in (DUTY_CYCLE, PRESSURE, CURRENT, SPOOL_POSITION))
    with deterministic_writer(path, dict(BAG_TOPICS)) as w:
        w.write_float64(bag_topic(LOAD_FLOW), START_NS, 0.0)
        w.write_fluid_pressure(bag_topic(SUPPLY_PRESSURE), START_NS, params.circuit.supply_pressure, 0.0)
        p, i, x = (outputs[r].tolist() for r in (PRESSURE, CURRENT, SPOOL_POSITION))
        for k in range(n_ticks + 1):
            t_ns = START_NS + k * TICK_NS
            if k in changes:
                w.write_float64(duty_t, t_ns, changes[k])
            w.write_fluid_pressure(p_t, t_ns, p[k], 0.0)
            w.write_float64(i_t, t_ns, i[k])
            w.write_float64(x_t, t_ns, x[k])
    return path


def write_reference_bags(
    out_dir: Path = DEFAULT_OUT, only: Iterable[str] | None = None, params: ValveParams | None = None
) -> list[Path]:
    """(Re)write the reference bags named in ``only`` (default: all) into ``out_dir``,
    replacing bags of the same name there."""
    names = list(only) if only else sorted(PROTOCOLS)
    if unknown := [n for n in names if n not in PROTOCOLS]:
        msg = f"unknown reference bag(s) {unknown}; accepted: {', '.join(sorted(PROTOCOLS))}"
        raise ValueError(msg)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for name in names:
        target = out_dir / name
        if target.exists():
            shutil.rmtree(target)
        paths.append(write_reference_bag(PROTOCOLS[name], out_dir, params))
    return paths
