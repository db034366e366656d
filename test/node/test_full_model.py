"""The emulator running the full model (with the damping chamber) in real time at 0.1 ms, on the
compiled core, under CPU load: its bag replays exactly with the same engine, and sits within a
tenth of a bar of the stiff reference solver."""
import signal

from pcv_sim.params import load_params, replace_param
from pcv_sim.replay import load_recording, replay

FULL = replace_param(load_params(), 'simulation.model', 'full')


def test_full_model_emulator_bag_replays_exactly_and_near_radau(ros, cpu_load):
    emu = ros.start(params={'model.simulation.model': 'full', 'safe_duty': 0.4, 'watchdog_timeout': 0.0,
                            'max_catchup': 10.0, 'record.enabled': True, 'record.directory': str(ros.tmp_path),
                            'record.name': 'full'})
    c = ros.client()
    assert c.wait_for_emulator(60.0), emu.output()
    c.spin_for(0.1)
    for duty in (0.7, 0.5):
        c.send_duty(duty)
        c.spin_for(0.3)
    end_ns = c.duty_sent[-1][1] + 300_000_000
    assert c.spin_until(lambda: c.samples[-1].stamp_ns > end_ns, 60), 'the emulator stopped publishing'
    assert emu.stop(signal.SIGINT) == 0, emu.output()
    assert 'erk2' in emu.output()                    # the node says which model and integrator run

    rec = load_recording(ros.tmp_path / 'full')
    exact = replay(rec, FULL, model='full')          # the emulator's own engine: the same arithmetic
    assert exact.signals['pressure'].fit.max_error < 1.0, exact.signals['pressure'].fit     # Pa
    assert exact.signals['current'].fit.max_error < 1e-6, exact.signals['current'].fit
    stiff = replay(rec, FULL, model='full', solver='radau')
    assert stiff.signals['pressure'].fit.max_error < 0.1e5, stiff.signals['pressure'].fit
    assert len(exact.steps) == 2 and stiff.signals['pressure'].fit.nrmse_fit_percent > 99.9
