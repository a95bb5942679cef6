"""Cross-validation of the Lie-group core and the edge Jacobians (``posegraph verify-jacobians``).

Every quantity is computed by this project for a batch of cases and compared with an independent
reference:

* **gtsam** (optional): ``Rot3``/``Pose3``/``Pose2`` ``Expmap``, ``Logmap``, ``ExpmapDerivative`` (= Jr),
  ``LogmapDerivative`` (= Jr⁻¹), ``AdjointMap``, and the whitened Jacobians of
  ``BetweenFactorPose3`` / ``BetweenFactorPose2`` from ``linearize`` with a unit noise model (so the blocks are the plain
  Jacobians ∂e/∂δ of ``e = Log(Z⁻¹ X_i⁻¹ X_j)``, and ``b = −e``);
* **central finite differences** on the manifold, with right perturbations ``X ⊕ δ = X·Exp(δ)``:
  ``Jr(ξ)`` column k is ``[Log(Exp(ξ)⁻¹ Exp(ξ + h e_k)) − Log(Exp(ξ)⁻¹ Exp(ξ − h e_k))] / 2h``,
  ``Jl(ξ)`` the same with ``Exp(ξ ± h e_k) Exp(ξ)⁻¹``, ``Jr⁻¹(ξ)`` from ``Log(Exp(ξ) Exp(±h e_k))``
  and the edge Jacobians from ``e(X_i Exp(±h e_k), X_j)`` and ``e(X_i, X_j Exp(±h e_k))``;
* **identities**: ``Log(Exp(ξ)) = ξ`` for rotation angles below π, and
  ``X Exp(δ) X⁻¹ = Exp(Ad(X) δ)`` for the adjoint.

Groups: SO(3), SE(3), SO(2) (whose Jacobians are all ``[[1]]``: identities and finite differences
only), SE(2) and Sim(3) (gtsam's ``Similarity3`` has ``Expmap``, ``Logmap`` and ``AdjointMap`` but no
``ExpmapDerivative``/``LogmapDerivative``: its Jacobians are checked by finite differences and
identities, its edges against ``BetweenFactorSimilarity3``; log-scales λ are 0, near 0 and ~N(0, ½)). Cases: random tangents (rotation angle uniform in [0, π), translations of size ~1–10), angles
near 0 (0, 1e-12 … 1e-2, where closed forms need their Taylor branches) and near π (π − 1e-12 …
π − 1e-3, where ``Log`` must not divide by sin θ), and, when a graph is given, its edges at the
file's poses.

Each check reports the largest difference over its cases, scaled as ``|a − b| / (1 + |b|)``
elementwise (relative for large entries, absolute for small ones), against a tolerance:

* :data:`CLOSED_FORM_TOLERANCE` (1e-9) — against gtsam and for the identities: both sides are
  closed forms evaluated in double precision; agreement is expected to ~1e-14, and 1e-9 leaves
  margin for near-π cases whose conditioning loses a few digits in either library.
* :data:`GTSAM_NEAR_PI_TOLERANCE` (1e-6) — against gtsam's ``Logmap`` and ``LogmapDerivative``
  (SO(3) and SE(3)) for angles near π only. gtsam switches to a truncated expansion there: measured
  against 50-digit mpmath evaluations of the closed forms, gtsam 4.3's ``Rot3.LogmapDerivative``
  is off by 5e-10 at π − 1e-4 and 4e-8 at π − 1e-3, and ``Pose3.Logmap``'s translation by 3e-7 at
  π − 1e-3, while this project's stay at ~1e-15 (``docs/cli.md``). Our side is held to 1e-9 near π by
  the identities ``Log(Exp ξ) = ξ`` and ``Jr⁻¹·Jr = I`` and by the finite differences.
* :data:`GTSAM_POSE2_MIN_ANGLE` (1e-2) — gtsam's ``Pose2`` ``Expmap``, ``ExpmapDerivative`` and
  ``LogmapDerivative`` (and ``Logmap``, by ~1e-8) lose digits at small angles ω (gtsam 4.3, at
  |v| ≈ 8: ``Expmap`` off by 6e-7 at ω = 1e-10, ``ExpmapDerivative`` by 1.2·ω below 1e-4,
  ``LogmapDerivative`` by 3.7e-4 at ω = 1e-4 and 1e-7 at 1e-3, all below 2e-10 from 1e-2 on), while
  this project's SE(2) agrees with finite differences there. So ``Pose2`` and
  ``BetweenFactorPose2``'s Jacobians are compared with gtsam only where the (residual's) angle is at
  least 1e-2; the edge residuals on all cases, and everything against finite differences.
* :data:`FINITE_DIFFERENCE_TOLERANCE` (1e-6) — against central differences with step
  :data:`FINITE_DIFFERENCE_STEP` (1e-6): truncation error ~h²·|f'''| ≈ 1e-12 and round-off
  ~ε/h ≈ 1e-10 per entry, so 1e-6 only fails for a wrong formula (a sign, a transpose, a missing
  term, a wrong branch), never for noise. Near π the step is shrunk so that ``θ ± h`` stays
  below π, where ``Log`` is continuous.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

__all__ = [
    "CLOSED_FORM_TOLERANCE",
    "GTSAM_NEAR_PI_TOLERANCE",
    "FINITE_DIFFERENCE_TOLERANCE",
    "FINITE_DIFFERENCE_STEP",
    "Check",
    "verify_all",
    "format_checks",
]

CLOSED_FORM_TOLERANCE = 1e-9
GTSAM_NEAR_PI_TOLERANCE = 1e-6
FINITE_DIFFERENCE_TOLERANCE = 1e-6
FINITE_DIFFERENCE_STEP = 1e-6
GTSAM_POSE2_MIN_ANGLE = 1e-2

NEAR_ZERO_ANGLES = np.array([0.0, 1e-12, 1e-10, 1e-8, 1e-6, 1e-5, 1e-4, 1e-3, 1e-2])
NEAR_PI_MARGINS = np.array([1e-12, 1e-10, 1e-8, 1e-6, 1e-5, 1e-4, 1e-3])
"""Angles ``π − margin``. Finite differences use only margins ≥ 1e-5 with a step of a tenth
of the margin, so that ``θ ± h`` stays below π."""


@dataclass(frozen=True)
class Check:
    """One quantity compared with one reference on one family of cases."""

    quantity: str
    """What was computed, e.g. ``"so3.right_jacobian"``."""
    reference: str
    """What it was compared with, e.g. ``"gtsam Rot3.ExpmapDerivative"`` or ``"finite differences"``."""
    cases: str
    """``"random"``, ``"near 0"``, ``"near π"`` or ``"edges of FILE"``."""
    count: int
    """Number of cases compared."""
    max_difference: float
    """Largest ``|a − b| / (1 + |b|)`` over all entries of all cases."""
    tolerance: float

    @property
    def passed(self) -> bool:
        return bool(self.max_difference <= self.tolerance)  # NaN fails

    @property
    def name(self) -> str:
        return f"{self.quantity} vs {self.reference} ({self.cases})"


def _scaled_difference(a: np.ndarray, b: np.ndarray) -> float:
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if a.shape != b.shape:
        raise ValueError(f"shapes differ: {a.shape} vs {b.shape}")
    if a.size == 0:
        return 0.0
    d = np.abs(a - b) / (1.0 + np.abs(b))
    return float(np.max(np.where(np.isnan(d), np.inf, d)))


# ----------------------------------------------------------------------------------- cases


def _unit_vectors(rng, n):
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def rotation_cases(rng, samples: int) -> dict[str, np.ndarray]:
    """Tangents ``(k, 3)`` of SO(3) by family: random, near 0, near π."""
    random = _unit_vectors(rng, samples) * rng.uniform(0, np.pi, size=(samples, 1))
    near_zero = _unit_vectors(rng, len(NEAR_ZERO_ANGLES)) * NEAR_ZERO_ANGLES[:, None]
    near_pi = _unit_vectors(rng, len(NEAR_PI_MARGINS)) * (np.pi - NEAR_PI_MARGINS)[:, None]
    return {"random": random, "near 0": near_zero, "near π": near_pi}


def planar_rotation_cases(rng, samples: int) -> dict[str, np.ndarray]:
    """Tangents ``(k, 1)`` of SO(2) by family: random in (−π, π), near 0 and near ±π (random signs)."""
    sign = lambda k: rng.choice([-1.0, 1.0], size=(k, 1))  # noqa: E731
    return {
        "random": rng.uniform(-np.pi, np.pi, size=(samples, 1)),
        "near 0": sign(len(NEAR_ZERO_ANGLES)) * NEAR_ZERO_ANGLES[:, None],
        "near π": sign(len(NEAR_PI_MARGINS)) * (np.pi - NEAR_PI_MARGINS)[:, None],
    }


def _with_translations(rng, rotations: dict[str, np.ndarray], size: int, first: bool) -> dict[str, np.ndarray]:
    """Each family's rotation tangents joined to random translations of ``size`` entries (~1 or ~10)."""
    out = {}
    for family, omega in rotations.items():
        v = rng.normal(size=(len(omega), size)) * rng.choice([1.0, 10.0], size=(len(omega), 1))
        out[family] = np.concatenate([omega, v] if first else [v, omega], axis=1)
    return out


