"""Conjugate gradients preconditioned by aggregation multigrid, for block SPD systems too large
to factorise.

The Cholesky factor of a pose graph's normal equations grows as n log n on a surface-like graph
(a 200,000-pose sphere: ~22 kB a pose), the matrix itself only as n (~2.6 kB a pose). Algebraic
multigrid by aggregation (Vaněk, Mandel and Brezina, "Algebraic multigrid by smoothed aggregation
for second and fourth order elliptic problems", 1996; pyamg's ``smoothed_aggregation_solver``)
builds a hierarchy of coarser systems from the matrix alone, and one cycle of it preconditions CG
(Hestenes–Stiefel; scipy's ``cg``).

Aggregation needs the *near-null space* ``B``: the vectors the matrix barely moves, which the
coarse levels must represent exactly. For a pose graph with right perturbations they are the
global motions: left-multiplying every pose by ``Exp(ξ)`` changes no residual, and in each
vertex's tangent that motion is ``δ_k = Ad(X_k⁻¹) ξ``, so ``B`` stacks the d×d blocks
``Ad(X_k⁻¹)`` (exactly H's null space before the anchor is removed; :func:`pose_null_space`).
With identity blocks instead CG needs several times the iterations (``benchmarks/bench_memory.py pcg``).

Two settings (``smoothed``): the solver's, plain aggregation (prolongators unsmoothed) with a
W-cycle, whose hierarchy is small beside H and cheap to set up; and smoothed aggregation (one
Jacobi step on each prolongator) with a V-cycle, about half the iterations, but its prolongators
and their set-up take as much memory again as H (~0.9 GiB on the 200,000-pose sphere) — used for
the chordal start's smaller r×r systems. Aggregates (which vertices merge into one coarse vertex)
depend on the graph, not the values, so they are computed at the first
:meth:`MultigridCG.factorize` and reused after (pyamg's ``predefined`` aggregation). The smoother
is one forward block Gauss–Seidel sweep before and one backward after, so the cycle is a
symmetric positive-definite operator, as CG needs.

pyamg is an optional dependency (``pip install "posegraph[large]"``); :func:`available` says
whether it imports.
"""

from __future__ import annotations

import numpy as np

from posegraph.linalg.cholmod import NotPositiveDefiniteError

__all__ = ["MultigridCG", "available", "pose_null_space", "DEFAULT_TOLERANCE", "INSTALL_HINT"]

DEFAULT_TOLERANCE = 1e-8
"""Relative residual ‖b − Ax‖ / ‖b‖ at which CG stops (the solver's floor under its forcing terms).
Inexact Gauss-Newton steps slow LM's last iterations; at 1e-8 the steps are what a factorisation
gives as far as LM's convergence tests see (final costs equal to the factorisation's to ≤ 2e-10
relative on the test graphs)."""

MAX_ITERATIONS = 1000
"""CG iterations before a solve is given up (raises :class:`NotPositiveDefiniteError`)."""

RESTARTS = 3
"""Restarts from the current solution when CG's own residual met the tolerance but ``b − Ax`` did not."""

COARSEST_UNKNOWNS = 500
"""Coarsening stops below this many unknowns; that level is solved by SuperLU."""

INSTALL_HINT = 'pip install "posegraph[large]" (pyamg)'

_SWEEP = ("block_gauss_seidel", {"sweep": "forward"}), ("block_gauss_seidel", {"sweep": "backward"})


def available() -> bool:
    """Whether pyamg imports."""
    try:
        import pyamg  # noqa: F401
    except ImportError:
        return False
    return True


def factorisation_fits(block_indptr, block_indices, num_blocks: int, block: int, ordering: str = "auto") -> bool:
    """Whether CHOLMOD's factor of a matrix of ``block``×``block`` blocks on this vertex pattern fits
    in memory (:func:`posegraph.linalg.cholmod.block_factor_bytes`, :func:`posegraph.linalg.heap.factor_exceeds_memory`).
    When it does not: a warning that conjugate gradients solve instead, saying both sizes, or
    without pyamg an ``ImportError`` with the sizes, the install hint and how to factorise anyway."""
    from posegraph.linalg import cholmod
    from posegraph.linalg.heap import factor_exceeds_memory

    reason = factor_exceeds_memory(cholmod.block_factor_bytes(block_indptr, block_indices, num_blocks, block, ordering))
    if reason is None:
        return True
    if not available():
        raise ImportError(f"{reason}; {INSTALL_HINT} to solve it by conjugate gradients (linear solver 'auto' "
                          "then does), or ask for linear solver 'cholmod' to factorise anyway")  # fmt: skip
    import warnings

    from posegraph.errors import PosegraphWarning

    warnings.warn(f"{reason}: solving by multigrid-preconditioned conjugate gradients (linear solver 'pcg')",
                  PosegraphWarning, stacklevel=4)  # fmt: skip
    return False


