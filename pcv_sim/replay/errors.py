"""Errors of the replay comparison."""

from __future__ import annotations

from pcv_sim.errors import PcvSimError

__all__ = ["ReplayError"]


class ReplayError(PcvSimError, ValueError):
    """A bag cannot be replayed as asked: missing or unusable topics, bad timestamps or values,
    an unknown threshold name. The message says what was found and what is accepted."""