def pose_cases(rng, samples: int) -> dict[str, np.ndarray]:
    """Tangents ``(k, 6)`` ``[ω; v]`` of SE(3) by family (rotation parts as :func:`rotation_cases`)."""
    return _with_translations(rng, rotation_cases(rng, samples), 3, first=True)


def similarity_cases(rng, samples: int) -> dict[str, np.ndarray]:
    """Tangents ``(k, 7)`` ``[ω; υ; λ]`` of Sim(3): :func:`pose_cases` and λ, a quarter each 0 and
    within 1e-6 of it (the Taylor branches), the rest ~N(0, ½)."""
    out = {}
    for family, xi in pose_cases(rng, samples).items():
        lam = rng.normal(scale=0.5, size=len(xi))
        lam[::4] = 0.0
        lam[1::4] *= 1e-6
        out[family] = np.concatenate([xi, lam[:, None]], axis=1)
    return out


def planar_pose_cases(rng, samples: int) -> dict[str, np.ndarray]:
    """Tangents ``(k, 3)`` ``[v_x, v_y, ω]`` of SE(2) by family (angles as :func:`planar_rotation_cases`)."""
    return _with_translations(rng, planar_rotation_cases(rng, samples), 2, first=False)


class _Group(NamedTuple):
    """One group checked: its module's name and module, its cases, where its rotation angle is, gtsam's class."""

    name: str
    module: object
    cases: object
    rotation_axes: tuple
    gtsam_class: str | None


