"""Unknown and missing keys of a file's mapping, named with the closest accepted one (difflib)."""

from __future__ import annotations

import difflib
from collections.abc import Iterable, Mapping
from typing import Any

from pcv_sim.errors import ParameterError, PcvSimError

__all__ = ["check_keys", "closest", "exactly_one", "missing_message", "unknown_message"]


def closest(word: Any, accepted: Iterable[str], *, cutoff: float = 0.6) -> str | None:
    """The accepted word `word` was most likely meant as (None when none is close)."""
    if not isinstance(word, str):
        return None
    words = list(accepted)
    hit = difflib.get_close_matches(word, words, n=1, cutoff=cutoff)
    if not hit:        # `forces` for `force`, `Pressure` for `pressure`
        low = {w.lower(): w for w in words}
        hit = difflib.get_close_matches(word.lower(), list(low), n=1, cutoff=cutoff)
        return low[hit[0]] if hit else None
    return hit[0]


def unknown_message(where: str, given: Mapping[Any, Any], accepted: Iterable[str]) -> str | None:
    """`where: unknown key 'forse' (did you mean 'force'?); accepted: ...`, or None when every key
    of `given` is accepted."""
    accepted = tuple(accepted)
    bad = sorted((k for k in given if k not in accepted), key=str)
    if not bad:
        return None
    parts = []
    for k in bad:
        near = closest(k, accepted)
        parts.append(f"{k!r} (did you mean {near!r}?)" if near else repr(k))
    return f"{where}: unknown key{'s' if len(bad) > 1 else ''} {', '.join(parts)}; accepted: {', '.join(accepted)}"


def missing_message(where: str, given: Mapping[Any, Any], wanted: Iterable[str], *, one_of: bool = True) -> str:
    """For a mapping that lacks the key(s) it needs: names what was there instead and, for a
    near miss, the key it was likely meant as."""
    wanted = tuple(wanted)
    there = [k for k in given if k != "t"]
    hints = []
    for k in there:
        near = closest(k, wanted)
        if near is not None and k not in wanted:
            hints.append(f"{k!r} (did you mean {near!r}?)")
    got = ", ".join(hints or [repr(k) for k in there]) or "none"
    return f"{where}: accepted is {'exactly one of' if one_of else 'each of'} {', '.join(wanted)}; got {got}"


def check_keys(where: str, given: Any, accepted: tuple[str, ...], required: tuple[str, ...] = (),
               error: type[PcvSimError] = ParameterError) -> Mapping[str, Any]:
    """`given` as a mapping with only `accepted` keys and every `required` one; `error` naming
    `where`, the unknown key and the one it was likely meant as, or the missing ones, otherwise."""
    if not isinstance(given, Mapping):
        raise error(f"{where}: got {given!r}; accepted is a mapping with {', '.join(accepted)}")
    msg = unknown_message(where, given, accepted)
    if msg:
        raise error(msg)
    missing = [k for k in required if k not in given]
    if missing:
        raise error(f"{where}: {', '.join(missing)} missing; accepted keys: {', '.join(accepted)}")
    return given


def exactly_one(where: str, given: Mapping[Any, Any], choices: tuple[str, ...],
                error: type[PcvSimError] = ParameterError) -> str:
    """The one key of `choices` that `given` holds (a timeline entry's action, a profile's
    shape); `error` naming what was there instead, or the keys given together, otherwise."""
    found = [c for c in choices if c in given]
    if len(found) != 1:
        if not found:
            raise error(missing_message(where, given, choices))
        raise error(f"{where}: accepted is exactly one of {', '.join(choices)} (got {', '.join(found)})")
    return found[0]
