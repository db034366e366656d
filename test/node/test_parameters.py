"""Parameter plumbing: command-line overrides rcl drops, unknown names, duplicate keys."""
import pytest

from pcv_sim.errors import ParameterError
from pcv_sim.node.parameters import (
    check_params_files, command_line_overrides, override_not_taken, parse_override_value, params_files,
    unknown_parameters_message,
)

START = 60.0


# --- without ROS ------------------------------------------------------------------------------

def test_command_line_overrides_are_read_as_rcl_types_them():
    argv = ['emulator', '--ros-args', '--params-file', 'a.yaml', '-p', 'watchdog_timeout:=abc',
            '--param', 'publish_rate:=500', '-p', 'emulator:frame_id:=x', '-p', 'other_node:frame_id:=y',
            '-r', '__ns:=/left', '--', 'not', '-p', 'ignored:=1',
            '--ros-args', '-p', 'model.fluid.bulk_modulus:=1e9', '-p', 'record.signals:=[pressure, current]']
    cli = command_line_overrides(argv, 'emulator')
    assert {k: v.value for k, v in cli.items()} == {
        'watchdog_timeout': 'abc', 'publish_rate': 500, 'frame_id': 'x', 'model.fluid.bulk_modulus': 1e9,
        'record.signals': ['pressure', 'current']}
    assert cli['watchdog_timeout'].argument == '-p watchdog_timeout:=abc'
    assert params_files(argv) == ['a.yaml']


@pytest.mark.parametrize(('text', 'value'), [('1e9', 1e9), ('2', 2), ('2.0', 2.0), ('true', True), ('abc', 'abc'),
                                             ("''", ''), ('[1, 2]', [1, 2])])
def test_parse_override_value(text, value):
    got = parse_override_value(text)
    assert got == value and type(got) is type(value)


def test_override_not_taken():
    cli = command_line_overrides(['e', '--ros-args', '-p', 'a:=abc', '-p', 'b:=2', '-p', 'c:=[1.0, 2.0]'], 'e')
    assert override_not_taken(cli['a'], 2.0)                  # rcl kept the params file's 2.0
    assert not override_not_taken(cli['a'], 'abc')
    assert not override_not_taken(cli['b'], 2)
    assert override_not_taken(cli['b'], 3.0)
    assert not override_not_taken(cli['c'], [1.0, 2.0])


def test_unknown_names_get_the_closest_accepted_name():
    msg = unknown_parameters_message(['watchdog_timout', 'zzz'], ['watchdog_timeout', 'safe_duty'])
    assert msg.startswith('unknown parameter(s) watchdog_timout (did you mean watchdog_timeout?), zzz; accepted are')


def test_a_duplicate_key_in_a_params_file_is_refused_with_key_and_line(tmp_path):
    f = tmp_path / 'emulator.yaml'
    f.write_text('/**:\n  ros__parameters:\n    safe_duty: 0.3\n    watchdog_timeout: 1.0\n    safe_duty: 0.5\n')
    with pytest.raises(ParameterError, match=r"--params-file .*emulator\.yaml: duplicate key 'safe_duty' at line 5 "
                                             r"\(first at line 3\)"):
        check_params_files(['e', '--ros-args', '--params-file', str(f)])


# --- the node ---------------------------------------------------------------------------------

def test_bad_command_lines_are_refused_at_start(ros):
    shipped = 'config/emulator.yaml'
    dup = ros.tmp_path / 'dup.yaml'
    dup.write_text('/**:\n  ros__parameters:\n    safe_duty: 0.3\n    safe_duty: 0.5\n')
    cases = [
        # rcl keeps the file's 2.0 for a string override: refused, not run silently with 2.0
        (['--params-file', shipped, '-p', 'watchdog_timeout:=abc'],
         "watchdog_timeout: got 'abc' (str); accepted is a number in s"),
        (['--params-file', shipped, '-p', 'model.spool.mass:=heavy'], "model.spool.mass: got 'heavy'"),
        (['--params-file', shipped, '-p', 'watchdog_timout:=1.0'],
         'unknown parameter(s) watchdog_timout (did you mean watchdog_timeout?)'),
        (['--params-file', str(dup)], "duplicate key 'safe_duty' at line 4 (first at line 3)"),
    ]
    procs = [(ros.start(f'bad{k}', args=args), message) for k, (args, message) in enumerate(cases)]
    for emu, message in procs:
        rc = emu.wait(START)
        out = emu.output()
        assert rc == 2, f'{emu.cmd}: exit {rc}\n{out}'
        assert 'emulator: invalid parameters: ' in out and message in out, out
        assert 'Traceback' not in out


def test_an_override_rcl_dropped_for_its_type_is_applied_and_unknown_names_can_be_tolerated(ros):
    f = ros.tmp_path / 'p.yaml'
    f.write_text('/**:\n  ros__parameters:\n    diagnostics_period: 0.2\n    watchdog_timeout: 2.0\n'
                 '    other_nodes_key: 1\n    allow_unknown_parameters: true\n')
    emu = ros.start(args=['--params-file', str(f), '-p', 'watchdog_timeout:=3'])      # int against the file's float
    c = ros.client()
    assert c.wait_for_emulator(START), emu.output()
    diag = c.wait_for_diagnostics(timeout=10)
    assert diag['watchdog_timeout_s'] == '3', diag
    assert 'ignoring unknown parameter(s) (allow_unknown_parameters): other_nodes_key' in emu.output()
