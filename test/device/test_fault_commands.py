"""Fault commands (the `faults` topic's one line of YAML, every device's: pcv_sim.device.faults) parsed
with a rig's targets: its valves, the cylinder and its measured signals; refused saying what is
accepted."""
import pytest

from pcv_sim.device.faults import FaultError, parse_fault_command

VALVES = ('left', 'right')


def _parse(text):
    return parse_fault_command(text, valves=VALVES, signals=('left.pressure', 'cylinder.position'))


def test_fault_commands_parse_with_the_rigs_fault_table():
    cmd = _parse('{fault: supply_drop, valve: right, pressure: 8.0e+6}')
    assert (cmd.clear, cmd.kind, cmd.target, dict(cmd.fault.values)) == (False, 'supply_drop', 'right',
                                                                         {'pressure': 8e6})
    cmd = _parse('{fault: bias, signal: left.pressure, value: 1.0e+5}')
    assert cmd.fault.sensor and cmd.target == 'left.pressure'
    cmd = _parse('{fault: supply_drop, valve: right, pressure: 80 bar}')      # a unit, as in a scenario file
    assert dict(cmd.fault.values) == {'pressure': pytest.approx(8e6)}
    cmd = _parse('{fault: drift, signal: left.pressure, rate: 0.5 bar/s}')   # the signal's unit per second
    assert dict(cmd.fault.values) == {'rate': pytest.approx(5e4)}
    cmd = _parse('{clear: supply_drop, valve: right}')      # no values needed to clear it
    assert (cmd.clear, cmd.kind, cmd.target, cmd.fault) == (True, 'supply_drop', 'right', None)


@pytest.mark.parametrize('text, match', [
    ('[coil_open, left]', r'accepted is a YAML mapping such as \{fault: coil_open, valve: left\}'),
    ('{fault: coil_open', r'is not YAML'),
    ('{fault: coil_open, clear: coil_open, valve: left}', r"needs exactly one of 'fault' or 'clear'"),
    ('{fault: coil_open}', r"needs exactly one of 'valve' \(a physical fault: left, right\)"),
    ('{fault: coil_opn, valve: left}', r"kind 'coil_opn'; accepted are supply_drop"),
    ('{fault: coil_open, valve: middle}', r"target 'middle' for coil_open; accepted are left, right"),
    ('{fault: supply_drop, valve: left}', r'supply_drop\.pressure: missing; accepted is the supply pressure under the fault \(Pa\)'),
    ('{fault: supply_drop, valve: left, pressure: 5.0e+9}', r'supply_drop\.pressure: got 5000000000\.0; accepted is a supply pressure in 0 \.\. 4e\+07 \(Pa\)'),
    ('{fault: supply_drop, valve: left, pressure: 80 mm}', r"supply_drop\.pressure: unit 'mm' in '80 mm' \(mm is a unit "
                                                          r"of length\); accepted for a pressure are Pa"),
    ('{fault: supply_drop, valve: left, pressure: 80}', r'80 is 80 Pa, below any supply pressure; did you mean 80 bar\?'),
    ('{fault: bias, signal: left.pressure, value: 2 mA}', r"bias\.value: unit 'mA' in '2 mA'"),
    ('{clear: coil_open, valve: left, x: 1}', r'clear takes no values \(x\)'),
    ('{clear: coil_opn, valve: left}', r"kind 'coil_opn'"),
])
def test_bad_fault_commands_are_refused_saying_what_is_accepted(text, match):
    with pytest.raises(FaultError, match=match):
        _parse(text)