def pose_null_space(group, poses: np.ndarray) -> np.ndarray:
    """``(p·d, d)`` stacked ``Ad(X_k⁻¹)`` for ``poses`` ``(p, k, k)``: the tangent of a global left motion."""
    blocks = group.adjoint(group.inverse(poses))
    return np.ascontiguousarray(blocks.reshape(-1, blocks.shape[-1]))


class MultigridCG:
    """``factorize(matrix, near_null_space)`` builds the hierarchy; ``solve(rhs)`` runs PCG.

    ``matrix``: scipy ``bsr_matrix`` (both triangles, d×d blocks), symmetric positive definite.
    ``tolerance``: CG's relative residual. ``smoothed``: smoothed aggregation and a V-cycle, else
    plain aggregation and a W-cycle (module docstring). ``iterations`` lists the CG iterations of
    each solve. Without pyamg: ``ImportError`` with the install hint.
    """

    def __init__(self, tolerance: float = DEFAULT_TOLERANCE, max_iterations: int = MAX_ITERATIONS, smoothed: bool = False):
        if not available():
            raise ImportError(f"linear_solver='pcg' needs pyamg: {INSTALL_HINT}")
        import pyamg

        self._pyamg = pyamg
        self.tolerance, self.max_iterations, self.smoothed = tolerance, max_iterations, smoothed
        self._aggregates = None  # per-level aggregation operators, from the first set-up
        self._matrix = self._preconditioner = None
        self.iterations: list[int] = []

    def factorize(self, matrix, near_null_space: np.ndarray) -> None:
        """The multigrid hierarchy of ``matrix``; :class:`NotPositiveDefiniteError` when an entry is not finite."""
        if not np.isfinite(matrix.data).all():
            raise NotPositiveDefiniteError("matrix has non-finite entries")
        self._matrix = self._preconditioner = None  # the last hierarchy is freed before the next is built
        levels = {}
        if self._aggregates:  # the same levels as the first set-up
            levels = dict(aggregate=[("predefined", {"AggOp": a}) for a in self._aggregates],
                          max_levels=len(self._aggregates) + 1)  # fmt: skip
        hierarchy = self._pyamg.smoothed_aggregation_solver(
            matrix, B=near_null_space, symmetry="hermitian", smooth="jacobi" if self.smoothed else None, improve_candidates=None,
            max_coarse=COARSEST_UNKNOWNS, coarse_solver="splu", presmoother=_SWEEP[0], postsmoother=_SWEEP[1],
            keep=self._aggregates is None, **levels,
        )  # fmt: skip
        if self._aggregates is None:
            self._aggregates = [level.AggOp for level in hierarchy.levels[:-1]]
            for level in hierarchy.levels:  # only the aggregates were wanted from `keep`
                for name in ("C", "T", "AggOp", "P_unsmoothed"):
                    level.__dict__.pop(name, None)
        self._matrix = matrix
        self._preconditioner = hierarchy.aspreconditioner(cycle="V" if self.smoothed else "W")

    def release(self) -> None:
        """Drop the matrix and the hierarchy (the aggregates stay); :meth:`factorize` must come next."""
        self._matrix = self._preconditioner = None

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        """``x`` with ‖rhs − A x‖ ≤ tolerance·‖rhs‖, ``rhs`` ``(N,)`` or ``(N, k)`` (one CG per column).

        Raises :class:`NotPositiveDefiniteError` when CG breaks down (the matrix is not positive
        definite to working precision) or does not converge within ``max_iterations``."""
        if self._preconditioner is None:
            raise RuntimeError("factorize() must succeed before solve()")
        rhs = np.asarray(rhs, dtype=np.float64)
        columns = rhs.reshape(rhs.shape[0], -1)
        solution = np.empty_like(columns)
        for c in range(columns.shape[1]):
            solution[:, c] = self._solve_one(columns[:, c])
        return solution.reshape(rhs.shape)

    def _solve_one(self, rhs: np.ndarray) -> np.ndarray:
        from scipy.sparse.linalg import cg

        count = [0]

        def counted(_):
            count[0] += 1

        x = np.zeros_like(rhs)
        goal = self.tolerance * np.linalg.norm(rhs)
        for _ in range(RESTARTS + 1):
            # CG's recurrence residual drifts from b − Ax at tight tolerances: checked, restarted from x
            correction, info = cg(self._matrix, rhs - self._matrix @ x, rtol=0.0, atol=goal,
                                  maxiter=self.max_iterations - count[0], M=self._preconditioner, callback=counted)  # fmt: skip
            x += correction
            if info < 0 or not np.isfinite(x).all() or np.linalg.norm(rhs - self._matrix @ x) <= goal:
                break
        self.iterations.append(count[0])
        if info != 0 or not np.isfinite(x).all():
            reason = "did not converge" if info > 0 else "broke down"
            raise NotPositiveDefiniteError(f"preconditioned CG {reason} after {count[0]} iterations")
        return x
