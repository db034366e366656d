"""A duty step at zero load flow (the paper's dynamic test, Sec. 3.2): pressure, current and
spool position over time (Fig. 11 style) with rise time, overshoot, settling time and steady
state. `--model simplified` runs the emulator's device (`ValveDevice`: its stepping, fall-rate
limiter and physical limits); `--model full` runs
the full model (with damping chamber) on scipy's stiff Radau solver. The steady state is the
static solution at the final duty (the zero-flow equilibrium), not the window's end: a --duration
shorter than the settling is warned about. --damping names the simplified model's damping
(equivalent, the default; paper: Table 1's 223.6 Ns/m; or a number)."""

from __future__ import annotations

import argparse
import math
import sys

import numpy as np

from pcv_sim.analysis.in_force import in_force, with_damping
from pcv_sim.analysis.metrics import step_metrics
from pcv_sim.analysis.static import EquilibriumError, zero_flow_equilibrium
from pcv_sim.commands.common import add_output_options, damping_option, emit_json, fraction, params_from, positive, save
from pcv_sim.device.valve import ValveDevice
from pcv_sim.errors import PcvSimError, UsageError
from pcv_sim.io.topics import CURRENT, DUTY_CYCLE, OUTPUT_ROLES, PRESSURE, ROLE_UNITS, SPOOL_POSITION
from pcv_sim.model.valve import ValveModel
from pcv_sim.params import ValveParams
from pcv_sim.plotting import pyplot
from pcv_sim.replay.compare import DISPLAY
from pcv_sim.simulation.duty import DutyProfile
from pcv_sim.simulation.reference import simulate_reference
from pcv_sim.simulation.trajectory import Trajectory

NAME = "step"
HELP = "simulate a duty step and report rise time, overshoot, settling time, steady state"

#: (role, axis label, scale from SI, settling band in SI): the outputs as replay shows them
SIGNALS = tuple((role, f"{d.label} [{d.unit}]", d.scale, d.band_min) for role, d in DISPLAY.items())


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--from", dest="start", type=fraction, required=True, metavar="D0", help="duty before the step (0..1)")
    p.add_argument("--to", dest="end", type=fraction, required=True, metavar="D1", help="duty after the step (0..1)")
    p.add_argument("--at", type=positive, default=0.02, help="step time [s] (default: %(default)s)")
    p.add_argument("--duration", type=positive, default=0.4, help="simulated time [s] (default: %(default)s)")
    p.add_argument("--model", choices=("simplified", "full"), default="simplified",
                   help="simplified: the emulator's device; full: stiff reference with chamber (default: %(default)s)")
    p.add_argument("--fall-rate", type=positive, default=None, metavar="PER_S",
                   help="rate-limit decreasing duty to this many duty units per second (default: the config's)")
    p.add_argument("--damping", type=damping_option, default=None, metavar="equivalent|paper|NS_PER_M",
                   help="the simplified model's damping (default: the config's)")
    add_output_options(p)


def step_params(args: argparse.Namespace) -> ValveParams:
    return with_damping(params_from(args), getattr(args, "damping", None))


def simulate_step(args: argparse.Namespace) -> Trajectory:
    params = step_params(args)
    rate = args.fall_rate if args.fall_rate is not None else params.command.duty_fall_rate_limit
    if args.at >= args.duration:
        raise UsageError(f"--at {args.at:g} s is not before --duration {args.duration:g} s")
    profile = DutyProfile.step(args.start, args.end, args.at, rate)
    if args.model == "full":
        return simulate_reference(ValveModel(params, "full"), profile, args.duration)
    from pcv_sim.params import replace_param

    return device_step(replace_param(params, "command.duty_fall_rate_limit", rate), profile, args.duration)


