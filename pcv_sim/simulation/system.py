"""The model interface of the simulation core: systems with named signals, and their composition.

A `System` is one block in the spirit of python-control's `updfcn(t, x, u, params)`: it declares
named states, inputs and outputs and points to four functions over float arrays (SI units),
written once in the numba subset of Python (`pcv_sim.jit`):

    rhs(t, x, u, p, f, w, dx)        d(state)/dt into dx
    state_output(t, x, p, f, y)      the outputs that depend on the state alone
    output(t, x, u, p, f, w, y)      all outputs (some may depend on u: direct feedthrough)
    project(x, p)                    hybrid constraints after a step (end stops), may do nothing

`p` is the system's parameter vector, `f` a tuple of tables, `w` a workspace that persists
between calls (e.g. the Newton start of an algebraic solve). Algebraic loops stay inside a
system (the valve solves its coil current itself).

Systems compose (`compose`): an output of one feeds an input of another, all states go into one
vector and are integrated together at one step. Only state outputs may be connected, so the
composite never has an algebraic loop between systems. A new system plugs in by writing those
four functions in a module and describing it with a `System`; `pcv_sim.simulation.compile`
generates and compiles the composite's right-hand side and integrator loops from them.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pcv_sim.errors import PcvSimError

__all__ = ["Composite", "CompositionError", "Kernel", "Stop", "System", "compose"]


class CompositionError(PcvSimError, ValueError):
    """Systems that cannot be connected as asked (unknown signal, feedthrough, double connection)."""


@dataclass(frozen=True)
class Kernel:
    """Where a system's compiled functions live: an importable module and the function names."""

    module: str
    rhs: str = "rhs"
    state_output: str = "state_output"
    output: str = "output"
    project: str = "project"


@dataclass(frozen=True)
class Stop:
    """An inelastic end stop: state `position` is held in [lo, hi]; `velocity` is zeroed at impact."""

    position: int
    velocity: int
    lo: float
    hi: float


@dataclass(frozen=True, eq=False)
class System:
    """One block: named signals, its kernel functions and its parameters (see the module docstring)."""

    name: str
    states: tuple[str, ...]
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    state_outputs: tuple[str, ...]
    kernel: Kernel
    p: np.ndarray
    f: tuple[np.ndarray, ...]
    workspace: int = 1
    #: Per state, the rate (1/s) of a linear decay the exponential integrator treats exactly;
    #: 0 = explicit. E.g. the valve's damping chamber, -2.6e8 1/s.
    stiff_rates: np.ndarray | None = None
    stops: tuple[Stop, ...] = ()
    #: Initial workspace values (default zeros).
    w0: tuple[float, ...] = ()
    #: (state, parameter) pairs: the state's linear decay rate (1/s) is p[parameter], which may
    #: change at run time (the valve's spool in oil of a changing temperature; 0 = explicit).
    #: Such a state is integrated exponentially by `erk2` but, unlike `stiff_rates`, not relaxed
    #: onto a slow manifold (its rate is that of the state itself, so its own update is exact).
    rate_parameters: tuple[tuple[int, int], ...] = ()

    def __post_init__(self) -> None:
        if not self.name.isidentifier():
            raise CompositionError(f"system name {self.name!r}: accepted is an identifier (letters, digits, _)")
        for what, names in (("state", self.states), ("input", self.inputs), ("output", self.outputs)):
            if len(set(names)) != len(names):
                raise CompositionError(f"system {self.name}: repeated {what} names in {names}")
        bad = [o for o in self.state_outputs if o not in self.outputs]
        if bad:
            raise CompositionError(f"system {self.name}: state outputs {bad} are not among its outputs")

    @property
    def rates(self) -> np.ndarray:
        return np.zeros(len(self.states)) if self.stiff_rates is None else np.asarray(self.stiff_rates, float)


