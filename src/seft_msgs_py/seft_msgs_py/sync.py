"""Collect the samples of several topics by step index (lockstep synchronization)."""

from typing import Iterable

__all__ = ['StepSync']


class StepSync:
    """Per-step collector: a step is complete when every topic delivered its sample.

    Parameters
    ----------
    names : iterable of str
        The topic names to collect.
    """

    def __init__(self, names: Iterable[str]):
        self.names = tuple(names)
        self._partial: dict[int, dict[str, float]] = {}

    def add(self, step: int, name: str, value: float) -> dict[str, float] | None:
        """Add one sample; return ``{name: value}`` when the step just became complete."""
        got = self._partial.setdefault(step, {})
        got[name] = value
        if len(got) == len(self.names):
            return self._partial.pop(step)
        return None
