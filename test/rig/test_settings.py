"""The rig node's settings without ROS (pcv_sim.rig.settings): checked by name, cross-checked with the
rig's step, and the settings every node shares declared once, as the emulator's."""
import pytest


@pytest.mark.parametrize('name, value, match', [
    ('time_mode', 'fast', r"time_mode: got 'fast'; accepted is one of 'real', 'simulated'"),
    ('real_time_factor', -1.0, r'real_time_factor: got -1.0; accepted is a number >= 0'),
    ('control_period', -0.001, r'control_period'),
    ('seed', -1, r'seed'),
    ('nope', 1, r"unknown parameter 'nope'; accepted are: rig_config"),
])
def test_rig_parameters_are_checked_by_name(name, value, match):
    from pcv_sim.errors import ParameterError
    from pcv_sim.rig.settings import check_rig_value

    with pytest.raises(ParameterError, match=match):
        check_rig_value(name, value)


def test_settings_cross_check_the_rig_step_and_override_the_control_period():
    from pcv_sim.errors import ParameterError
    from pcv_sim.rig import load_rig
    from pcv_sim.rig.settings import RigNodeSettings

    rig = load_rig()
    assert RigNodeSettings(control_period=0.01).rig_params(rig).steps_per_period == 100
    assert RigNodeSettings().rig_params(rig) is rig
    with pytest.raises(ParameterError, match=r'wake_period 0.00025 s is not a whole multiple of the model step'):
        RigNodeSettings(wake_period=2.5e-4).check(rig)
    with pytest.raises(ParameterError, match=r'max_catchup: got 0.0005; accepted is a number >= wake_period'):
        RigNodeSettings(max_catchup=5e-4).check(rig)


def test_the_rig_declares_every_setting_all_nodes_share_as_the_emulator_does():
    """One declaration (pcv_sim.device.settings.CommonSettings): the real-time loop's settings (overrun
    and realtime_priority too), diagnostics, the rejection log and the bag's place."""
    import dataclasses

    from pcv_sim.device.settings import NODE_PARAMETERS, CommonSettings
    from pcv_sim.errors import ParameterError
    from pcv_sim.rig.settings import RIG_PARAMETERS, RigNodeSettings, check_rig_value

    common = [f.metadata["name"] or f.name for f in dataclasses.fields(CommonSettings)]
    rig, emulator = {p.name: p for p in RIG_PARAMETERS}, {p.name: p for p in NODE_PARAMETERS}
    assert {"overrun", "realtime_priority", "wake_period", "max_catchup"} <= set(common)
    for name in common:
        assert (rig[name].default, rig[name].unit, rig[name].description, rig[name].read_only) == \
               (emulator[name].default, emulator[name].unit, emulator[name].description, emulator[name].read_only)
    assert RigNodeSettings().catchup_bound == 0.05
    assert RigNodeSettings(overrun="skip").catchup_bound == 1e-3            # one wake period
    with pytest.raises(ParameterError, match=r"realtime_priority: got 100; accepted is an integer 0..99"):
        check_rig_value("realtime_priority", 100)


def test_the_watchdog_is_declared_once_for_every_device_with_the_emulators_default():
    """watchdog_timeout and safe_duty: one declaration (pcv_sim.params.WatchdogParams) for the emulator's
    settings and the rig YAML's `rig:`, the rig node's `rig.<key>` parameters too: the same default
    (2 s, which a rig YAML may leave out), range and refusal; the shipped rig states the default."""
    import dataclasses
    import re

    import yaml

    from pcv_sim.device.settings import SCHEMA, NodeSettings
    from pcv_sim.device.valve import ValveDevice
    from pcv_sim.errors import ParameterError
    from pcv_sim.node.kinds import RIG_PREFIX, _rig_with
    from pcv_sim.params import WatchdogParams, default_params
    from pcv_sim.rig.params import DEFAULT_RIG, TimingParams, load_rig, rig_from_mapping

    one = {f.name: f for f in dataclasses.fields(WatchdogParams)}
    for cls in (NodeSettings, TimingParams):
        fields = {f.name: f for f in dataclasses.fields(cls)}
        for key, f in one.items():
            assert (fields[key].default, dict(fields[key].metadata)) == (f.default, dict(f.metadata)), (cls, key)
    assert (WatchdogParams().watchdog_timeout, WatchdogParams().safe_duty) == (2.0, 0.0)

    data = yaml.safe_load(DEFAULT_RIG.read_text())
    shipped = load_rig().timing
    assert (shipped.watchdog_timeout, shipped.safe_duty) == (2.0, 0.0)
    for key in ("watchdog_timeout", "safe_duty"):
        del data["rig"][key]
    left_out = rig_from_mapping(data, base=DEFAULT_RIG.parent).timing
    assert (left_out.watchdog_timeout, left_out.safe_duty) == (NodeSettings().watchdog_timeout, NodeSettings().safe_duty)
    with pytest.raises(ParameterError, match=r"missing key\(s\) rig\.time_step$"):       # the others stay required
        rig_from_mapping({**data, "rig": {k: v for k, v in data["rig"].items() if k != "time_step"}})
    dev = ValveDevice(default_params())
    assert dev.safe_duty == 0.0 and dev.watchdogs[dev.valve_names[0]].timeout_steps == round(2.0 / dev.dt)

    rig = load_rig()
    assert _rig_with(rig, {f"{RIG_PREFIX}watchdog_timeout": 60.0}).timing.watchdog_timeout == 60.0
    for value in (-0.5, 60.5):
        refusal = re.escape(f"got {value!r}; accepted is a duration in 0 .. 60 (s)")
        with pytest.raises(ParameterError, match=rf"^watchdog_timeout: {refusal}$"):
            SCHEMA.check("watchdog_timeout", value)
        with pytest.raises(ParameterError, match=rf"^rig.watchdog_timeout: {refusal}$"):
            _rig_with(rig, {f"{RIG_PREFIX}watchdog_timeout": value})
        data["rig"]["watchdog_timeout"] = value
        with pytest.raises(ParameterError, match=rf"^rig: rig.watchdog_timeout: {refusal} \(model time"):
            rig_from_mapping(data, base=DEFAULT_RIG.parent)
    data["rig"]["watchdog_timeout"] = 2.0
    refusal = re.escape("got 1.5; accepted is a duty fraction 0..1")
    with pytest.raises(ParameterError, match=rf"^safe_duty: {refusal}$"):
        SCHEMA.check("safe_duty", 1.5)
    with pytest.raises(ParameterError, match=rf"^rig.safe_duty: {refusal}$"):
        _rig_with(rig, {f"{RIG_PREFIX}safe_duty": 1.5})