@dataclass(frozen=True, eq=False)
class Composite:
    """Systems wired together; signals are named `system.signal`. Made by `compose`."""

    systems: tuple[System, ...]
    #: (output system index, output index) -> (input system index, input index)
    connections: tuple[tuple[tuple[int, int], tuple[int, int]], ...]
    inputs: tuple[str, ...] = field(default=())         # unconnected inputs, `system.input`

    @property
    def states(self) -> tuple[str, ...]:
        return tuple(f"{s.name}.{x}" for s in self.systems for x in s.states)

    @property
    def outputs(self) -> tuple[str, ...]:
        return tuple(f"{s.name}.{y}" for s in self.systems for y in s.outputs)

    def offsets(self, what: str) -> list[int]:
        """Start index of each system in the concatenated states / inputs / outputs / p / workspace."""
        sizes = {
            "states": [len(s.states) for s in self.systems],
            "inputs": [len(s.inputs) for s in self.systems],
            "outputs": [len(s.outputs) for s in self.systems],
            "p": [len(s.p) for s in self.systems],
            "workspace": [s.workspace for s in self.systems],
        }[what]
        return [int(v) for v in np.concatenate([[0], np.cumsum(sizes)])]

    def index(self, kind: str, name: str) -> int:
        """Position of `system.signal` in the composite's states, inputs (external) or outputs."""
        names = {"state": self.states, "input": self.inputs, "output": self.outputs}[kind]
        try:
            return names.index(name)
        except ValueError:
            raise CompositionError(f"no {kind} {name!r}; accepted: {', '.join(names)}") from None

    @property
    def stops(self) -> tuple[Stop, ...]:
        out = []
        for s, off in zip(self.systems, self.offsets("states")):
            out += [Stop(st.position + off, st.velocity + off, st.lo, st.hi) for st in s.stops]
        return tuple(out)

    @property
    def rates(self) -> np.ndarray:
        return np.concatenate([s.rates for s in self.systems])

    @property
    def rate_parameters(self) -> tuple[tuple[int, int], ...]:
        """(state, parameter) pairs in the composite's state and parameter vectors: the states
        whose decay rate is read from the parameters at run time (`System.rate_parameters`)."""
        xs, ps = self.offsets("states"), self.offsets("p")
        return tuple((i + xs[k], j + ps[k]) for k, s in enumerate(self.systems) for i, j in s.rate_parameters)


def _split(signal: str) -> tuple[str, str]:
    name, dot, sig = signal.partition(".")
    if not dot or not sig:
        raise CompositionError(f"signal {signal!r}: accepted is 'system.signal'")
    return name, sig


def compose(systems: list[System] | tuple[System, ...],
            connections: list[tuple[str, str]] | tuple[tuple[str, str], ...] = ()) -> Composite:
    """Wire `systems` together: each connection (`a.output`, `b.input`) feeds a state output of
    one system into an input of another. Unconnected inputs stay inputs of the composite."""
    systems = tuple(systems)
    by_name = {s.name: k for k, s in enumerate(systems)}
    if len(by_name) != len(systems):
        raise CompositionError(f"system names must differ: {[s.name for s in systems]}")
    wires: dict[tuple[int, int], tuple[int, int]] = {}
    for src, dst in connections:
        (sa, so), (sb, si) = _split(src), _split(dst)
        if sa not in by_name or sb not in by_name:
            raise CompositionError(f"connection {src} -> {dst}: unknown system; systems: {', '.join(by_name)}")
        a, b = systems[by_name[sa]], systems[by_name[sb]]
        if so not in a.outputs:
            raise CompositionError(f"connection {src} -> {dst}: {sa} has no output {so!r}; outputs: {a.outputs}")
        if so not in a.state_outputs:
            raise CompositionError(
                f"connection {src} -> {dst}: {src} depends on {sa}'s inputs (direct feedthrough); only state "
                f"outputs can be connected ({', '.join(a.state_outputs)}), so no algebraic loop forms between systems")
        if si not in b.inputs:
            raise CompositionError(f"connection {src} -> {dst}: {sb} has no input {si!r}; inputs: {b.inputs}")
        key = (by_name[sb], b.inputs.index(si))
        if key in wires:
            raise CompositionError(f"input {dst} is connected twice")
        wires[key] = (by_name[sa], a.outputs.index(so))
    inputs = tuple(f"{s.name}.{u}" for k, s in enumerate(systems) for j, u in enumerate(s.inputs)
                   if (k, j) not in wires)
    return Composite(systems, tuple((src, dst) for dst, src in sorted(wires.items())), inputs)
