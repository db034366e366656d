"""A device's topics follow from its names (io/topics.py input_topics, output_topics): the one node
class serves the emulator and the rig from these tables, so they carry the pinned topic names."""
from pcv_sim.io.bag import FLOAT64, FLUID_PRESSURE
from pcv_sim.io.topics import JOINT_STATE, input_topics, output_topics


def test_the_emulators_inputs_and_outputs_are_its_bare_names():
    inputs = input_topics(('load_flow', 'duty_cycle', 'supply_pressure', 'oil_temperature'), ('valve',))
    assert [(e.topic, e.type, e.input, e.answers) for e in inputs] == [
        ('duty_cycle', FLOAT64, 'duty_cycle', 'valve'),           # the duty first: a lockstep waits on it
        ('load_flow', FLOAT64, 'load_flow', ''),
        ('supply_pressure', FLUID_PRESSURE, 'supply_pressure', ''),
        ('oil_temperature', FLOAT64, 'oil_temperature', ''),
    ]
    outputs = output_topics(('pressure', 'current', 'spool_position', 'coil_temperature'))
    assert [(o.topic, o.type, o.signals, o.frame_id) for o in outputs] == [
        ('pressure', FLUID_PRESSURE, ('pressure',), ''),           # '': the node's frame_id setting
        ('current', FLOAT64, ('current',), ''),
        ('spool_position', FLOAT64, ('spool_position',), ''),
        ('coil_temperature', FLOAT64, ('coil_temperature',), ''),
    ]


def test_the_rigs_topics_are_per_valve_with_the_cylinder_as_one_joint_state_and_the_chambers_again():
    inputs = input_topics(('cylinder.external_force', 'right.duty_cycle', 'left.duty_cycle', 'left.oil_temperature'),
                          ('left', 'right'))
    assert [(e.topic, e.input, e.answers) for e in inputs] == [
        ('left/duty_cycle', 'left.duty_cycle', 'left'),           # in the order of the valves
        ('right/duty_cycle', 'right.duty_cycle', 'right'),
        ('cylinder/external_force', 'cylinder.external_force', ''),
        ('left/oil_temperature', 'left.oil_temperature', ''),
    ]
    signals = ('left.pressure', 'left.current', 'right.pressure', 'cylinder.position', 'cylinder.velocity',
               'cylinder.effort')
    outputs = output_topics(signals, {'left': 'a', 'right': 'b'})
    assert [(o.topic, o.type, o.signals, o.frame_id) for o in outputs] == [
        ('left/pressure', FLUID_PRESSURE, ('left.pressure',), ''),
        ('left/current', FLOAT64, ('left.current',), ''),
        ('right/pressure', FLUID_PRESSURE, ('right.pressure',), ''),
        ('cylinder/pressure_a', FLUID_PRESSURE, ('left.pressure',), 'chamber_a'),
        ('cylinder/pressure_b', FLUID_PRESSURE, ('right.pressure',), 'chamber_b'),
        ('cylinder/joint_states', JOINT_STATE, ('cylinder.position', 'cylinder.velocity', 'cylinder.effort'),
         'cylinder'),
    ]
    # A device without the cylinder's three signals has no joint state.
    assert all(o.type != JOINT_STATE for o in output_topics(signals[:3]))
