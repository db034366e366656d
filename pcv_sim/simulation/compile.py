"""From a composition of systems to compiled code: the composite right-hand side and the
fixed-step integrator loops, generated as Python source and compiled with `pcv_sim.jit`.

The generated module calls each system's own kernel functions (one source of the physics) with
views of the composite's arrays, routes connections through an input buffer, and holds every
fixed-step integrator as a loop over `n` steps, so that a whole batch of 0.1 ms steps runs in
machine code. The generated functions are compiled without numba's runtime (`jit(nrt=False)`):
no reference counting of the views, which would cost more than the physics of a step; such
code cannot allocate (numba refuses to compile it), and none does. Python calls the entry points
`sim_*`, which take every array of the composite as views of one float64 array (the arena,
`arena_layout`) and the systems' tables as views of one flat array (`pack_tables`): numba unboxes
each argument of a call from Python, and ~40 arrays cost more than a step. The source is written to the
kernel cache (`pcv_sim.jit.cache_root()`), keyed by a digest of its text, so numba's disk cache
serves the next process; with numba disabled the same module runs as plain Python.

Integrators (all fixed step, inputs held over a step: zero-order hold):

    euler   explicit Euler (order 1)
    rk2     Heun, the explicit trapezoid (order 2)
    rk4     classical Runge-Kutta (order 4)
    erk2    exponential Heun (ETD2RK): states with a declared stiff rate lam (the valve's damping
            chamber, lam = K_d beta / V_c ~ 2.6e8 1/s) are integrated with the exact response of
            their linear part, x' = -lam x + N(x): x1 = e^{-lam h} x0 + h phi1 N0 + h phi2 (N* - N0);
            the stiff states are relaxed at the predictor and at the end (x = e^{-lam h} x0 + h phi1
            N(x), one more evaluation each), so that a state slaved to the others (the chamber
            pressure to the spool velocity) sits on its slow manifold at every stage: 4
            evaluations per step with stiff states, 2 (Heun exactly) without. This is what runs
            the full model at 0.1 ms. A state may take its rate from the parameters instead
            (`System.rate_parameters`: the valve's spool velocity, damped by oil of a changing
            temperature); it is integrated exponentially at that rate, without the relaxation.
"""

from __future__ import annotations

import hashlib
import importlib.util
import math
import os
import sys
from types import ModuleType

import numpy as np

from pcv_sim.jit import cache_root, enabled
from pcv_sim.simulation.system import Composite

__all__ = ["ARENA", "INTEGRATORS", "ORDERS", "arena_layout", "compiled_module", "exponential_weights",
           "generate_source", "pack_tables"]

INTEGRATORS = ("euler", "rk2", "rk4", "erk2")
ORDERS = {"euler": 1, "rk2": 2, "rk4": 4, "erk2": 2}

#: The composite's arrays in the one float64 array (the arena) the entry points take, in order:
#: state, external inputs, parameters, workspace, outputs, systems' inputs, the integrators'
#: scratch (s1-s4, xt) and the exponential weights (E, A, B).
ARENA = ("x", "u", "P", "W", "Y", "U", "s1", "s2", "s3", "s4", "xt", "E", "A", "B")


def arena_layout(plant: Composite) -> dict[str, tuple[int, int]]:
    """Each of `ARENA`'s arrays as (start, stop) in the arena (the plant's structure alone)."""
    nx = len(plant.states)
    sizes = {"x": nx, "u": len(plant.inputs), "P": sum(len(s.p) for s in plant.systems),
             "W": sum(s.workspace for s in plant.systems), "Y": len(plant.outputs),
             "U": sum(len(s.inputs) for s in plant.systems)}
    out, at = {}, 0
    for name in ARENA:
        n = sizes.get(name, nx)
        out[name] = (at, at + n)
        at += n
    return out


