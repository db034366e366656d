"""The executables' command line: a params file they cannot use stops them with exit 2, the file and the reason."""
import subprocess
import sys

from .conftest import REPO, clean_child_env

CASES = [
    ('missing.yaml', None, 'cannot read it: No such file or directory'),
    ('syntax.yaml', 'a: [1, 2\n', "not valid YAML: while parsing a flow sequence expected ',' or ']'"),
    ('nested.yaml', '/**:\n  ros__parameters:\n    a: [1, 2]: 3\n',
     'not valid YAML: mapping values are not allowed here at line 3, column 14'),
    # YAML, but not a ROS parameter file: rcl refuses it, and its words come through without C source lines
    ('flat.yaml', 'a: 1\nb: 2\n', "Couldn't parse params file"),
]


def test_a_params_file_that_cannot_be_read_exits_2_naming_the_file_and_the_reason(tmp_path):
    """Both executables read the command line with one function: every case for the emulator, two for the rig."""
    procs = []
    for executable, (name, text, reason) in [*(('emulator', case) for case in CASES),
                                             ('rig', CASES[0]), ('rig', CASES[3])]:
        path = tmp_path / f'{executable}-{name}'
        if text is not None:
            path.write_text(text)
        cmd = [sys.executable, '-m', f'pcv_sim.node.{executable}', '--ros-args', '--params-file', str(path)]
        procs.append((subprocess.Popen(cmd, cwd=REPO, env=clean_child_env(), stdout=subprocess.PIPE,
                                       stderr=subprocess.STDOUT, text=True), executable, path, reason))
    for proc, executable, path, reason in procs:
        out, _ = proc.communicate(timeout=120)
        assert proc.returncode == 2, out
        assert f'{executable}: invalid parameters: ' in out and str(path) in out and reason in out, out
        assert 'Traceback' not in out and '.c:' not in out, out
