"""Compiled kernels with one source: numba when it is installed and enabled, plain Python otherwise.

Every function of the physics that the simulation core runs is written once, in the subset of
Python that numba compiles (floats, tuples and numpy arrays, `math`), and decorated with `jit`.
With numba the decorator compiles it on first use and caches the machine code on disk (under
`cache_root()`, keyed by a digest of the sources the kernels depend on), so a process that starts later
loads it instead of compiling (processes that compile at the same time share the cache
safely: `_SharedCache`); without
numba, or with the environment variable `PCV_SIM_JIT=0`, the same function runs as written. A
test runs both paths on the same inputs and checks that they agree to rounding.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, TypeVar

__all__ = ["ENV_VAR", "backend", "cache_root", "compiled_for", "enabled", "jit", "kernel_sources", "source_digest"]

F = TypeVar("F", bound=Callable[..., Any])

#: Set to 0 (or false/no/off) to run every kernel as plain Python.
ENV_VAR = "PCV_SIM_JIT"


def _wanted() -> bool:
    return os.environ.get(ENV_VAR, "1").strip().lower() not in ("0", "false", "no", "off")


def cache_root() -> Path:
    """Where compiled kernels are kept: $PCV_SIM_CACHE, else ~/.cache/pcv_sim (else the temp dir)."""
    env = os.environ.get("PCV_SIM_CACHE")
    if env:
        return Path(env)
    home = Path.home() if os.environ.get("HOME") else Path(tempfile.gettempdir())
    return home / ".cache" / "pcv_sim"


def source_digest() -> str:
    """A digest of the sources compiled code can depend on. numba's cache only notices changes in
    the file that defines a function, not in the functions it calls or the constants it reads, so
    the cache directory is keyed on every module that defines a kernel and every pcv_sim module
    those import, transitively (`kernel_sources`). An edit there can never run stale machine code;
    an edit elsewhere (a node, a command, a report) keeps the compiled kernels."""
    h = hashlib.sha1()
    pkg = Path(__file__).resolve().parent
    for path in kernel_sources():
        h.update(str(path.relative_to(pkg)).encode())
        h.update(path.read_bytes())
    return h.hexdigest()[:16]


def kernel_sources() -> list[Path]:
    """The package's modules that define a `jit` function, and the pcv_sim modules they import
    (from the import statements, transitively, with their parent packages), sorted."""
    pkg = Path(__file__).resolve().parent
    modules = {_module_name(pkg, p): p for p in pkg.rglob("*.py")}
    texts = {m: p.read_text(encoding="utf-8") for m, p in modules.items()}
    todo = [m for m, t in texts.items() if "@jit" in t or "jit(" in t]
    seen: set[str] = set()
    while todo:
        m = todo.pop()
        if m not in seen:
            seen.add(m)
            todo.extend(_imported(m, modules[m], texts[m], modules))
    return sorted(modules[m] for m in seen)


def _module_name(pkg: Path, path: Path) -> str:
    parts = (pkg.name, *path.relative_to(pkg).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imported(name: str, path: Path, text: str, modules: dict[str, Path]) -> set[str]:
    import ast

    here = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
    found: set[str] = set()
    for node in ast.walk(ast.parse(text)):
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = ".".join([*here[:len(here) - node.level + 1], node.module or ""]).strip(".") \
                if node.level else (node.module or "")
            found.add(base)
            found.update(f"{base}.{a.name}" for a in node.names)
    out: set[str] = set()
    for m in found:
        parts = m.split(".")
        out.update(q for q in (".".join(parts[:i]) for i in range(1, len(parts) + 1)) if q in modules)
    return out


def _numba() -> Any:
    if not _wanted():
        return None
    if "NUMBA_CACHE_DIR" not in os.environ:      # must be set before numba is imported
        os.environ["NUMBA_CACHE_DIR"] = str(cache_root() / "numba" / source_digest())
    try:
        import numba
    except ImportError:
        return None
    return numba


_NUMBA = _numba()


@contextlib.contextmanager
def _locked(directory: str) -> Iterator[None]:
    """An exclusive lock on the cache directory `directory` across processes (flock on its
    `.lock`; where flock is missing, none)."""
    try:
        import fcntl
    except ImportError:
        yield
        return
    os.makedirs(directory, exist_ok=True)
    fd = os.open(os.path.join(directory, ".lock"), os.O_RDWR | os.O_CREAT, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)                # releases the lock


def _shared_cache(py_func: Callable[..., Any]) -> Any:
    """numba's disk cache of `py_func`, read and written under the cache directory's lock.

    numba keeps one index per function (signature -> data file) and picks a data file's number
    from the index it read: two processes that save two signatures of one function at the same
    time both read the old index, both write file 1 and each its own index, so the index can name
    the other signature's machine code for a signature (called with the wrong types: a crash or
    wrong numbers). Under the lock an index and its data files change together; compiling stays
    outside it, so processes still compile side by side (the test session's warm-up does).
    """
    from numba.core import caching

    base: Any = caching.FunctionCache          # untyped

    class _SharedCache(base):  # type: ignore[misc]
        def load_overload(self, sig: Any, target_context: Any) -> Any:
            with _locked(self._cache_path):
                return super().load_overload(sig, target_context)

        def save_overload(self, sig: Any, data: Any) -> None:
            with _locked(self._cache_path):
                super().save_overload(sig, data)

    return _SharedCache(py_func)
#: Contraction (FMA) and reciprocals only. Never reassociation (C_q,gap (1 - L) + C_q,hole L with
#: C_q,gap ~ 1e19 far from the gap region cancels to 0 when reordered), never 'nnan'/'ninf' (the
#: compiler could drop the finiteness checks that turn a diverging model into a fault).
#: error_model numpy: a division by zero gives inf/nan (caught by those checks), no exception.
_FASTMATH = {"contract", "arcp", "nsz"}


def enabled() -> bool:
    """True when kernels are compiled with numba (installed and not disabled by PCV_SIM_JIT)."""
    return _NUMBA is not None


def backend() -> str:
    """'numba <version>' or 'python' (for logs, diagnostics and benchmarks)."""
    return f"numba {_NUMBA.__version__}" if _NUMBA is not None else "python"


def jit(fn: F | None = None, *, inline: bool = False, nrt: bool = True) -> Any:
    """Compile `fn` with numba (nopython, cached, releasing the GIL) or return it unchanged.

    `@jit(inline=True)` for the physics the integrator loops call: numba then inlines the function
    into its caller, which saves the call's argument passing (a tuple of a dozen arrays and their
    reference counts per call: ~60 % of a step's cost otherwise) at the price of a longer first
    compilation (BENCHMARKS.md, Model).

    `@jit(nrt=False)` compiles without numba's runtime: arrays are borrowed from the caller and
    views of them (a composite hands each system slices of its arrays) carry no reference counts.
    With the runtime every slice costs an atomic increment and decrement: for two valves and a
    cylinder ~75 % of a step (2.1 -> 0.55 us, bit for bit the same numbers; BENCHMARKS.md,
    Model). Such a function cannot allocate an array (numba refuses to compile it, so the mistake
    cannot pass unseen); the generated composite code (`pcv_sim.simulation.compile`) never does.
    """
    if fn is None:
        return lambda f: jit(f, inline=inline, nrt=nrt)
    if _NUMBA is None:
        return fn
    options: dict[str, Any] = {} if nrt else {"_nrt": False}   # numba's flag for it (no public name)
    dispatcher = _NUMBA.njit(cache=True, nogil=True, error_model="numpy", fastmath=_FASTMATH,
                             inline="always" if inline else "never", **options)(fn)
    dispatcher._cache = _shared_cache(fn)       # what cache=True set, locked (numba has no option)
    return dispatcher


def compiled_for(fn: F, *example: Any) -> F:
    """`fn`'s machine code for the argument types of `example` (compiled now, or loaded from the
    cache), called without numba's dispatch: the dispatcher types every argument and picks the
    compiled version on each call (~0.25 us for 14 arguments, as much as half a step of the rig).
    For a call made every control period with arguments of always those types. Nothing is checked
    then: an array of another dtype, dimension or layout is read as if it were of the example's
    (wrong numbers, not an error), so the caller binds its arrays once and passes only arrays it
    made of those types. Without numba: `fn` itself."""
    dispatcher: Any = fn
    if _NUMBA is None or not hasattr(dispatcher, "get_overload"):
        return fn
    types = tuple(dispatcher.typeof_pyval(a) for a in example)
    dispatcher.compile(types)
    entry: F = dispatcher.get_overload(types)
    return entry
