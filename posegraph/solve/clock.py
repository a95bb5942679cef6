"""Wall-clock seconds per solver phase, collected in one place for the iteration records."""

from __future__ import annotations

import time
from contextlib import contextmanager

__all__ = ["PhaseClock", "PHASES"]

PHASES = ("linearize", "assemble", "factorize", "solve")
"""The phases of an iteration, as :class:`~posegraph.solve.result.IterationRecord` reports them
(``seconds_<phase>``): residuals, Jacobians and per-edge blocks; their scatter into H and g;
numeric factorisations; triangular solves and cost evaluations of trial steps."""


class PhaseClock:
    """Sums the time spent in each phase since the last :meth:`lap`.

    ``with clock.phase("factorize"): ...`` adds that block's wall-clock time to the phase;
    :meth:`lap` returns the sums as ``{"seconds_linearize": …, …}`` and starts again from zero.
    """

    def __init__(self) -> None:
        self._seconds = dict.fromkeys(PHASES, 0.0)

    @contextmanager
    def phase(self, name: str):
        start = time.perf_counter()
        try:
            yield
        finally:
            self._seconds[name] += time.perf_counter() - start

    def lap(self) -> dict:
        """The seconds per phase since the last lap, keyed ``seconds_<phase>``; resets them."""
        out = {f"seconds_{name}": value for name, value in self._seconds.items()}
        self._seconds = dict.fromkeys(PHASES, 0.0)
        return out