def _groups() -> list[_Group]:
    from posegraph.lie import se2, se3, sim3, so2, so3

    return [
        _Group("so3", so3, rotation_cases, (0, 1, 2), "Rot3"),
        _Group("se3", se3, pose_cases, (0, 1, 2), "Pose3"),
        _Group("so2", so2, planar_rotation_cases, (0,), None),  # every Jacobian is [[1]]: no gtsam needed
        _Group("se2", se2, planar_pose_cases, (2,), "Pose2"),
        _Group("sim3", sim3, similarity_cases, (0, 1, 2), "Similarity3"),
    ]


def _angles(tangents: np.ndarray, rotation_axes) -> np.ndarray:
    return np.linalg.norm(tangents[:, list(rotation_axes)], axis=1)


def _fd_steps(family: str, tangents: np.ndarray, rotation_axes=(0, 1, 2)) -> np.ndarray:
    """Per-case finite-difference step: the default, or a tenth of the distance to π."""
    h = np.full(len(tangents), FINITE_DIFFERENCE_STEP)
    if family == "near π":
        h = np.minimum(h, (np.pi - _angles(tangents, rotation_axes)) / 10)
    return h


def _usable_for_fd(family: str, tangents: np.ndarray, rotation_axes=(0, 1, 2)) -> np.ndarray:
    if family != "near π":
        return tangents
    return tangents[np.pi - _angles(tangents, rotation_axes) >= 1e-5]


# ------------------------------------------------------------------------ finite differences


def _central_columns(f, x: np.ndarray, h: np.ndarray) -> np.ndarray:
    """``(k, d_out, d)``: column c of each Jacobian is ``(f(x, +h e_c) − f(x, −h e_c)) / 2h``.

    ``f(x, delta)`` maps a batch ``(k, d)`` and perturbations ``(k, d)`` to ``(k, d_out)``.
    """
    k, d = x.shape
    columns = []
    for c in range(d):
        e = np.zeros((k, d))
        e[:, c] = h
        columns.append((f(x, e) - f(x, -e)) / (2 * h[:, None]))
    return np.stack(columns, axis=-1)


