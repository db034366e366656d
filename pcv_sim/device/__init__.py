"""The emulated devices around the model, without ROS: what the nodes adapt.

`device`: the one device (valves and an optional plant in one simulator, and everything around
the model: inputs at their steps, watchdogs, the fall-rate limiter, stepping), built on its parts:
`spec` (what it composes and hands out, as data), `composition` (its simulator and layout, time,
fault state), `restarts`, `feed` (fed inputs), `injection` (injected faults; `faults` what a
fault is, `sensors` sensor faults), `outputs` (samples and records, the physical limits of
`limits` checked before they leave); `inputs`: the one timing rule, the queue, a watchdog;
`valve`: the emulator's configuration of it,
one valve and no plant (the rig's, valves on the cylinder, is `pcv_sim.rig.rig`); `settings`:
the node's settings, declared once and validated like the valve YAML; `recording`: a device's
bag layout and its recorder, live and offline; `parameters`: the
command-line and params-file checks rcl does not do; `diagnostics`: the device's health per
concern. A new system plugs into a device here without touching ROS code (the node only moves
messages). Covered by the test that nothing outside `pcv_sim/node` imports ROS.
"""

__all__ = [
    "composition", "device", "diagnostics", "faults", "feed", "injection", "inputs", "limits", "outputs",
    "parameters", "recording", "restarts", "sensors", "settings", "spec", "valve",
]
