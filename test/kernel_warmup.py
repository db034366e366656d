"""The composites the test session compiles before its first test (`conftest.compiled_kernels`), each
built once so that its kernels are in the disk cache (`pcv_sim.jit.cache_root()`): both valve models,
the shipped rig (two valves and the cylinder), the options rig and the valve with every option.

Run as a script it builds the ones named on its command line: the session's second process, which
compiles its share beside the session's own (the cache takes two writers: `pcv_sim.jit`)."""
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent


def write_options_rig(directory, thermal_resistance=1.0, heat_capacity=1.0):
    """The shipped rig plus a valve `probe` on its own load volume with the options of docs/model.md
    R33, R34 that bring inputs: a lumped coil (ambient temperature in; coil temperature and resistance
    out; by default a 1 s thermal time constant, so a short run sees it warm) and an oil temperature
    input; no watchdog. Written into `directory`; returns the rig YAML's path."""
    import yaml

    valve = yaml.safe_load((REPO / 'config' / 'valve.yaml').read_text())
    valve['solenoid'].update(coil_temperature='lumped', coil_thermal_resistance=thermal_resistance,
                             coil_heat_capacity=heat_capacity)
    valve['fluid']['temperature'] = 'input'
    (directory / 'probe.yaml').write_text(yaml.safe_dump(valve))
    rig = yaml.safe_load((REPO / 'config' / 'rig.yaml').read_text())
    for slot in rig['valves'].values():
        slot['config'] = str(REPO / 'config' / 'valve.yaml')
    rig['rig']['watchdog_timeout'] = 0.0
    rig['valves']['probe'] = {'config': str(directory / 'probe.yaml'), 'chamber': 'none', 'initial_duty': 0.0}
    (directory / 'rig.yaml').write_text(yaml.safe_dump(rig))
    return directory / 'rig.yaml'


def _valve(kind):
    from pcv_sim.device.valve import ValveDevice
    from pcv_sim.params import default_params, replace_param

    ValveDevice(replace_param(default_params(), 'simulation.model', kind))     # loads what it steps with


def _rig():
    from pcv_sim.rig import Rig, load_rig

    Rig(load_rig())          # compiles (or loads) what the rig node and the lockstep call


def _options_rig():
    # A third valve with the options, a kernel of its own, which a rig node test starts: compiled in
    # its process beside other tests' load it outlasted START (90 s).
    from pcv_sim.rig import Rig, load_rig

    with tempfile.TemporaryDirectory() as directory:
        Rig(load_rig(write_options_rig(Path(directory))))


def _options_valve():
    # the emulator's with every option (test/node/test_emulator_options.py)
    from pcv_sim.device.valve import ValveDevice
    from pcv_sim.params import default_params, replace_param

    options = default_params()
    for key, value in (('solenoid.coil_temperature', 'lumped'), ('fluid.temperature', 'input'),
                       ('spool.core', 'separate')):
        options = replace_param(options, key, value)
    ValveDevice(options)


#: name -> what builds it
BUILDS = {'simplified': lambda: _valve('simplified'), 'full': lambda: _valve('full'), 'rig': _rig,
          'options_rig': _options_rig, 'options_valve': _options_valve}
#: The two processes' shares, about equal in compile time (empty cache, a quiet machine: options rig
#: ~54 s, rig ~33 s, options valve ~19 s, each valve model ~16 s); the session's own first.
IN_SESSION = ('options_rig', 'simplified')
BESIDE = ('rig', 'options_valve', 'full')


def build(names):
    for name in names:
        BUILDS[name]()


if __name__ == '__main__':
    unknown = sorted(set(sys.argv[1:]) - set(BUILDS))
    if unknown:
        sys.exit(f"unknown composites {', '.join(unknown)}; accepted: {', '.join(BUILDS)}")
    build(sys.argv[1:])