def _fd_jacobians(group, tangents: np.ndarray, h: np.ndarray) -> dict[str, np.ndarray]:
    """Finite-difference Jr, Jl and Jr⁻¹ of ``group`` (a :mod:`posegraph.lie` module) at ``tangents``."""
    X = group.exp(tangents)
    X_inv = _inverse(group, X)
    right = _central_columns(lambda x, d: group.log(X_inv @ group.exp(x + d)), tangents, h)
    left = _central_columns(lambda x, d: group.log(group.exp(x + d) @ X_inv), tangents, h)
    right_inverse = _central_columns(lambda x, d: group.log(X @ group.exp(d)), tangents, h)
    return {"right_jacobian": right, "left_jacobian": left, "right_jacobian_inverse": right_inverse}


def _inverse(group, X):
    if hasattr(group, "inverse"):
        return group.inverse(X)
    return np.swapaxes(X, -1, -2)  # SO(3), SO(2)


# ------------------------------------------------------------------------------- gtsam side


def _gtsam_group(gtsam, class_name: str, xi: np.ndarray) -> dict[str, np.ndarray]:
    """gtsam's ``Expmap`` (as matrices and its ``Logmap`` of them), derivatives and, for poses, ``AdjointMap``."""
    cls = getattr(gtsam, class_name)
    out: dict[str, list] = {"exp": [], "log": [], "right_jacobian": [], "right_jacobian_inverse": [], "adjoint": []}
    for x in xi:
        element = cls.Expmap(x)
        out["exp"].append(_gtsam_matrix(element))
        out["log"].append(np.asarray(cls.Logmap(element)).reshape(-1))
        if hasattr(cls, "ExpmapDerivative"):  # Similarity3 has neither derivative
            out["right_jacobian"].append(cls.ExpmapDerivative(x))
            out["right_jacobian_inverse"].append(cls.LogmapDerivative(x))
        if hasattr(element, "AdjointMap"):
            out["adjoint"].append(element.AdjointMap())
    return {name: np.array(values) for name, values in out.items()}


def _gtsam_matrix(element) -> np.ndarray:
    """gtsam's element as this project's matrix: ``matrix()``, scaled by ``s`` for ``Similarity3``
    (``[[R, t], [0, 1/s]]`` → ``[[s R, s t], [0, 1]]``, :mod:`posegraph.lie.sim3`)."""
    if hasattr(element, "scale"):
        return element.scale() * element.matrix()
    return element.matrix()


def _gtsam_between(gtsam, Xi, Xj, Z, group):
    """Residuals ``(m, d)`` and Jacobians ``(m, d, d)`` ×2 of gtsam's BetweenFactorPose3 (Pose2,
    Similarity3 for those groups), unit noise."""
    from posegraph.crosscheck.gtsam_bridge import _gtsam_pose, _gtsam_similarity

    d = group.dim
    between = {3: gtsam.BetweenFactorPose2, 6: gtsam.BetweenFactorPose3, 7: gtsam.BetweenFactorSimilarity3}[d]
    element = (lambda M: _gtsam_similarity(gtsam, M)) if d == 7 else (lambda M: _gtsam_pose(gtsam, M))
    unit = gtsam.noiseModel.Unit.Create(d)
    residuals, jac_i, jac_j = [], [], []
    for a, b, z in zip(Xi, Xj, Z):
        factor = between(0, 1, element(z), unit)
        values = gtsam.Values()
        values.insert(0, element(a))
        values.insert(1, element(b))
        A, rhs = factor.linearize(values).jacobian()
        jac_i.append(A[:, :d])
        jac_j.append(A[:, d:])
        residuals.append(-np.asarray(rhs).reshape(d))
    return np.array(residuals), np.array(jac_i), np.array(jac_j)


# ---------------------------------------------------------------------------------- checks


def _lie_checks(rng, samples: int, gtsam) -> list[Check]:
    """Every group of :func:`_groups` on every family of its cases."""
    checks: list[Check] = []
    for group in _groups():
        for family, xi in group.cases(rng, samples).items():
            checks += _identity_checks(group, family, xi, rng)
            if gtsam is not None and group.gtsam_class is not None:
                checks += _gtsam_checks(group, family, xi, gtsam)
            checks += _finite_difference_checks(group, family, xi)
    return checks