def pack_tables(plant: Composite) -> tuple[np.ndarray, np.ndarray, tuple[tuple[np.ndarray, ...], ...]]:
    """The systems' tables in one float64 array: (flat, layout, views). `layout` holds, per table
    in order, its start in `flat` and its shape (int64); `views` are the tables (copies of the
    systems' `f`) as views of `flat`. The entry points rebuild the views from `layout`."""
    tables = [np.ascontiguousarray(t, dtype=np.float64) for s in plant.systems for t in s.f]
    if any(t.ndim == 0 for t in tables):
        raise ValueError("a system's table is a scalar: accepted are arrays of 1 or more dimensions")
    flat = np.concatenate([t.ravel() for t in tables]) if tables else np.zeros(0)
    layout: list[int] = []
    views = []
    at = 0
    for s in plant.systems:
        own = []
        for t in s.f:
            layout += [at, *np.shape(t)]
            own.append(flat[at:at + t.size].reshape(np.shape(t)))
            at += t.size
        views.append(tuple(own))
    return flat, np.array(layout, dtype=np.int64), tuple(views)


_LOOPS = '''

@jit(nrt=False)
def advance_euler(n, k0, h, x, u, P, F, W, Y, U, s1, s2, s3, s4, xt, E, A, B):
    for j in range(n):
        derivs((k0 + j) * h, x, u, P, F, W, Y, U, s1)
        for i in range(NX):
            x[i] += h * s1[i]
        project(x, P)


@jit(nrt=False)
def advance_rk2(n, k0, h, x, u, P, F, W, Y, U, s1, s2, s3, s4, xt, E, A, B):
    hh = 0.5 * h
    for j in range(n):
        t = (k0 + j) * h
        derivs(t, x, u, P, F, W, Y, U, s1)
        for i in range(NX):
            xt[i] = x[i] + h * s1[i]
        derivs(t + h, xt, u, P, F, W, Y, U, s2)
        for i in range(NX):
            x[i] += hh * (s1[i] + s2[i])
        project(x, P)


@jit(nrt=False)
def advance_rk4(n, k0, h, x, u, P, F, W, Y, U, s1, s2, s3, s4, xt, E, A, B):
    hh = 0.5 * h
    h6 = h / 6.0
    for j in range(n):
        t = (k0 + j) * h
        derivs(t, x, u, P, F, W, Y, U, s1)
        for i in range(NX):
            xt[i] = x[i] + hh * s1[i]
        derivs(t + hh, xt, u, P, F, W, Y, U, s2)
        for i in range(NX):
            xt[i] = x[i] + hh * s2[i]
        derivs(t + hh, xt, u, P, F, W, Y, U, s3)
        for i in range(NX):
            xt[i] = x[i] + h * s3[i]
        derivs(t + h, xt, u, P, F, W, Y, U, s4)
        for i in range(NX):
            x[i] += h6 * (s1[i] + 2.0 * s2[i] + 2.0 * s3[i] + s4[i])
        project(x, P)


@jit(nrt=False)
def advance_erk2(n, k0, h, x, u, P, F, W, Y, U, s1, s2, s3, s4, xt, E, A, B):
    # E = exp(-lam h), A = h phi1(lam h), B = h phi2(lam h); N = dx/dt + lam x (the nonlinear rest).
    for j in range(n):
        t = (k0 + j) * h
        derivs(t, x, u, P, F, W, Y, U, s1)
        for i in range(NX):
            s1[i] += LAM[i] * x[i]
            xt[i] = E[i] * x[i] + A[i] * s1[i]
            s4[i] = x[i]
        if STIFF:
            relax(t + h, xt, s4, u, P, F, W, Y, U, s3, E, A)
        derivs(t + h, xt, u, P, F, W, Y, U, s2)
        for i in range(NX):
            s2[i] += LAM[i] * xt[i]
            x[i] = E[i] * x[i] + A[i] * s1[i] + B[i] * (s2[i] - s1[i])
        if STIFF:
            relax(t + h, x, s4, u, P, F, W, Y, U, s3, E, A)
        project(x, P)


@jit(inline=True)
def relax(t, y, y0, u, P, F, W, Y, U, s, E, A):
    # The stiff states of y once more, with their forcing N at y itself (exponential Euler from
    # y0 with end-point forcing): a state slaved to the others (the chamber pressure to the spool
    # velocity) then sits on its slow manifold at every stage, so the force it exerts (the
    # chamber's damping) is that of the stage's own velocity. N does not depend on the stiff
    # state itself (its linear part is lam x), so one evaluation gives it exactly.
    derivs(t, y, u, P, F, W, Y, U, s)
    for i in range(NX):
        if LAM[i] > 0.0:
            y[i] = E[i] * y0[i] + A[i] * (s[i] + LAM[i] * y[i])
'''


