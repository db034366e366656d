"""The emulated device around the model, without ROS: what the `emulator` node adapts.

`valve`: one valve (`ValveDevice`: inputs at their steps, watchdog, faults, physical limits,
samples, the recorder hook); `settings`: the node's settings, declared once and validated like
the valve YAML; `parameters`: the command-line and params-file checks rcl does not do;
`diagnostics`: the device's health per concern. A new system plugs into a device here without
touching ROS code (the node only moves messages). Covered by the test that nothing outside
`pcv_sim/node` imports ROS.
"""

__all__ = ["diagnostics", "parameters", "settings", "valve"]