def _identity_checks(group: _Group, family: str, xi: np.ndarray, rng) -> list[Check]:
    """``Log(Exp ξ) = ξ``, ``Jr⁻¹·Jr = I``, ``Jl⁻¹·Jl = I`` and, for poses, the adjoint's defining identity."""
    g, n, k = group.module, group.name, len(xi)
    eye = np.broadcast_to(np.eye(xi.shape[1]), (k, xi.shape[1], xi.shape[1]))
    X = g.exp(xi)
    checks = [
        Check(f"{n}.log({n}.exp(ξ))", "ξ", family, k, _scaled_difference(g.log(X), xi), CLOSED_FORM_TOLERANCE),
        Check(f"{n}.right_jacobian_inverse", f"inverse of {n}.right_jacobian", family, k,
              _scaled_difference(g.right_jacobian_inverse(xi) @ g.right_jacobian(xi), eye), CLOSED_FORM_TOLERANCE),
        Check(f"{n}.left_jacobian_inverse", f"inverse of {n}.left_jacobian", family, k,
              _scaled_difference(g.left_jacobian_inverse(xi) @ g.left_jacobian(xi), eye), CLOSED_FORM_TOLERANCE),
    ]  # fmt: skip
    if hasattr(g, "adjoint"):
        # Ad(X) δ = Log(X Exp(δ) X⁻¹) for small δ, checked through Exp to avoid Log's branches.
        delta = rng.normal(scale=0.1, size=xi.shape)
        lhs = X @ g.exp(delta) @ g.inverse(X)
        rhs = g.exp(np.einsum("kij,kj->ki", g.adjoint(X), delta))
        checks.append(Check(f"{n}.adjoint", "X·Exp(δ)·X⁻¹ = Exp(Ad(X)·δ)", family, k, _scaled_difference(lhs, rhs),
                            CLOSED_FORM_TOLERANCE))  # fmt: skip
    return checks


def _gtsam_checks(group: _Group, family: str, xi: np.ndarray, gtsam) -> list[Check]:
    """Exp, Log, Jr, Jr⁻¹ (and Ad) against gtsam's class; Log and Jr⁻¹ near π with gtsam's looser tolerance."""
    g, n, cls = group.module, group.name, group.gtsam_class
    ref = _gtsam_group(gtsam, cls, xi)
    near_pi = GTSAM_NEAR_PI_TOLERANCE if family == "near π" else CLOSED_FORM_TOLERANCE
    compared = [
        ("exp", g.exp(xi), "Expmap", CLOSED_FORM_TOLERANCE),
        ("log", g.log(ref["exp"]), "Logmap", near_pi),
        ("right_jacobian", g.right_jacobian(xi), "ExpmapDerivative", CLOSED_FORM_TOLERANCE),
        ("right_jacobian_inverse", g.right_jacobian_inverse(xi), "LogmapDerivative", near_pi),
    ]
    if hasattr(g, "adjoint"):
        compared.append(("adjoint", g.adjoint(g.exp(xi)), "AdjointMap", CLOSED_FORM_TOLERANCE))
    accurate = _angles(xi, group.rotation_axes) >= GTSAM_POSE2_MIN_ANGLE if cls == "Pose2" else np.ones(len(xi), bool)
    checks = []
    for name, mine, method, tolerance in compared:
        if accurate.any() and ref[name].size:  # Similarity3: no derivatives in gtsam  # module docstring: gtsam's Pose2 at small angles
            checks.append(Check(f"{n}.{name}", f"gtsam {cls}.{method}", family, int(accurate.sum()),
                                _scaled_difference(mine[accurate], ref[name][accurate]), tolerance))  # fmt: skip
    return checks


def _finite_difference_checks(group: _Group, family: str, xi: np.ndarray) -> list[Check]:
    """Jr, Jl and Jr⁻¹ against central differences (near π only where ``θ ± h`` stays below π)."""
    usable = _usable_for_fd(family, xi, group.rotation_axes)
    if not len(usable):
        return []
    fd = _fd_jacobians(group.module, usable, _fd_steps(family, usable, group.rotation_axes))
    return [
        Check(f"{group.name}.{name}", "finite differences", family, len(usable),
              _scaled_difference(getattr(group.module, name)(usable), fd[name]), FINITE_DIFFERENCE_TOLERANCE)
        for name in ("right_jacobian", "left_jacobian", "right_jacobian_inverse")
    ]  # fmt: skip


