"""One small interface to a matrix Lie group, so that the solver is written once for all of them.

A :class:`LieGroup` bundles the batched functions of one group module (:mod:`posegraph.lie.se3`,
:mod:`posegraph.lie.se2`, :mod:`posegraph.lie.sim3`) with the two sizes the
solver needs: the tangent dimension (the block size of the normal equations) and the size of the
matrices that represent the elements; and, for the initialisers, where the rotation and the
translation sit in the tangent and the rotation group's module. Conventions are the project's (``docs/architecture.md``):
right perturbations ``X ⊕ δ = X·Exp(δ)``, ``Y ⊖ X = Log(X⁻¹Y)``, right Jacobians, tangent order as
gtsam's. Every callable takes any leading batch shape.

With these, an edge residual ``e = Log(Z⁻¹ X_i⁻¹ X_j)`` has the Jacobians (any group)::

    ∂e/∂δ_j = Jr⁻¹(e),      ∂e/∂δ_i = −Jr⁻¹(e) · Ad(X_j⁻¹ X_i)

(:mod:`posegraph.solve.residuals`). Adding a group is one :meth:`LieGroup.of` line below.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from types import ModuleType
from typing import Callable

import numpy as np

from posegraph.lie import se2, se3, sim3, so2, so3

__all__ = ["LieGroup", "SE3", "SE2", "SIM3", "SIM3_G2O", "embed_in_se3"]


@dataclass(frozen=True)
class LieGroup:
    """A matrix Lie group as the solver and the initialisers see it: sizes, axes and batched functions."""

    name: str
    """Short name, e.g. ``"SE3"``."""
    dim: int
    """Tangent dimension ``d`` (6 for SE(3), 3 for SE(2), 7 for Sim(3)): the block size of H."""
    matrix_size: int
    """Elements are ``(…, matrix_size, matrix_size)`` matrices (4 for SE(3), 3 for SE(2))."""
    exp: Callable
    """``(…, d) -> (…, k, k)``: ``Exp(ξ)``."""
    log: Callable
    """``(…, k, k) -> (…, d)``: ``Log(X)``, the inverse of ``exp`` on its principal domain."""
    inverse: Callable
    """``(…, k, k) -> (…, k, k)``: ``X⁻¹``."""
    compose: Callable
    """``(a, b) -> a·b``, batch shapes broadcast."""
    between: Callable
    """``(a, b) -> a⁻¹·b``, batch shapes broadcast."""
    adjoint: Callable
    """``(…, k, k) -> (…, d, d)``: ``Ad(X)``, with ``X·Exp(δ) = Exp(Ad(X) δ)·X``."""
    right_jacobian: Callable
    """``(…, d) -> (…, d, d)``: ``Jr(ξ)``, ``Exp(ξ + δ) ≈ Exp(ξ)·Exp(Jr(ξ) δ)``."""
    right_jacobian_inverse: Callable
    """``(…, d) -> (…, d, d)``: ``Jr(ξ)⁻¹``, the Jacobian of ``Log`` under right perturbations."""
    left_jacobian_inverse: Callable | None = None
    """``(…, d) -> (…, d, d)``: ``Jl(ξ)⁻¹`` (the solver does not need it); at ``ξ = [ω; 0]`` its translation block is ``V(ω)⁻¹``,
    which maps a pose's translation to the translation part of its ``Log`` (the chordal start uses it)."""
    rotation_axes: tuple = ()
    """Tangent indices of the rotation part (``(0, 1, 2)`` of SE(3)'s ``[ω; v]``, ``(2,)`` of SE(2)'s
    ``[v_x, v_y, ω]``); the initialisers weigh rotations and translations by these blocks of Ω."""
    translation_axes: tuple = ()
    """Tangent indices of the translation part (``(3, 4, 5)`` for SE(3), ``(0, 1)`` for SE(2))."""
    rotations: ModuleType | None = None
    """The rotation group's module (:mod:`posegraph.lie.so3`, :mod:`posegraph.lie.so2`): ``log``,
    ``project`` of the ``(…, r, r)`` rotation blocks, ``r = matrix_size − 1``."""
    scale_axes: tuple = ()
    """Tangent index of the log-scale λ (``(6,)`` for Sim(3)); empty for the rigid groups."""
    residual_log: Callable | None = None
    """``(…, k, k) -> (…, d)``: the ``Log`` edge residuals use when a file format defines its cost with
    its own (g2o's ``EdgeSim3``: :func:`posegraph.lie.sim3.g2o_log`, first-order near θ = 0 and
    λ = 0); None: :attr:`log`. The Jacobians are those of :attr:`log` either way."""
    edge_errors: Callable | None = None
    """``(Z, X_i, X_j) -> (X_i⁻¹X_j (…, k, k), Log(Z⁻¹X_i⁻¹X_j) (…, d))`` in one pass, bit for bit :attr:`between`
    then :attr:`log` (:func:`posegraph.lie.se2.edge_errors`); None: the residuals compose those two."""
    adjoint_of_inverse: Callable | None = None
    """``(…, k, k) -> (…, d, d)``: ``Ad(X⁻¹)`` in one pass, bit for bit :attr:`adjoint` of :attr:`inverse`; None: those two."""

    @property
    def edge_log(self) -> Callable:
        """The ``Log`` of edge residuals: :attr:`residual_log` if set, else :attr:`log`."""
        return self.residual_log if self.residual_log is not None else self.log

    @property
    def rotation_block(self) -> slice:
        """``rotation_axes`` as a slice (they are contiguous in every group here), for views of Ω's blocks."""
        return slice(self.rotation_axes[0], self.rotation_axes[-1] + 1)

    @property
    def translation_block(self) -> slice:
        """``translation_axes`` as a slice."""
        return slice(self.translation_axes[0], self.translation_axes[-1] + 1)

    @property
    def space_dim(self) -> int:
        """``r = matrix_size − 1``: the dimension of the space the poses act on (3 or 2)."""
        return self.matrix_size - 1

    @classmethod
    def of(
        cls, name: str, module: ModuleType, dim: int, matrix_size: int, *,
        rotation_axes: tuple = (), translation_axes: tuple = (), rotations: ModuleType | None = None,
        scale_axes: tuple = (),
    ) -> "LieGroup":  # fmt: skip
        """The group whose functions are those of ``module`` (named as in :mod:`posegraph.lie.se3`).

        Each callable looks its function up in ``module`` when called, so the group always runs
        what the module holds (a test that replaces ``se3.right_jacobian_inverse`` sees it used
        by the solver's Jacobians too); the lookup costs ~0.1 µs per batched call.
        """
        functions = {f: _forward(module, f) for f in _FUNCTIONS}
        functions.update({f: _forward(module, f) for f in _FUSED if hasattr(module, f)})
        return cls(
            name=name, dim=dim, matrix_size=matrix_size, **functions,
            rotation_axes=tuple(rotation_axes), translation_axes=tuple(translation_axes), rotations=rotations,
            scale_axes=tuple(scale_axes),
        )  # fmt: skip

    def __repr__(self) -> str:
        own_log = "" if self.residual_log is None else ", residual_log=" + self.residual_log.__name__
        return f"LieGroup({self.name}, dim={self.dim}, matrix_size={self.matrix_size}{own_log})"