_SAMPLE = '''

@jit(nrt=False)
def advance_sample_{name}(n, k0, h, x, u, P, F, W, Y, U, s1, s2, s3, s4, xt, E, A, B, select, out, after, lo, hi):
    # n steps, the outputs at the step reached (inputs in force from there on): out[i] =
    # Y[select[i]], then `after` more steps with the same inputs. One call where advance +
    # outputs + advance would be three: each call from Python costs its argument unboxing and the
    # Python around it, about a step of the rig.
    if n > 0:
        advance_{name}(n, k0, h, x, u, P, F, W, Y, U, s1, s2, s3, s4, xt, E, A, B)
    outputs((k0 + n) * h, x, u, P, F, W, Y, U)
    for i in range(len(select)):
        out[i] = Y[select[i]]
    # The bounds of the first len(lo) sampled outputs (lo[i] <= out[i] <= hi[i]; NaN is outside).
    inside = True
    for i in range(len(lo)):
        if not (lo[i] <= out[i] and out[i] <= hi[i]):
            inside = False
    if after > 0:
        advance_{name}(after, k0 + n, h, x, u, P, F, W, Y, U, s1, s2, s3, s4, xt, E, A, B)
    # Returns sum(x^2): not finite iff the state ran away or a sampled output is outside its
    # bounds (the caller's check, without another call).
    acc = 0.0
    for i in range(NX):
        acc += x[i] * x[i]
    if not inside:
        acc = np.nan
    return acc
'''


_RUN = '''

@jit(nrt=False)
def run_{name}(k0, h, x, u, P, F, W, Y, U, s1, s2, s3, s4, xt, E, A, B, change_steps, change_values,
               sample_steps, out):
    # Inputs change_values[c] act from step change_steps[c] on; at each of sample_steps (sorted)
    # every output goes into out, with the inputs due at that step already in force.
    c = 0
    k = k0
    for j in range(len(sample_steps)):
        target = sample_steps[j]
        while True:
            while c < len(change_steps) and change_steps[c] <= k:
                for i in range(len(u)):
                    u[i] = change_values[c, i]
                c += 1
            if k >= target:
                break
            nxt = target
            if c < len(change_steps) and change_steps[c] < nxt:
                nxt = change_steps[c]
            advance_{name}(nxt - k, k, h, x, u, P, F, W, Y, U, s1, s2, s3, s4, xt, E, A, B)
            k = nxt
        outputs(k * h, x, u, P, F, W, Y, U)
        for i in range(len(Y)):
            out[j, i] = Y[i]
    return k
'''


_ENTRIES = '''

@jit(nrt=False)
def sim_advance_{name}(S, Fa, FL, n, k0, h):
{views}
    advance_{name}(n, k0, h, x, u, P, F, W, Y, U, s1, s2, s3, s4, xt, E, A, B)


@jit(nrt=False)
def sim_advance_sample_{name}(S, Fa, FL, n, k0, h, select, out, after, feed_i, feed_v, row, lo, hi):
{views}
    if row >= 0:
        # After the n steps, before the outputs: the inputs of row `row` of feed_v (u[feed_i[j]] =
        # feed_v[row, j]; NaN: left as it is), the inputs due at the sampled step.
        if n > 0:
            advance_{name}(n, k0, h, x, u, P, F, W, Y, U, s1, s2, s3, s4, xt, E, A, B)
        for j in range(len(feed_i)):
            v = feed_v[row, j]
            if v == v:
                u[feed_i[j]] = v
        return advance_sample_{name}(0, k0 + n, h, x, u, P, F, W, Y, U, s1, s2, s3, s4, xt, E, A, B, select, out,
                                     after, lo, hi)
    return advance_sample_{name}(n, k0, h, x, u, P, F, W, Y, U, s1, s2, s3, s4, xt, E, A, B, select, out, after,
                                 lo, hi)


@jit(nrt=False)
def sim_sample_{name}(S, Fa, FL, n, k0, h, select, out, after, lo, hi):
{views}
    # sim_advance_sample without a fed row: three arguments fewer to unbox on every call of a
    # loop that samples every control period (the lockstep's planned stretch)
    return advance_sample_{name}(n, k0, h, x, u, P, F, W, Y, U, s1, s2, s3, s4, xt, E, A, B, select, out, after,
                                 lo, hi)


@jit(nrt=False)
def sim_run_{name}(S, Fa, FL, k0, h, change_steps, change_values, sample_steps, out):
{views}
    return run_{name}(k0, h, x, u, P, F, W, Y, U, s1, s2, s3, s4, xt, E, A, B, change_steps, change_values,
                      sample_steps, out)
'''


