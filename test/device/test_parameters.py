"""Parameter plumbing: command-line overrides rcl drops, unknown names, duplicate keys."""
import pytest

from pcv_sim.device.parameters import (
    check_params_files,
    command_line_overrides,
    override_not_taken,
    params_files,
    parse_override_value,
    ros_arguments_message,
    unknown_parameters_message,
)
from pcv_sim.errors import ParameterError


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


def test_a_params_file_that_cannot_be_read_or_is_not_yaml_is_refused_naming_file_and_reason(tmp_path):
    missing = tmp_path / 'missing.yaml'
    with pytest.raises(ParameterError, match=f'--params-file {missing}: cannot read it: No such file'):
        check_params_files(['emulator', '--ros-args', '--params-file', str(missing)])
    bad = tmp_path / 'bad.yaml'
    bad.write_text('/**:\n  ros__parameters:\n    a: [1, 2]: 3\n')
    with pytest.raises(ParameterError, match='not valid YAML: mapping values are not allowed here at line 3, column 14'):
        check_params_files(['emulator', '--ros-args', '--params-file', str(bad)])


def test_rcl_refusals_lose_their_c_source_locations():
    err = RuntimeError("Failed to parse ROS arguments: Couldn't parse params file: '--params-file f.yaml'. Error: "
                       "Cannot have a value before ros__parameters at line 7\n, at /project/src/parse.c:835, at "
                       "/project/src/rcl/arguments.c:415")
    assert ros_arguments_message(err) == ("Couldn't parse params file: '--params-file f.yaml'. Error: Cannot have a "
                                          "value before ros__parameters at line 7")