def _edge_checks(Xi, Xj, Z, family: str, gtsam, group) -> list[Check]:
    """Residuals and Jacobians of edges ``(Xi, Xj, Z)`` ``(m, k, k)`` each of ``group`` (a :class:`LieGroup`;
    its exact ``log``: g2o's first-order Sim(3) error is the cost, not what the Jacobians differentiate)."""
    from dataclasses import replace

    from posegraph.model.graph import PoseGraph
    from posegraph.solve.residuals import edge_jacobians, edge_residuals

    group = replace(group, residual_log=None)
    m, d = len(Xi), group.dim
    poses = np.concatenate([Xi, Xj])
    graph = PoseGraph(
        ids=np.arange(2 * m), poses=poses, edge_from=np.arange(m), edge_to=np.arange(m, 2 * m),
        measurements=Z, information=np.broadcast_to(np.eye(d), (m, d, d)).copy(), group=group,
    )  # fmt: skip
    residuals = edge_residuals(poses, graph)
    jac_i, jac_j = edge_jacobians(poses, graph)
    checks = []
    if gtsam is not None:
        ref_e, ref_i, ref_j = _gtsam_between(gtsam, Xi, Xj, Z, group)
        factor = "gtsam BetweenFactor" + {3: "Pose2", 6: "Pose3", 7: "Similarity3"}[d]
        checks.append(
            Check("edge residual", factor, family, m, _scaled_difference(residuals, ref_e), CLOSED_FORM_TOLERANCE)
        )
        # gtsam's Pose2 derivatives lose digits at small angles (module docstring).
        cases = _angles(residuals, group.rotation_axes) >= GTSAM_POSE2_MIN_ANGLE if d == 3 else np.ones(m, bool)
        # gtsam 4.3's Similarity3::Logmap returns the identity as its derivative, so the
        # BetweenFactorSimilarity3 Jacobians are exact only at a zero residual (∂e/∂δj = I always):
        # Sim(3)'s edge Jacobians are checked by finite differences alone.
        if cases.any() and d != 7:
            checks += [
                Check("edge Jacobian ∂e/∂δi", factor, family, int(cases.sum()),
                      _scaled_difference(jac_i[cases], ref_i[cases]), CLOSED_FORM_TOLERANCE),
                Check("edge Jacobian ∂e/∂δj", factor, family, int(cases.sum()),
                      _scaled_difference(jac_j[cases], ref_j[cases]), CLOSED_FORM_TOLERANCE),
            ]  # fmt: skip
    # Log is discontinuous where the residual's rotation angle reaches π: finite differences skip
    # the (rare) edges within 1e-4 of it; gtsam is compared on all of them above.
    smooth = _angles(residuals, group.rotation_axes) < np.pi - 1e-4
    Xi, Xj, Z, jac_i, jac_j = Xi[smooth], Xj[smooth], Z[smooth], jac_i[smooth], jac_j[smooth]
    m = len(Xi)
    h = np.full(m, FINITE_DIFFERENCE_STEP)
    Zinv = group.inverse(Z)
    zeros = np.zeros((m, d))
    fd_i = _central_columns(lambda x, t: group.log(Zinv @ group.inverse(Xi @ group.exp(t)) @ Xj), zeros, h)
    fd_j = _central_columns(lambda x, t: group.log(Zinv @ group.inverse(Xi) @ Xj @ group.exp(t)), zeros, h)
    checks += [
        Check("edge Jacobian ∂e/∂δi", "finite differences", family, m, _scaled_difference(jac_i, fd_i),
              FINITE_DIFFERENCE_TOLERANCE),
        Check("edge Jacobian ∂e/∂δj", "finite differences", family, m, _scaled_difference(jac_j, fd_j),
              FINITE_DIFFERENCE_TOLERANCE),
    ]  # fmt: skip
    return checks


def _random_edges(rng, samples: int, residual_scale: float, group):
    """Random edges ``(Xi, Xj, Z)`` of ``group`` (SE(3), SE(2), Sim(3)) with residuals of ``residual_scale``."""
    from posegraph.lie import se2, se3, sim3

    module, cases = {3: (se2, planar_pose_cases), 6: (se3, pose_cases), 7: (sim3, similarity_cases)}[group.dim]
    Xi = module.exp(cases(rng, samples)["random"])
    Xj = module.exp(cases(rng, samples)["random"])
    # Measurements close to the truth (residual angles ≲ 3·residual_scale, far from π).
    noise = rng.normal(scale=residual_scale, size=(samples, group.dim))
    Z = module.between(Xi, Xj) @ module.exp(noise)
    return Xi, Xj, Z