def _views(plant: Composite) -> str:
    """The entry points' first lines: the composite's arrays as views of the arena S and the
    tables F as views of the flat Fa after the layout FL (`arena_layout`, `pack_tables`)."""
    lines = [f"    {name} = S[{a}:{b}]" for name, (a, b) in arena_layout(plant).items()]
    systems = []
    at = 0
    for s in plant.systems:
        own = []
        for t in s.f:
            nd = np.ndim(t)
            dims = [f"FL[{at + 1 + d}]" for d in range(nd)]
            size = " * ".join(dims) if dims else "1"
            view = f"Fa[FL[{at}]:FL[{at}] + {size}]"
            own.append(view if nd == 1 else f"{view}.reshape(({', '.join(dims)}))")
            at += 1 + nd
        systems.append("(" + "".join(f"{v}, " for v in own).rstrip(" ") + ")" if own else "()")
    lines.append("    F = (" + "".join(f"{v}, " for v in systems).rstrip(" ") + ")")
    return "\n".join(lines)


def exponential_weights(rates: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """E = e^{-lam h}, A = h phi1(lam h), B = h phi2(lam h) per state (lam = 0: 1, h, h/2)."""
    e, a, b = np.ones(len(rates)), np.full(len(rates), h), np.full(len(rates), 0.5 * h)
    for i, lam in enumerate(np.asarray(rates, float)):
        z = lam * h
        if z > 1e-6:
            e[i] = math.exp(-z)
            a[i] = -math.expm1(-z) / z * h
            b[i] = (z - 1.0 + math.exp(-z)) / (z * z) * h
        elif z > 0.0:                      # series: phi1 = 1 - z/2, phi2 = 1/2 - z/6
            e[i] = math.exp(-z)
            a[i] = (1.0 - 0.5 * z) * h
            b[i] = (0.5 - z / 6.0) * h
    return e, a, b


def generate_source(plant: Composite) -> str:
    """The Python source of the composite's kernel module (see the module docstring)."""
    xs, us, ys, ps, ws = (plant.offsets(k) for k in ("states", "inputs", "outputs", "p", "workspace"))
    lines = ['"""Generated by pcv_sim.simulation.compile: do not edit (it is rewritten from the systems)."""',
             "import numpy as np", "from pcv_sim.jit import jit"]
    for k, s in enumerate(plant.systems):
        kn = s.kernel
        lines.append(f"from {kn.module} import {kn.rhs} as rhs_{k}, {kn.state_output} as so_{k}, "
                     f"{kn.output} as out_{k}, {kn.project} as proj_{k}")
    lines.append(f"NX = {xs[-1]}")
    lam = ", ".join(repr(float(v)) for v in plant.rates) or ""
    lines.append(f"LAM = np.array([{lam}], dtype=np.float64)")
    lines.append(f"STIFF = {bool(np.any(plant.rates > 0.0))}")

    single = len(plant.systems) == 1 and not plant.connections

    def view(name: str, off: list[int], k: int) -> str:
        # One system: the whole arrays (a view costs reference counting on every call).
        if single:
            return "u" if name == "U" else name
        return f"{name}[{off[k]}:{off[k + 1]}]"

    ext = {name: j for j, name in enumerate(plant.inputs)}
    wiring: list[str] = []
    for k, s in enumerate(plant.systems):
        for j, name in enumerate(s.inputs):
            full = f"{s.name}.{name}"
            if full in ext:
                wiring.append(f"    U[{us[k] + j}] = u[{ext[full]}]")
    for (ka, oa), (kb, ib) in plant.connections:
        wiring.append(f"    U[{us[kb] + ib}] = Y[{ys[ka] + oa}]")
    if single:
        wiring = []                         # the system reads the external inputs directly
    state_outputs = [f"    so_{k}(t, {view('x', xs, k)}, {view('P', ps, k)}, F[{k}], {view('Y', ys, k)})"
                     for k in range(len(plant.systems))]
    body = ["", "", "@jit(nrt=False)", "def derivs(t, x, u, P, F, W, Y, U, dx):",
            "    # state outputs first (no feedthrough), then every input, then the right-hand sides"]
    body += state_outputs + wiring
    body += [f"    rhs_{k}(t, {view('x', xs, k)}, {view('U', us, k)}, {view('P', ps, k)}, F[{k}], "
             f"{view('W', ws, k)}, {view('dx', xs, k)})" for k in range(len(plant.systems))]
    body += ["", "", "@jit(nrt=False)", "def outputs(t, x, u, P, F, W, Y, U):", *state_outputs, *wiring]
    body += [f"    out_{k}(t, {view('x', xs, k)}, {view('U', us, k)}, {view('P', ps, k)}, F[{k}], "
             f"{view('W', ws, k)}, {view('Y', ys, k)})" for k in range(len(plant.systems))]
    body += ["", "", "@jit(nrt=False)", "def project(x, P):"]
    body += [f"    proj_{k}({view('x', xs, k)}, {view('P', ps, k)})" for k in range(len(plant.systems))]
    loops = _LOOPS
    if plant.rate_parameters:
        # States whose rate is a parameter (set at run time): erk2 reads it where it splits off
        # the linear part; the relaxation stays with the declared (constant) stiff states.
        body += ["", "", "@jit(inline=True)", "def lam(i, P):"]
        for i, j in plant.rate_parameters:
            body += [f"    if i == {i}:", f"        return P[{j}]"]
        body += ["    return LAM[i]"]
        loops = loops.replace("s1[i] += LAM[i] * x[i]", "s1[i] += lam(i, P) * x[i]").replace(
            "s2[i] += LAM[i] * xt[i]", "s2[i] += lam(i, P) * xt[i]")
    # The entry points Python calls: one arena, the flat tables and their layout instead of ~40
    # arrays (numba unboxes each argument of a call from Python: ~0.1 us an array).
    views = _views(plant)
    body += ["", "", "@jit(nrt=False)", "def sim_outputs(S, Fa, FL, t):", views, "    outputs(t, x, u, P, F, W, Y, U)"]
    return "\n".join(lines + body) + loops + "".join(_RUN.format(name=n) + _SAMPLE.format(name=n)
                                                     + _ENTRIES.format(name=n, views=views) for n in INTEGRATORS)


_LOADED: dict[str, ModuleType] = {}


def compiled_module(plant: Composite) -> ModuleType:
    """The kernel module of `plant`: generated once per distinct source, cached on disk."""
    source = generate_source(plant)
    digest = hashlib.sha1(source.encode()).hexdigest()[:16]
    name = f"pcv_sim_kernel_{digest}"
    if name in _LOADED:
        return _LOADED[name]
    directory = cache_root() / "kernels"
    path = directory / f"{name}.py"
    try:
        directory.mkdir(parents=True, exist_ok=True)
        if not path.is_file() or path.read_text() != source:
            tmp = path.with_suffix(f".{os.getpid()}.tmp")
            tmp.write_text(source)
            os.replace(tmp, path)          # atomic: concurrent processes never see half a file
    except OSError:
        # No writable cache: compile from a temporary file (works; compiled again next time).
        import tempfile

        directory = __import__("pathlib").Path(tempfile.mkdtemp(prefix="pcv_sim_kernel_"))
        path = directory / f"{name}.py"
        path.write_text(source)
    spec = importlib.util.spec_from_file_location(name, path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    module.JIT = enabled()  # type: ignore[attr-defined]  # for diagnostics: compiled or Python
    _LOADED[name] = module
    return module
