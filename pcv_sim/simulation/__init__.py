"""The simulation core: the model interface (`system`), composition, compiled fixed-step
integrators (`compile`, `simulator`), the stiff reference (`reference`), rest states (`rest`),
the valve's stepper (`stepper`) and the real-time schedules (`clock`). See docs/architecture.md."""

from pcv_sim.simulation.simulator import Simulator
from pcv_sim.simulation.system import CompositionError, Kernel, Stop, System, compose

__all__ = ["CompositionError", "Kernel", "Simulator", "Stop", "System", "compose"]
