"""A composite of systems at a fixed step: its state, its held inputs, batches of compiled steps.

`Simulator` is what every fixed-step user runs (the emulator's device, replay, the rig, the
benchmarks): one state vector for all systems, inputs held over each step (zero-order hold),
`advance(n)` running n steps of the chosen integrator in compiled code, and `outputs()` giving
every output at the present time with the inputs in force from now on (right-continuous).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

import numpy as np

from pcv_sim.jit import compiled_for
from pcv_sim.simulation.compile import INTEGRATORS, arena_layout, compiled_module, exponential_weights, pack_tables
from pcv_sim.simulation.system import Composite, System, compose

__all__ = ["Simulator"]

#: `advance_sample`'s feed and bounds when there are none (always these types: one compiled
#: specialisation).
_NO_FEED = (np.zeros(0, dtype=np.int64), np.zeros((0, 0)), -1)
_NO_BOUNDS = (np.zeros(0), np.zeros(0))


class Simulator:
    """Fixed-step simulation of a `Composite` (or one `System`)."""

    def __init__(self, plant: Composite | System, dt: float, integrator: str = "rk2") -> None:
        if isinstance(plant, System):
            plant = compose([plant])
        if integrator not in INTEGRATORS:
            raise ValueError(f"integrator {integrator!r}: accepted are {', '.join(INTEGRATORS)}")
        if not (np.isfinite(dt) and dt > 0.0):
            raise ValueError(f"time step {dt!r} s: accepted is a finite number > 0")
        self.plant = plant
        self.dt = float(dt)
        self.integrator = integrator
        module = compiled_module(plant)
        self._module = module
        # The compiled entry points take the arena (every array below is a view of it), the flat
        # tables and their layout: a call from Python unboxes 3 arrays, not ~40.
        self._advance = getattr(module, f"sim_advance_{integrator}")
        self._run = getattr(module, f"sim_run_{integrator}")
        self._advance_sample = getattr(module, f"sim_advance_sample_{integrator}")
        self._sample = getattr(module, f"sim_sample_{integrator}")        # the same without a fed row
        self._sample_entry: Callable[..., float] | None = None       # `sample_entry`, made on first use
        self._outputs = module.sim_outputs
        self._derivs = module.derivs
        self._project = module.project
        self._layout = arena_layout(plant)
        self._S = np.zeros(max(b for _, b in self._layout.values()))
        self._views()
        self._Fa, self._FL, self.F = pack_tables(plant)
        self.P[:] = np.concatenate([s.p for s in plant.systems])
        for s, off in zip(plant.systems, plant.offsets("workspace")):
            self.W[off:off + len(s.w0)] = s.w0
        self.refresh_rates()
        self.steps = 0
        # Every entry's machine code carries its own copy of what it calls (the integrator loop,
        # derivs, project); a process runs the copies of the entry it loaded first, wherever it calls
        # from. Where that code lies changes a step's time by several % (BENCHMARKS.md, Rig), so
        # `sim_advance` is loaded first, always: the same copies in every process whatever is called
        # first (zero steps: nothing changes).
        self._advance(self._S, self._Fa, self._FL, 0, 0, self.dt)

    def _views(self) -> None:
        """x, u, P, W, Y, U, the scratch and the weights as views of the arena."""
        self._use({name: self._S[a:b] for name, (a, b) in self._layout.items()})

    def _use(self, v: Mapping[str, np.ndarray]) -> None:
        self.x, self.u, self.P, self.W, self.Y, self.U = v["x"], v["u"], v["P"], v["W"], v["Y"], v["U"]
        self._E, self._A, self._B = v["E"], v["A"], v["B"]
        self._parts = v

    @property
    def arena(self) -> np.ndarray:
        """The one array the compiled code steps (`compile.arena_layout`: state, inputs, parameters,
        workspace, outputs, scratch, weights): a copy of it is the whole state, and writing a copy
        back restores it. The same array for the simulator's life (`copy` makes a new one)."""
        return self._S

    @property
    def tables(self) -> np.ndarray:
        """The systems' fit tables, flat (`compile.pack_tables`); written in place, e.g. by a batch
        that holds the tables of several copies one after the other."""
        return self._Fa

    @property
    def table_layout(self) -> tuple[int, ...]:
        """Where each table is in `tables` and its shape (the structure of the systems' tables)."""
        return tuple(self._FL.tolist())

    def runs_like(self, other: Simulator) -> bool:
        """Whether `other` runs the same compiled code on an arena of the same layout and tables:
        its arena's values may then be written into this one's (`arena[:] = other.arena`)."""
        return (other._module is self._module and other._S.shape == self._S.shape
                and other.integrator == self.integrator and np.array_equal(other._Fa, self._Fa)
                and np.array_equal(other._FL, self._FL))

    def bind(self, parts: Mapping[str, np.ndarray]) -> None:
        """Hand the arrays to another arena that is stepped in this simulator's place (a batch's:
        `parts` are views there, one per part of `compile.arena_layout`, of its length): the
        values go there and x, u, P, ... become those views, so what is written to them is where
        that arena is stepped. Nothing steps this simulator itself until `unbind`."""
        for name, (a, b) in self._layout.items():
            parts[name][:] = self._S[a:b]
        self._use(parts)

    def unbind(self) -> None:
        """After `bind`: the values back into the simulator's own arena, its arrays its own again."""
        if self._parts["x"].base is self._S:
            return
        for name, (a, b) in self._layout.items():
            self._S[a:b] = self._parts[name]
        self._views()

    def rates(self) -> np.ndarray:
        """Each state's linear decay rate (1/s) for the exponential integrator: the declared stiff
        rates, and those read from the parameters (`System.rate_parameters`) as they are now."""
        rates = self.plant.rates.copy()
        for i, j in self.plant.rate_parameters:
            rates[i] = self.P[j]
        return rates

    def refresh_rates(self) -> None:
        """Recompute the exponential weights after a rate parameter changed (in `P`)."""
        self._E[:], self._A[:], self._B[:] = exponential_weights(self.rates(), self.dt)

    def copy(self) -> Simulator:
        """An independent simulator in the same state (its own arrays, the same compiled code)."""
        new = object.__new__(Simulator)
        new.__dict__.update(self.__dict__)      # the tables are shared: nothing writes them
        new._S = self._S.copy()
        new._views()
        return new

    def __deepcopy__(self, memo: dict[int, object]) -> Simulator:
        return self.copy()          # compiled functions and their module are shared, not copied

    @property
    def time(self) -> float:
        """Model time (s): an integer count of steps, so it never drifts."""
        return self.steps * self.dt

    def advance(self, n: int = 1) -> None:
        """n fixed steps with the present inputs (held)."""
        if n <= 0:
            return
        self._advance(self._S, self._Fa, self._FL, n, self.steps, self.dt)
        self.steps += n

    def advance_sample(self, n: int, select: np.ndarray, out: np.ndarray, after: int = 0,
                       feed: tuple[np.ndarray, np.ndarray, int] | None = None,
                       bounds: tuple[np.ndarray, np.ndarray] | None = None) -> float:
        """`advance(n)`, `outputs()[select]` into `out`, then `advance(after)`, in one compiled
        call: what a loop that samples every few steps (the rig's lockstep) runs. `feed` =
        (indices, values, row): before the outputs, `u[indices[j]] = values[row, j]` (indices
        int64, values a C-contiguous float64 matrix; NaN leaves that input as it is), the inputs
        due at the sampled step. `bounds` = (lo, hi), float64: lo[i] <= out[i] <= hi[i] for the
        first len(lo) sampled outputs. Returns the sum of the squared states: not finite if and
        only if the state ran away or a sampled output is outside its bounds."""
        n, after = max(int(n), 0), max(int(after), 0)
        feed_i, feed_v, row = feed if feed is not None else _NO_FEED
        lo, hi = bounds if bounds is not None else _NO_BOUNDS
        norm = self._advance_sample(self._S, self._Fa, self._FL, n, self.steps, self.dt, select, out, after,
                                    feed_i, feed_v, row, lo, hi)
        self.steps += n + after
        return float(norm)

    def sample_entry(self) -> tuple[Callable[..., float], tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """`advance_sample` without a fed row, as compiled code, and its first three arguments (the
        arena, the tables and their layout), for a loop that calls it every few steps and cannot
        afford the method's Python: `fn(*arrays, n, steps, dt, select, out, after, lo, hi)` with
        n, after >= 0 (the same numbers as `advance_sample(n, select, out, after, bounds=(lo, hi))`);
        the caller then adds n + after to `steps`. It is the machine code for exactly these argument
        types (`jit.compiled_for`: no dispatch, nothing checked): ints, a float, int64 `select`,
        float64 `lo` and `hi` and a C-contiguous float64 vector `out` of `select`'s length; the
        caller passes only arrays it made so. The arrays stay the simulator's for its life (`copy`
        makes new ones)."""
        entry = self._sample_entry
        if entry is None:
            entry = self._sample_entry = compiled_for(
                self._sample, self._S, self._Fa, self._FL, 0, 0, self.dt, _NO_FEED[0], np.empty(0), 0, *_NO_BOUNDS)
        return entry, (self._S, self._Fa, self._FL)

    def run(self, change_steps: np.ndarray, change_values: np.ndarray, sample_steps: np.ndarray) -> np.ndarray:
        """Run to the last of `sample_steps` (absolute, sorted, >= the present step) in compiled code:
        external inputs `change_values[c]` act from step `change_steps[c]` on (sorted); returns
        every output (rows) at each sample step, with the inputs due at that step in force."""
        change_steps = np.ascontiguousarray(change_steps, dtype=np.int64)
        change_values = np.ascontiguousarray(change_values, dtype=np.float64).reshape(len(change_steps), len(self.u))
        sample_steps = np.ascontiguousarray(sample_steps, dtype=np.int64)
        if sample_steps.size and sample_steps[0] < self.steps:
            raise ValueError(f"sample step {int(sample_steps[0])} is before the present step {self.steps}")
        out = np.empty((len(sample_steps), len(self.Y)))
        self.steps = int(self._run(self._S, self._Fa, self._FL, self.steps, self.dt, change_steps, change_values,
                                   sample_steps, out))
        return out

    def outputs(self) -> np.ndarray:
        """Every output at the present time (inputs in force from now on); a view, overwritten later."""
        self._outputs(self._S, self._Fa, self._FL, self.time)
        return self.Y

    def outputs_at(self, t: float) -> np.ndarray:
        """Every output of the present state and inputs, at time `t` (s); a view, overwritten later."""
        self._outputs(self._S, self._Fa, self._FL, t)
        return self.Y

    def derivatives(self, t: float, x: np.ndarray, u: np.ndarray | None = None) -> np.ndarray:
        """d(state)/dt at (t, x) with inputs u (default: those held now): for stiff reference solvers."""
        dx = np.empty(len(x))
        self._derivs(t, np.ascontiguousarray(x, dtype=np.float64), self.u if u is None else u, self.P, self.F,
                     self.W, self.Y, self.U, dx)
        return dx

    def project(self, x: np.ndarray) -> None:
        """Apply the systems' hybrid constraints (end stops) to x in place."""
        self._project(x, self.P)

    def finite(self) -> bool:
        return bool(np.all(np.isfinite(self.x)))

    def set_parameters(self, system: int, p: np.ndarray) -> None:
        """Replace one system's parameter vector (same layout) in place."""
        off = self.plant.offsets("p")
        if len(p) != off[system + 1] - off[system]:
            raise ValueError("parameter vector of another length than the system's")
        self.P[off[system]:off[system + 1]] = p
        self.refresh_rates()