def verify_all(graph=None, *, samples: int = 500, seed: int = 0, use_gtsam: bool = True) -> list[Check]:
    """Run every check; returns the list of :class:`Check` (see the module docstring).

    ``graph``: also check the Jacobians of its edges at its poses. ``use_gtsam``: compare with
    gtsam when it is importable (ImportError with the install hint if asked for and missing).
    """
    gtsam = None
    if use_gtsam:
        from posegraph.crosscheck.gtsam_bridge import require_gtsam

        gtsam = require_gtsam()
    rng = np.random.default_rng(seed)
    samples = max(int(samples), 1)
    from posegraph.lie.group import SE2, SE3, SIM3

    checks = _lie_checks(rng, samples, gtsam)
    for group, space in ((SE3, ""), (SE2, "SE(2) "), (SIM3, "Sim(3) ")):
        for label, scale in (("random, small residuals", 0.05), ("random, large residuals", 0.6)):
            checks += _edge_checks(*_random_edges(rng, samples, scale, group), space + label, gtsam, group)
    if graph is not None and graph.num_edges:
        Xi = graph.poses[graph.edge_from]
        Xj = graph.poses[graph.edge_to]
        name = graph.source or "the graph"
        import os

        checks += _edge_checks(Xi, Xj, graph.measurements, f"edges of {os.path.basename(name)}", gtsam, graph.group)
    if graph is not None and graph.priors is not None and len(graph.priors):
        import os

        checks += _prior_checks(graph, f"priors of {os.path.basename(graph.source or 'the graph')}", gtsam)
    return checks


def _prior_checks(graph, family: str, gtsam) -> list[Check]:
    """The priors' Jacobians against central differences, their cost terms against gtsam's factors
    (``PriorFactorPose3/2``, ``GPSFactor``, ``PoseTranslationPrior2D``: :func:`posegraph.crosscheck.gtsam_bridge.prior_factors`)."""
    from posegraph.solve.unary import prior_errors, prior_jacobians, prior_squared_norms

    poses, priors, group = graph.poses, graph.priors, graph.group
    errors = prior_errors(poses, graph)
    jacobians = prior_jacobians(poses, graph, errors)
    r = group.space_dim
    at_pose, at_position = poses[priors.pose_vertex], poses[priors.position_vertex]
    residuals = {  # e(X·Exp(δ)) of each prior, written out (module docstring of posegraph.solve.unary)
        "pose": lambda _x, t: group.log(group.inverse(priors.pose_measurements) @ at_pose @ group.exp(t) @ priors.pose_offsets),
        "position": lambda _x, t: (at_position @ group.exp(t))[:, :r, r] - priors.position_measurements,
    }
    checks = []
    for kind, jacobian in zip(("pose", "position"), jacobians):
        count = len(jacobian)
        if count:
            fd = _central_columns(residuals[kind], np.zeros((count, group.dim)), np.full(count, FINITE_DIFFERENCE_STEP))
            checks.append(Check(f"{kind} prior Jacobian ∂e/∂δ", "finite differences", family, count,
                                _scaled_difference(jacobian, fd), FINITE_DIFFERENCE_TOLERANCE))
    if gtsam is not None:
        from posegraph.crosscheck.gtsam_bridge import poses_to_values, prior_factors

        factors, values = prior_factors(graph), poses_to_values(graph.ids, poses)
        theirs = np.array([2.0 * factors.at(k).error(values) for k in range(factors.size())])
        checks.append(Check("prior eᵀΩe", "gtsam prior factors", family, len(theirs),
                            _scaled_difference(prior_squared_norms(errors, priors), theirs), CLOSED_FORM_TOLERANCE))
    return checks


def format_checks(checks: list[Check]) -> str:
    """A table: quantity, reference, cases, count, largest difference, tolerance, ok/FAIL."""
    rows = [("quantity", "reference", "cases", "n", "max diff", "tolerance", "")]
    for c in checks:
        rows.append((c.quantity, c.reference, c.cases, str(c.count), f"{c.max_difference:.2e}",
                     f"{c.tolerance:.0e}", "ok" if c.passed else "FAIL"))
    widths = [max(len(r[k]) for r in rows) for k in range(len(rows[0]))]
    lines = ["  ".join(cell.ljust(w) if k < 3 else cell.rjust(w) for k, (cell, w) in enumerate(zip(r, widths))).rstrip()
             for r in rows]
    failed = sum(not c.passed for c in checks)
    lines.append(f"{len(checks) - failed} of {len(checks)} checks within tolerance")
    return "\n".join(lines)
