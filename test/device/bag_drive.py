"""One scripted run of each device fed to a recorder through the node's hooks (`attach`, `begin`,
`shown`, `reset`, `close`, as `pcv_sim.node.device_node` calls them), so that bags written by two
versions of the recorder can be compared message by message (test_bag_layout.py; the reference bags
in test/device/data were written by the recorder before the layouts became one)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from mcap.reader import make_reader

#: Model time 0 of the scripted runs (ns).
T0 = 1_700_000_000_000_000_000


def drive(dev: Any, recorder: Any, steps: int, script: dict[int, list[tuple[str, Any]]]) -> Any:
    """`dev` run for `steps` model steps with `recorder` on its hooks; `script[k]`: what acts at step k
    (`(input name, value)`, `("fault", command)`, `("reset", None)`, `("watchdog", timeout s)`)."""
    recorder.attach(dev)
    dev.origin_ns = T0
    recorder.begin(dev)
    first = dev.present_sample()
    recorder.shown(dev, first, dev.measure(first).tolist())
    per = dev.sample_every
    due = sorted(script)
    while dev.steps < steps:
        for k in [k for k in due if k <= dev.steps]:
            due.remove(k)
            for what, value in script[k]:
                if what == "fault":
                    assert dev.submit_fault(value, k) is None
                elif what == "reset":
                    dev.install(dev.prepare())
                    recorder.reset(dev)
                elif what == "watchdog":
                    dev.set_watchdog_timeout(value)
                else:
                    assert dev.submit(what, value, k) is None
        stop = min(steps, (dev.steps // per + 1) * per, *(k for k in due if k > dev.steps))
        for sample in dev.run_to(stop):
            recorder.shown(dev, sample, dev.measure(sample).tolist())
    return recorder.close()


#: The emulator: a duty step, a supply and a load flow change, a physical and a sensor fault, a reset.
EMULATOR_SCRIPT: dict[int, list[tuple[str, Any]]] = {
    100: [("duty_cycle", 0.7)],
    250: [("supply_pressure", 150e5)],
    300: [("load_flow", 1e-6)],
    350: [("fault", "{fault: coil_short, resistance_factor: 0.5}")],
    420: [("fault", "{fault: bias, signal: pressure, value: 1.0e+5}")],
    455: [("reset", None)],
    520: [("duty_cycle", 0.3)],
}
#: The rig: duty steps, a force, a supply change, the watchdog firing, a physical fault and its
#: clearing, sensor faults (a dropout: no message), a reset.
RIG_SCRIPT: dict[int, list[tuple[str, Any]]] = {
    0: [("watchdog", 0.04)],
    50: [("left.duty_cycle", 0.7), ("right.duty_cycle", 0.3)],
    120: [("cylinder.external_force", 500.0), ("left.supply_pressure", 150e5)],
    200: [("fault", "{fault: coil_open, valve: left}")],
    260: [("fault", "{fault: dropout, signal: right.current}")],
    300: [("fault", "{fault: bias, signal: cylinder.velocity, value: 0.01}")],
    380: [("fault", "{clear: coil_open, valve: left}"), ("left.duty_cycle", 0.6)],
    640: [("reset", None)],
    700: [("right.duty_cycle", 0.55)],
}


def emulator_run(make: Callable[..., Any], directory: Path, name: str, dev: Any, **kw: Any) -> Any:
    """The emulator's script through `make(directory, name=name, **kw)`, 0.06 s."""
    return drive(dev, make(directory, name=name, **kw), 600, EMULATOR_SCRIPT)


def rig_run(make: Callable[..., Any], directory: Path, name: str, dev: Any, **kw: Any) -> Any:
    """The rig's script through `make(directory, name=name, **kw)`, 0.08 s."""
    return drive(dev, make(directory, name=name, **kw), 800, RIG_SCRIPT)


def messages(bag: Path) -> dict[str, Any]:
    """Every channel of a bag with its type, QoS metadata and messages (log time, publish time,
    bytes) in order, read with the mcap reader."""
    out: dict[str, Any] = {}
    for f in sorted(bag.glob("*.mcap")):
        with f.open("rb") as fh:
            reader = make_reader(fh)
            summary = reader.get_summary()
            assert summary is not None
            for ch in summary.channels.values():
                schema = summary.schemas[ch.schema_id]
                out.setdefault(ch.topic, {"type": schema.name, "encoding": ch.message_encoding,
                                          "metadata": dict(ch.metadata), "messages": []})
            for _schema, ch, msg in reader.iter_messages(log_time_order=False):
                out[ch.topic]["messages"].append((msg.log_time, msg.publish_time, bytes(msg.data)))
    return out