def _forward(module: ModuleType, name: str) -> Callable:
    """``module.<name>(*args)``, looked up at each call."""

    def call(*args):
        return getattr(module, name)(*args)

    call.__name__, call.__qualname__ = name, f"{module.__name__}.{name}"
    call.__doc__ = getattr(module, name).__doc__
    return call


_FUNCTIONS = (
    "exp", "log", "inverse", "compose", "between", "adjoint", "right_jacobian", "right_jacobian_inverse",
    "left_jacobian_inverse",
)

_FUSED = ("edge_errors", "adjoint_of_inverse")
"""Optional one-pass forms of compositions the solver's hot path runs (a module without them gets None)."""

SE3 = LieGroup.of("SE3", se3, 6, 4, rotation_axes=(0, 1, 2), translation_axes=(3, 4, 5), rotations=so3)
"""Rigid motions in 3D: ``(…, 4, 4)`` matrices, tangent ``[ω; v]``."""
SE2 = LieGroup.of("SE2", se2, 3, 3, rotation_axes=(2,), translation_axes=(0, 1), rotations=so2)
"""Rigid motions in the plane: ``(…, 3, 3)`` matrices, tangent ``[v_x, v_y, ω]``."""
SIM3 = LieGroup.of(
    "SIM3", sim3, 7, 4, rotation_axes=(0, 1, 2), translation_axes=(3, 4, 5), rotations=so3, scale_axes=(6,),
)  # fmt: skip
"""Similarities in 3D: ``(…, 4, 4)`` matrices ``[[s R, t], [0, 1]]``, tangent ``[ω; υ; λ]``, λ = log s."""
SIM3_G2O = replace(SIM3, residual_log=_forward(sim3, "g2o_log"))
"""Sim(3) with g2o's ``EdgeSim3`` error as the cost (:func:`posegraph.lie.sim3.g2o_log`): what the
g2o reader gives Sim(3) files, so that the χ² reported is the one g2o computes."""


def embed_in_se3(poses):
    """``poses`` as SE(3) matrices, for what is written or compared in 3D: SE(2)'s ``(…, 3, 3)``
    embedded in the plane z = 0 (:func:`posegraph.lie.se2.to_se3`); ``(…, 4, 4)`` as they are, except
    that a Sim(3) pose ``[[s R, t], [0, 1]]`` becomes ``[[R, t], [0, 1]]`` (its scale applied, as a
    monocular system corrects its keyframes after a Sim(3) optimisation: the camera keeps its
    position ``t``). Poses with ``|s − 1| ≤ 1e-12`` (every SE(3) pose) are returned unchanged."""
    if np.shape(poses)[-1] == 3:
        return se2.to_se3(poses)
    poses = np.asarray(poses)
    s = sim3.scale(poses) if poses.size else np.ones(poses.shape[:-2])
    if np.all(np.abs(s - 1.0) <= _UNIT_SCALE_TOLERANCE):
        return poses
    out = np.array(poses, dtype=np.float64)
    out[..., :3, :3] /= np.where(np.abs(s - 1.0) <= _UNIT_SCALE_TOLERANCE, 1.0, s)[..., None, None]
    return out


_UNIT_SCALE_TOLERANCE = 1e-12
"""Scales this close to 1 are taken as rigid motions by :func:`embed_in_se3` (SE(3) poses have det(R) = 1 to ~1e-16)."""
