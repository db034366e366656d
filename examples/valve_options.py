"""The valve off the paper's bench (docs/model.md R33-R35): three example runs and their plot.

    .venv-kilted/bin/python examples/valve_options.py [--out docs/img/valve_options.png]

- cold start: ISO VG 46 at -20 degC warming to 40 degC over a minute, at the emulator's 0.1 ms
  step (the cold oil makes the spool's damping pole ~100x faster; the exponential integrator takes
  it exactly), duty stepping 50 <-> 70 % every 5 s: the response slows and overshoots in the cold;
- coil heating: 90 % duty for 20 minutes, open loop (the coil warms, its resistance rises, the
  current and the pressure fall) and with a PI controller closing the loop on pressure (the
  duty rises to hold it);
- fast release with core-spool separation: 100 % -> 0 % -> 60 %, without and with the paper's
  fall-rate limit (2 /s): without it the spool stops on its end stop and the core flies on by a
  few micrometres (the gap); the solenoid brings it back when the duty returns. Inside the stroke
  they never part (docs/model.md R35: Sec. 3.2's undershoot is not reproduced).

The same three on the rig (two valves on the steering cylinder, under a controller) are scenario
files beside this one: cold_start.yaml, coil_heating.yaml, coil_heating_closed_loop.yaml,
fast_release.yaml and fast_release_limited.yaml (`pcv-sim scenario run FILE --report out/`).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from pcv_sim.device.valve import VALVE, ValveDevice
from pcv_sim.params import default_params, replace_param
from pcv_sim.units import PA_PER_BAR, kelvin

REPO = Path(__file__).resolve().parents[1]


def _params(**changes):
    p = default_params()
    for key, value in changes.items():
        p = replace_param(p, key.replace("__", "."), value)
    return p


def _device(params, duty: float) -> ValveDevice:
    """The emulator's device at rest at `duty`, its watchdog off."""
    return ValveDevice(params, safe_duty=duty, watchdog_timeout=0.0)


def _signal(dev: ValveDevice, name: str) -> float:
    """A signal of the device by its name at the present step (SI)."""
    return float(dev.sample()[dev.signals.index(name)])


def cold_start() -> dict[str, np.ndarray]:
    dev = _device(_params(fluid__temperature="input", fluid__oil_temperature_c=-20.0), 0.5)
    t, p, oil = [], [], []
    for k in range(60_000):                         # 60 s in 1 ms samples
        if k % 5000 == 0:
            dev.set_duty(VALVE, 0.7 if (k // 5000) % 2 else 0.5)
        dev.set_temperature(VALVE, "oil_temperature", kelvin(-20.0 + 60.0 * min(1.0, k / 60_000)))
        dev.advance_to(dev.steps + 10)
        t.append(dev.time)
        p.append(_signal(dev, "pressure") / PA_PER_BAR)
        oil.append(dev.temperature(VALVE, "oil_temperature") - kelvin(0.0))
    return {"t": np.array(t), "p": np.array(p), "oil": np.array(oil)}


def coil_heating(closed_loop: bool) -> dict[str, np.ndarray]:
    dev = _device(_params(solenoid__coil_temperature="lumped", solenoid__coil_reference_temperature_c=40.0), 0.9)
    target, integral = _signal(dev, "pressure"), 0.0
    t, p, i, temp, duty = [], [], [], [], []
    for _ in range(1200 * 10):                      # 20 min, the controller at 10 Hz
        if closed_loop:
            err = (target - _signal(dev, "pressure")) / PA_PER_BAR
            integral += 0.1 * err
            dev.set_duty(VALVE, min(1.0, max(0.0, 0.9 + 0.002 * err + 0.002 * integral)))
        dev.advance_to(dev.steps + 1000)
        s = dev.valve_sample()
        t.append(dev.time)
        p.append(s.pressure / PA_PER_BAR)
        i.append(s.current)
        temp.append(_signal(dev, "coil_temperature") - kelvin(0.0))
        duty.append(s.duty)
    return {"t": np.array(t), "p": np.array(p), "i": np.array(i), "T": np.array(temp), "duty": np.array(duty)}


def release(limit: float | None) -> dict[str, np.ndarray]:
    dev = _device(_params(spool__core="separate", command__duty_fall_rate_limit=limit), 1.0)
    dev.set_duty(VALVE, 0.0)
    t, p, gap = [], [], []
    for k in range(8000):                           # 0.8 s in 0.1 ms steps
        if k == 1000:
            dev.set_duty(VALVE, 0.6)
        dev.advance_to(dev.steps + 1)
        t.append(dev.time)
        p.append(_signal(dev, "pressure") / PA_PER_BAR)
        gap.append((_signal(dev, "spool_position") - _signal(dev, "core_position")) * 1e3)
    return {"t": np.array(t), "p": np.array(p), "gap": np.array(gap)}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default=str(REPO / "docs" / "img" / "valve_options.png"))
    args = ap.parse_args()
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cold = cold_start()
    hot_open, hot_closed = coil_heating(False), coil_heating(True)
    fast, limited = release(None), release(2.0)
    fig, ax = plt.subplots(3, 2, figsize=(12, 10))
    ax[0, 0].plot(cold["t"], cold["p"])
    ax[0, 0].set(title="cold start: duty 50 <-> 70 %, oil -20 -> 40 degC", xlabel="s", ylabel="pressure, bar")
    ax[0, 1].plot(cold["t"], cold["oil"])
    ax[0, 1].set(title="oil temperature (input)", xlabel="s", ylabel="degC")
    for run, label in ((hot_open, "duty 90 % (open loop)"), (hot_closed, "PI on pressure")):
        ax[1, 0].plot(run["t"] / 60, run["p"], label=label)
        ax[1, 1].plot(run["t"] / 60, run["T"], label=f"coil temperature, {label}")
    ax[1, 0].set(title="coil heating: pressure", xlabel="min", ylabel="bar")
    ax[1, 1].set(title="coil temperature", xlabel="min", ylabel="degC")
    for a in ax[1]:
        a.legend()
    for run, label in ((fast, "no rate limit"), (limited, "fall rate limit 2 /s")):
        ax[2, 0].plot(run["t"] * 1e3, run["p"], label=label)
        ax[2, 1].plot(run["t"] * 1e3, run["gap"], label=label)
    ax[2, 0].set(title="release 100 -> 0 %, 60 % after 100 ms: pressure", xlabel="ms", ylabel="bar")
    ax[2, 1].set(title="core-spool gap", xlabel="ms", ylabel="mm")
    for a in ax[2]:
        a.legend()
    fig.tight_layout()
    fig.savefig(args.out, dpi=80)
    print(f"wrote {args.out}")
    print(f"coil heating, open loop: current {hot_open['i'][0]:.3f} -> {hot_open['i'][-1]:.3f} A, pressure "
          f"{hot_open['p'][0]:.1f} -> {hot_open['p'][-1]:.1f} bar, coil {hot_open['T'][-1]:.1f} degC; "
          f"closed loop: duty {hot_closed['duty'][0]:.3f} -> {hot_closed['duty'][-1]:.3f}, "
          f"pressure {hot_closed['p'][-1]:.1f} bar")


if __name__ == "__main__":
    main()