def device_step(params: ValveParams, profile: DutyProfile, duration: float) -> Trajectory:
    """The emulator's device at rest at the profile's first duty, each command acting from the
    first step at or after its time, sampled at every step to `duration` (from 0; a sample shows
    the duty in force from its step on). PcvSimError when the model stops (the device's fault)."""
    dev = ValveDevice(params, safe_duty=profile.values[0], watchdog_timeout=0.0, sample_every=1)
    dt = dev.dt
    for t, duty in zip(profile.times, profile.values, strict=True):
        dev.submit(DUTY_CYCLE, duty, at_step=math.ceil(t / dt - 1e-9))
    dev.run_to(0)                                      # what is due at step 0 acts before its sample
    samples = [dev.valve_sample(), *dev.run(round(duration / dt))]
    if dev.fault is not None:
        raise PcvSimError(f"the model stopped: {dev.fault}")
    return Trajectory(np.array([s.step * dt for s in samples]), np.array([s.duty for s in samples]),
                      np.array([s.current for s in samples]), np.array([s.pressure for s in samples]),
                      np.array([s.spool_position for s in samples]))


def steady_state(args: argparse.Namespace) -> dict[str, float] | None:
    """The static solution at the final duty, zero load flow: pressure, current, spool position."""
    try:
        eq = zero_flow_equilibrium(ValveModel(step_params(args), args.model), args.end)
    except EquilibriumError:
        return None
    return {PRESSURE: eq.pressure, CURRENT: eq.current, SPOOL_POSITION: eq.spool_position}


def run(args: argparse.Namespace) -> int:
    traj = simulate_step(args)
    static = steady_state(args)
    window = {name: step_metrics(traj.t, getattr(traj, name), args.at, band_min=band) for name, _, _, band in SIGNALS}
    metrics = {name: step_metrics(traj.t, getattr(traj, name), args.at, band_min=band,
                                  final=static[name] if static else None)
               for name, _, _, band in SIGNALS}
    unsettled = [name for name, _, _, _ in SIGNALS
                 if math.isnan(metrics[name].settling_time)
                 or abs(window[name].final - metrics[name].final) > metrics[name].band]
    warnings = []
    if static is None:
        warnings.append(f"no static solution at duty {args.end:g}: the steady state is the window's end")
    elif unsettled:
        warnings.append(
            f"--duration {args.duration:g} s ends before the response settles ({', '.join(unsettled)} outside "
            f"its band at the end); the steady state is the static solution at duty {args.end:g}; "
            f"settling times past the window are n/a: lengthen --duration")
    state = in_force(step_params(args), args.model)
    for w in warnings:
        print(f"pcv-sim step: warning: {w}", file=sys.stderr)
    if args.json:
        emit_json({"model": args.model, "from": args.start, "to": args.end, "step_time_s": args.at,
                   "in_force": state.as_dict(),
                   "steady_state": "static solution" if static else "window end",
                   "metrics": {k: v.as_dict() for k, v in metrics.items()}, "warnings": warnings,
                   "units": {**{r: ROLE_UNITS[r] for r in OUTPUT_ROLES}, "times": "s"}})
    else:
        print(f"Duty step {args.start:g} -> {args.end:g} at {args.at:g} s, {args.model} model")
        print(f"  in force: {state.text()}")
        print(f"  steady state: {'the static solution at the final duty' if static else 'the window end'}")
        print("  signal                 initial      final   rise [ms]   overshoot [%]   settling [ms]")
        for name, label, scale, _ in SIGNALS:
            m = metrics[name]
            print(f"  {label:20s} {m.initial * scale:9.3f} {m.final * scale:10.3f} {m.rise_time * 1e3:11.2f}"
                  f" {m.overshoot_percent:15.2f} {m.settling_time * 1e3:15.2f}")
    if args.plot:
        plt = pyplot()
        fig, axes = plt.subplots(3, 1, figsize=(8, 8), sharex=True)
        for ax, (name, label, scale, _) in zip(axes, SIGNALS):
            ax.plot(traj.t * 1e3, getattr(traj, name) * scale)
            ax.set_ylabel(label)
            ax.grid(True, alpha=0.3)
        axes[0].set_title(f"duty {args.start:g} -> {args.end:g} ({args.model} model), cf. Fig. 11")
        axes[-1].set_xlabel("time [ms]")
        save(fig, args.plot)
    return 0
