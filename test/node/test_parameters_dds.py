"""Command lines and params files refused or applied by the running node (pcv_sim.device.parameters checks them)."""


START = 60.0


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
    # the descriptors say doc, accepted range and unit, from the declarations (as the controller node's)
    from rcl_interfaces.srv import DescribeParameters

    from pcv_sim.params import WatchdogParams, declarations

    request = DescribeParameters.Request(names=['watchdog_timeout', 'time_mode', 'publish_rate'])
    timeout, mode, rate = c.call(DescribeParameters, f'{c.device_name}/describe_parameters', request, 10).descriptors
    doc = declarations(WatchdogParams)['watchdog_timeout'].metadata['description']
    assert timeout.description == f'{doc}; accepted 0 .. 60 [s]'
    assert mode.description.endswith('; accepted real | simulated [-]') and mode.read_only
    assert rate.description.endswith('; accepted > 0 [Hz]')
    assert 'ignoring unknown parameter(s) (allow_unknown_parameters): other_nodes_key' in emu.output()
