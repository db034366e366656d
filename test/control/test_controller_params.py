"""The example controller's gains and settings from their one declaration
(pcv_sim.control.params.PositionControllerParams): the keyword constructor, a scenario's
`controller_params` and a change between periods are checked by it, with its messages."""
import dataclasses
import re

import pytest

from pcv_sim.control.params import PositionControllerParams, controller_params
from pcv_sim.control.steering import PositionController
from pcv_sim.errors import ParameterError
from pcv_sim.rig.scenario import ScenarioError, resolve_controller

AMPS = 12.0 / 5.6


def sample(setpoint=0.01, position=0.0):
    return {"cylinder.position": position, "cylinder.velocity": 0.0, "setpoint": setpoint,
            "left.current": AMPS * 0.6, "right.current": AMPS * 0.6}


def test_the_keywords_are_the_declarations_with_their_defaults():
    c = PositionController()
    assert c.params == PositionControllerParams()
    assert (c.kp, c.ki, c.kv, c.base, c.period, c.fault_time, c.current_loop) == (15.0, 30.0, 0.5, 0.6, 1e-3, 0.02, 0.0)
    assert c.amps_per_duty == pytest.approx(12.0 / 5.6)
    given = PositionController(kp=20, current_loop="20 ms", coil_volts=24)      # a unit, as a file may give it
    assert (given.kp, given.current_loop, given.amps_per_duty) == (20.0, 0.02, pytest.approx(24.0 / 5.6))
    assert PositionController(PositionControllerParams(kp=20.0)).kp == 20.0


@pytest.mark.parametrize(("values", "message"), [
    ({"kp": -15.0}, r"^kp: got -15.0; accepted is a gain in 0 \.\. 10000 \(duty/m\)$"),
    ({"ki": float("nan")}, r"^ki: got nan; accepted is a finite number$"),
    ({"base": 0.2}, r"^base: got 0.2; accepted is a duty where the valve regulates in 0.3 \.\. 1$"),
    ({"period": 0.0}, r"^period: got 0.0; accepted is a plausible value 0.0001 \.\. 1 \(s\)$"),
    ({"fault_time": 0.0}, r"^fault_time: got 0.0; accepted is a duration > 0 and <= 10 \(s\)$"),
    ({"coil_ohm": "5.6 bar"}, r"^coil_ohm: got '5.6 bar' \(str\); accepted is a number in ohm$"),
    ({"current_loop": "20 bar"}, r"^current_loop: unit 'bar' in '20 bar' \(bar is a unit of pressure\); accepted for "
                                 r"a time are s, ms"),
    ({"current_loop": -1.0}, r"^current_loop: got -1.0; accepted is a time constant in 0 \.\. 10 \(s\)$"),
    ({"kv": True}, r"^kv: got True \(bool\); accepted is a number in duty/\(m/s\)$"),
    ({"kpp": 1.0}, r"^PositionController: unknown key 'kpp' \(did you mean 'kp'\?\); accepted: kp, ki, kv, base, "
                   r"period, fault_time, coil_volts, coil_ohm, current_loop$"),
])
def test_a_refused_value_names_the_key_and_what_is_accepted(values, message):
    with pytest.raises(ParameterError, match=message):
        PositionController(**values)
    with pytest.raises(ParameterError, match=message):
        controller_params(values)


def test_params_and_keywords_together_are_refused():
    with pytest.raises(TypeError, match="not both"):
        PositionController(PositionControllerParams(), kp=1.0)


def test_a_scenario_s_controller_params_are_checked_by_the_declarations():
    spec = "pcv_sim.control.steering:PositionController"
    assert resolve_controller(spec, {"kp": 20.0, "current_loop": "20 ms"}, None).params == \
        PositionControllerParams(kp=20.0, current_loop=0.02)
    with pytest.raises(ScenarioError, match=r"^controller_params: current_loop: got -1; accepted is a time constant "
                                            r"in 0 \.\. 10 \(s\)$"):
        resolve_controller(spec, {"current_loop": -1}, None)
    with pytest.raises(ScenarioError, match=r"^controller_params: PositionController: unknown key 'kpp' "
                                            r"\(did you mean 'kp'\?\)"):
        resolve_controller(spec, {"kpp": 1}, None)


def test_a_scenario_s_controller_params_are_checked_on_load_naming_the_file(tmp_path):
    """A scenario file's controller_params for a callable with declarations (check_params) are refused
    when the file is loaded, not when the run builds the controller: the file, the key and the
    declaration's message; a callable without them is checked when built, as before."""
    import yaml

    from pcv_sim.rig.scenario import load_scenario, scenario_from_mapping

    scenario = {"duration": 0.01, "controller": "pcv_sim.control.steering:PositionController",
                "controller_params": {"kp": 20.0, "current_loop": -1}}
    path = tmp_path / "bad_gains.yaml"
    path.write_text(yaml.safe_dump(scenario))
    with pytest.raises(ScenarioError, match=rf"^{re.escape(str(path))}: controller_params: current_loop: got -1; "
                                            r"accepted is a time constant in 0 \.\. 10 \(s\)$"):
        load_scenario(path)
    with pytest.raises(ScenarioError, match=r"^scenario: controller_params: PositionController: unknown key 'kpp' "
                                            r"\(did you mean 'kp'\?\)"):
        scenario_from_mapping({**scenario, "controller_params": {"kpp": 1.0}})
    ok = scenario_from_mapping({**scenario, "controller_params": {"kp": 20.0, "current_loop": "20 ms"}})
    assert ok.controller_params == {"kp": 20.0, "current_loop": "20 ms"}
    assert resolve_controller(ok.controller, ok.controller_params, None).params == \
        PositionControllerParams(kp=20.0, current_loop=0.02)
    (tmp_path / "derived.py").write_text("from pcv_sim.control.steering import PositionController\n\n\n"
                                         "class Derived(PositionController):\n"
                                         "    def __init__(self, fail_at):\n        super().__init__()\n")
    derived = scenario_from_mapping({**scenario, "controller": "derived:Derived", "controller_params": {"fail_at": 1}},
                                    path=tmp_path / "s.yaml")       # its own keywords: not its base's check
    assert resolve_controller(derived.controller, derived.controller_params, tmp_path).params == \
        PositionControllerParams()
    (tmp_path / "plain.py").write_text("def make(gain):\n    return lambda t, m: {'left': gain}\n")
    loose = scenario_from_mapping({**scenario, "controller": "plain:make", "controller_params": {"gains": 1}},
                                  path=tmp_path / "s.yaml")
    with pytest.raises(ScenarioError, match=r"^controller_params: plain:make does not take them"):
        resolve_controller(loose.controller, loose.controller_params, tmp_path)


def test_retune_changes_the_gains_from_the_next_period_and_keeps_the_state():
    """A retuned controller goes on from its integral and held samples; a fresh one with the same
    gains would not: the next period is the retuned one's, not the fresh one's."""
    c = PositionController()
    for k in range(50):
        c(k * 1e-3, sample())
    integral = c.integral
    assert integral > 0
    new = dataclasses.replace(c.params, kp=30.0, ki=60.0)
    c.retune(new)
    assert c.params is new and c.integral == integral
    out = c(0.05, {"setpoint": 0.01})                        # a sample dropped: the held measurements
    error = 0.01
    u = 30.0 * error + 60.0 * integral                       # the new gains on the state carried over
    assert out["left"] == pytest.approx(0.6 + min(u, 0.35))
    fresh = PositionController(new)(0.05, sample())
    assert fresh["left"] != out["left"]
