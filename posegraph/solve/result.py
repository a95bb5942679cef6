"""What the solver returns: per-iteration records and the overall result."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["IterationRecord", "OptimizeResult"]


@dataclass(frozen=True)
class IterationRecord:
    """One outer iteration (one relinearisation) of Gauss-Newton or Levenberg-Marquardt.

    Times are wall-clock seconds summed over the iteration, LM retries included.
    """

    iteration: int
    """1-based iteration number."""
    cost: float
    """Cost ½ Σ eᵀ Ω e after the iteration (equal to the cost before it if no step was accepted)."""
    cost_decrease: float
    """Cost before minus cost after the iteration (0 if no step was accepted)."""
    lambda_: float
    """LM damping λ of the accepted (or last tried) step; 0 for Gauss-Newton."""
    step_norm: float
    """Euclidean norm of the accepted (or last tried) solved tangent step δ over all free vertices
    (the poses moved by ``step_scale · δ``)."""
    gain_ratio: float
    """Actual over predicted cost decrease of that step, at the scale ``step_scale`` it was taken
    (NaN if the model predicted none)."""
    accepted: bool
    """Whether a step was accepted in this iteration."""
    attempts: int
    """Number of damped systems factorised in this iteration (1 + LM retries)."""
    seconds_linearize: float
    """Residuals, Jacobians and per-edge Hessian/gradient blocks."""
    seconds_assemble: float
    """Scatter of the per-edge blocks into the sparse matrix and the gradient vector."""
    seconds_factorize: float
    """Numeric factorisation(s) of the damped normal equations."""
    seconds_solve: float
    """Triangular solves, and evaluating the cost at the trial poses (line-search trials included)."""
    step_scale: float = 1.0
    """Fraction ``t`` of the solved step δ that was taken, ``X ← X ⊕ t·δ``: 1 for a full step, below 1
    when the line search shortened a step the quadratic model over-promised (NaN if none was taken)."""

    @property
    def seconds(self) -> float:
        """Total seconds of this iteration."""
        return self.seconds_linearize + self.seconds_assemble + self.seconds_factorize + self.seconds_solve


@dataclass(frozen=True, eq=False)
class OptimizeResult:
    """The outcome of :func:`posegraph.solve.optimize`."""

    poses: np.ndarray
    """``(n, 4, 4)`` optimised poses ``X_k``, vertex order as in the graph."""
    initial_cost: float
    """Cost at the initial poses."""
    final_cost: float
    """Cost at ``poses``."""
    iterations: int
    """Number of outer iterations run."""
    termination: str
    """Why the solver stopped: ``"converged: relative decrease"``, ``"converged: absolute decrease"``,
    ``"converged: cost below tolerance"``, ``"converged: predicted decrease below tolerance"``,
    ``"converged: Newton decrement below tolerance"`` (``½gᵀM⁻¹g`` under the held factorisation was
    100 times below the tolerances; the last record took its chord step if the cost confirmed it,
    else no step), ``"converged: nothing to
    optimise"``, ``"maximum iterations"``, ``"lambda exceeded bound"``,
    ``"no decrease"`` (Gauss-Newton: neither the step nor any shortening of it decreased the cost),
    ``"linear system not positive definite"``, ``"non-finite cost"`` or ``"callback"``."""
    converged: bool
    """True when one of the ``"converged: ..."`` reasons applies."""
    linear_solver: str
    """The backend that ran, e.g. ``"cholmod (supernodal, amd)"`` or ``"scipy (SuperLU, ...)"``."""
    method: str
    """``"lm"`` or ``"gn"``."""
    records: list = field(default_factory=list)
    """One :class:`IterationRecord` per iteration."""
    seconds_setup: float = 0.0
    """Sparsity analysis and symbolic factorisation (once per graph)."""
    seconds_total: float = 0.0
    """Wall-clock seconds of the whole call."""
    points: np.ndarray | None = None
    """``(L, s)`` optimised landmark positions (landmark order as in ``graph.landmarks``), None for a pose graph."""
    final_residuals: np.ndarray | None = None
    """``(m, d)`` edge residuals ``e = Log(Z⁻¹ X_i⁻¹ X_j)`` at ``poses`` (the solver's last
    evaluation; e.g. for χ² per edge without evaluating them again)."""

    @property
    def seconds_linearize(self) -> float:
        return float(sum(r.seconds_linearize for r in self.records))

    @property
    def seconds_assemble(self) -> float:
        return float(sum(r.seconds_assemble for r in self.records))

    @property
    def seconds_factorize(self) -> float:
        return float(sum(r.seconds_factorize for r in self.records))

    @property
    def seconds_solve(self) -> float:
        return float(sum(r.seconds_solve for r in self.records))

    def summary(self) -> str:
        """A few human-readable lines: costs, iterations, reason, backend and time split."""
        return (
            f"{self.method.upper()}: cost {self.initial_cost:.10g} -> {self.final_cost:.10g} in "
            f"{self.iterations} iterations ({self.termination}); linear solver {self.linear_solver}\n"
            f"time {self.seconds_total:.3f} s: setup {self.seconds_setup:.3f}, linearize "
            f"{self.seconds_linearize:.3f}, assemble {self.seconds_assemble:.3f}, factorize "
            f"{self.seconds_factorize:.3f}, solve {self.seconds_solve:.3f}"
        )
