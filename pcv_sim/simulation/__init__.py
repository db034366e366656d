"""The simulation core: the model interface (`system`), composition, compiled fixed-step
integrators (`compile`, `simulator`), the stiff reference (`reference`), rest states (`rest`),
the valve as a system and its inputs (`valve`), duty profiles and the fall-rate limiter (`duty`)
and the real-time schedules (`clock`). The valve at the fixed step with everything around it is
a device (`pcv_sim.device.valve.ValveDevice`). See docs/architecture.md."""

from pcv_sim.simulation.simulator import Simulator
from pcv_sim.simulation.system import CompositionError, Kernel, Stop, System, compose

__all__ = ["CompositionError", "Kernel", "Simulator", "Stop", "System", "compose"]
