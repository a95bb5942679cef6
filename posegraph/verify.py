"""Cross-validation of the Lie-group core and the edge Jacobians (``posegraph verify-jacobians``).

Every quantity is computed by this project for a batch of cases and compared with an independent
reference:

* **gtsam** (optional): ``Rot3``/``Pose3`` ``Expmap``, ``Logmap``, ``ExpmapDerivative`` (= Jr),
  ``LogmapDerivative`` (= Jr⁻¹), ``AdjointMap``, and the whitened Jacobians of
  ``BetweenFactorPose3`` from ``linearize`` with a unit noise model (so the blocks are the plain
  Jacobians ∂e/∂δ of ``e = Log(Z⁻¹ X_i⁻¹ X_j)``, and ``b = −e``);
* **central finite differences** on the manifold, with right perturbations ``X ⊕ δ = X·Exp(δ)``:
  ``Jr(ξ)`` column k is ``[Log(Exp(ξ)⁻¹ Exp(ξ + h e_k)) − Log(Exp(ξ)⁻¹ Exp(ξ − h e_k))] / 2h``,
  ``Jl(ξ)`` the same with ``Exp(ξ ± h e_k) Exp(ξ)⁻¹``, ``Jr⁻¹(ξ)`` from ``Log(Exp(ξ) Exp(±h e_k))``
  and the edge Jacobians from ``e(X_i Exp(±h e_k), X_j)`` and ``e(X_i, X_j Exp(±h e_k))``;
* **identities**: ``Log(Exp(ξ)) = ξ`` for rotation angles below π, and
  ``X Exp(δ) X⁻¹ = Exp(Ad(X) δ)`` for the adjoint.

Cases: random tangents (rotation angle uniform in [0, π), translations of size ~1–10), angles
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
* :data:`FINITE_DIFFERENCE_TOLERANCE` (1e-6) — against central differences with step
  :data:`FINITE_DIFFERENCE_STEP` (1e-6): truncation error ~h²·|f'''| ≈ 1e-12 and round-off
  ~ε/h ≈ 1e-10 per entry, so 1e-6 only fails for a wrong formula (a sign, a transpose, a missing
  term, a wrong branch), never for noise. Near π the step is shrunk so that ``θ ± h`` stays
  below π, where ``Log`` is continuous.
"""

from __future__ import annotations

from dataclasses import dataclass

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


def pose_cases(rng, samples: int) -> dict[str, np.ndarray]:
    """Tangents ``(k, 6)`` ``[ω; v]`` of SE(3) by family (rotation parts as :func:`rotation_cases`)."""
    out = {}
    for family, omega in rotation_cases(rng, samples).items():
        v = rng.normal(size=omega.shape) * rng.choice([1.0, 10.0], size=(len(omega), 1))
        out[family] = np.concatenate([omega, v], axis=1)
    return out


def _fd_steps(family: str, tangents: np.ndarray) -> np.ndarray:
    """Per-case finite-difference step: the default, or a tenth of the distance to π."""
    h = np.full(len(tangents), FINITE_DIFFERENCE_STEP)
    if family == "near π":
        margin = np.pi - np.linalg.norm(tangents[:, :3], axis=1)
        h = np.minimum(h, margin / 10)
    return h


def _usable_for_fd(family: str, tangents: np.ndarray) -> np.ndarray:
    if family != "near π":
        return tangents
    margin = np.pi - np.linalg.norm(tangents[:, :3], axis=1)
    return tangents[margin >= 1e-5]


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
    """Finite-difference Jr, Jl and Jr⁻¹ of ``group`` (the so3 or se3 module) at ``tangents``."""
    X = group.exp(tangents)
    X_inv = _inverse(group, X)
    right = _central_columns(lambda x, d: group.log(X_inv @ group.exp(x + d)), tangents, h)
    left = _central_columns(lambda x, d: group.log(group.exp(x + d) @ X_inv), tangents, h)
    right_inverse = _central_columns(lambda x, d: group.log(X @ group.exp(d)), tangents, h)
    return {"right_jacobian": right, "left_jacobian": left, "right_jacobian_inverse": right_inverse}


def _inverse(group, X):
    if hasattr(group, "inverse"):
        return group.inverse(X)
    return np.swapaxes(X, -1, -2)  # SO(3)


# ------------------------------------------------------------------------------- gtsam side


def _gtsam_rotation(gtsam, omega: np.ndarray) -> dict[str, np.ndarray]:
    exp, log, jr, jr_inv = [], [], [], []
    for w in omega:
        R = gtsam.Rot3.Expmap(w)
        exp.append(R.matrix())
        jr.append(gtsam.Rot3.ExpmapDerivative(w))
        jr_inv.append(gtsam.Rot3.LogmapDerivative(w))
    return {"exp": np.array(exp), "right_jacobian": np.array(jr), "right_jacobian_inverse": np.array(jr_inv)}


def _gtsam_rotation_log(gtsam, R: np.ndarray) -> np.ndarray:
    return np.array([np.asarray(gtsam.Rot3.Logmap(gtsam.Rot3(r))).reshape(3) for r in R])


def _gtsam_pose(gtsam, xi: np.ndarray) -> dict[str, np.ndarray]:
    exp, jr, jr_inv, ad = [], [], [], []
    for x in xi:
        T = gtsam.Pose3.Expmap(x)
        exp.append(T.matrix())
        ad.append(T.AdjointMap())
        jr.append(gtsam.Pose3.ExpmapDerivative(x))
        jr_inv.append(gtsam.Pose3.LogmapDerivative(x))
    return {
        "exp": np.array(exp),
        "adjoint": np.array(ad),
        "right_jacobian": np.array(jr),
        "right_jacobian_inverse": np.array(jr_inv),
    }


def _gtsam_pose_log(gtsam, T: np.ndarray) -> np.ndarray:
    return np.array([np.asarray(gtsam.Pose3.Logmap(gtsam.Pose3(t))).reshape(6) for t in T])


def _gtsam_between(gtsam, Xi, Xj, Z):
    """Residuals ``(m, 6)`` and Jacobians ``(m, 6, 6)`` ×2 of gtsam's BetweenFactorPose3 (unit noise)."""
    unit = gtsam.noiseModel.Unit.Create(6)
    residuals, jac_i, jac_j = [], [], []
    for a, b, z in zip(Xi, Xj, Z):
        factor = gtsam.BetweenFactorPose3(0, 1, gtsam.Pose3(z), unit)
        values = gtsam.Values()
        values.insert(0, gtsam.Pose3(a))
        values.insert(1, gtsam.Pose3(b))
        A, rhs = factor.linearize(values).jacobian()
        jac_i.append(A[:, :6])
        jac_j.append(A[:, 6:])
        residuals.append(-np.asarray(rhs).reshape(6))
    return np.array(residuals), np.array(jac_i), np.array(jac_j)


# ---------------------------------------------------------------------------------- checks


def _lie_checks(rng, samples: int, gtsam) -> list[Check]:
    from posegraph.lie import se3, so3

    checks: list[Check] = []

    def add(quantity, reference, family, count, diff, tol):
        checks.append(Check(quantity, reference, family, int(count), float(diff), tol))

    # SO(3)
    for family, omega in rotation_cases(rng, samples).items():
        R = so3.exp(omega)
        mine = {
            "exp": R,
            "right_jacobian": so3.right_jacobian(omega),
            "right_jacobian_inverse": so3.right_jacobian_inverse(omega),
            "left_jacobian": so3.left_jacobian(omega),
            "left_jacobian_inverse": so3.left_jacobian_inverse(omega),
        }
        k = len(omega)
        add("so3.log(so3.exp(ω))", "ω", family, k, _scaled_difference(so3.log(R), omega), CLOSED_FORM_TOLERANCE)
        add("so3.left_jacobian_inverse", "inverse of so3.left_jacobian", family, k,
            _scaled_difference(mine["left_jacobian_inverse"] @ mine["left_jacobian"],
                               np.broadcast_to(np.eye(3), (k, 3, 3))),
            CLOSED_FORM_TOLERANCE)
        near_pi = GTSAM_NEAR_PI_TOLERANCE if family == "near π" else CLOSED_FORM_TOLERANCE
        if gtsam is not None:
            ref = _gtsam_rotation(gtsam, omega)
            add("so3.exp", "gtsam Rot3.Expmap", family, k, _scaled_difference(R, ref["exp"]), CLOSED_FORM_TOLERANCE)
            add("so3.log", "gtsam Rot3.Logmap", family, k,
                _scaled_difference(so3.log(ref["exp"]), _gtsam_rotation_log(gtsam, ref["exp"])), near_pi)
            add("so3.right_jacobian", "gtsam Rot3.ExpmapDerivative", family, k,
                _scaled_difference(mine["right_jacobian"], ref["right_jacobian"]), CLOSED_FORM_TOLERANCE)
            add("so3.right_jacobian_inverse", "gtsam Rot3.LogmapDerivative", family, k,
                _scaled_difference(mine["right_jacobian_inverse"], ref["right_jacobian_inverse"]), near_pi)
        usable = _usable_for_fd(family, omega)
        if len(usable):
            fd = _fd_jacobians(so3, usable, _fd_steps(family, usable))
            for name in ("right_jacobian", "left_jacobian", "right_jacobian_inverse"):
                value = getattr(so3, name)(usable)
                add(f"so3.{name}", "finite differences", family, len(usable),
                    _scaled_difference(value, fd[name]), FINITE_DIFFERENCE_TOLERANCE)

    # SE(3)
    for family, xi in pose_cases(rng, samples).items():
        T = se3.exp(xi)
        k = len(xi)
        add("se3.log(se3.exp(ξ))", "ξ", family, k, _scaled_difference(se3.log(T), xi), CLOSED_FORM_TOLERANCE)
        # Ad(X) δ = Log(X Exp(δ) X⁻¹) for small δ, checked through Exp to avoid Log's branches.
        delta = rng.normal(scale=0.1, size=(k, 6))
        lhs = T @ se3.exp(delta) @ se3.inverse(T)
        rhs = se3.exp(np.einsum("kij,kj->ki", se3.adjoint(T), delta))
        add("se3.adjoint", "X·Exp(δ)·X⁻¹ = Exp(Ad(X)·δ)", family, k, _scaled_difference(lhs, rhs),
            CLOSED_FORM_TOLERANCE)
        jr = se3.right_jacobian(xi)
        add("se3.right_jacobian_inverse", "inverse of se3.right_jacobian", family, k,
            _scaled_difference(se3.right_jacobian_inverse(xi) @ jr, np.broadcast_to(np.eye(6), (k, 6, 6))),
            CLOSED_FORM_TOLERANCE)
        near_pi = GTSAM_NEAR_PI_TOLERANCE if family == "near π" else CLOSED_FORM_TOLERANCE
        if gtsam is not None:
            ref = _gtsam_pose(gtsam, xi)
            add("se3.exp", "gtsam Pose3.Expmap", family, k, _scaled_difference(T, ref["exp"]), CLOSED_FORM_TOLERANCE)
            add("se3.log", "gtsam Pose3.Logmap", family, k,
                _scaled_difference(se3.log(ref["exp"]), _gtsam_pose_log(gtsam, ref["exp"])), near_pi)
            add("se3.adjoint", "gtsam Pose3.AdjointMap", family, k,
                _scaled_difference(se3.adjoint(T), ref["adjoint"]), CLOSED_FORM_TOLERANCE)
            add("se3.right_jacobian", "gtsam Pose3.ExpmapDerivative", family, k,
                _scaled_difference(jr, ref["right_jacobian"]), CLOSED_FORM_TOLERANCE)
            add("se3.right_jacobian_inverse", "gtsam Pose3.LogmapDerivative", family, k,
                _scaled_difference(se3.right_jacobian_inverse(xi), ref["right_jacobian_inverse"]), near_pi)
        usable = _usable_for_fd(family, xi)
        if len(usable):
            fd = _fd_jacobians(se3, usable, _fd_steps(family, usable))
            for name in ("right_jacobian", "left_jacobian", "right_jacobian_inverse"):
                value = getattr(se3, name)(usable)
                add(f"se3.{name}", "finite differences", family, len(usable),
                    _scaled_difference(value, fd[name]), FINITE_DIFFERENCE_TOLERANCE)
    return checks


def _edge_checks(Xi, Xj, Z, family: str, gtsam) -> list[Check]:
    """Residuals and Jacobians of edges ``(Xi, Xj, Z)`` ``(m, 4, 4)`` each."""
    from posegraph.graph import PoseGraph
    from posegraph.lie import se3
    from posegraph.solve.residuals import edge_jacobians, edge_residuals

    m = len(Xi)
    poses = np.concatenate([Xi, Xj])
    graph = PoseGraph(
        ids=np.arange(2 * m), poses=poses, edge_from=np.arange(m), edge_to=np.arange(m, 2 * m),
        measurements=Z, information=np.broadcast_to(np.eye(6), (m, 6, 6)).copy(),
    )
    residuals = edge_residuals(poses, graph)
    jac_i, jac_j = edge_jacobians(poses, graph)
    checks = []
    if gtsam is not None:
        ref_e, ref_i, ref_j = _gtsam_between(gtsam, Xi, Xj, Z)
        checks += [
            Check("edge residual", "gtsam BetweenFactorPose3", family, m, _scaled_difference(residuals, ref_e),
                  CLOSED_FORM_TOLERANCE),
            Check("edge Jacobian ∂e/∂δi", "gtsam BetweenFactorPose3", family, m, _scaled_difference(jac_i, ref_i),
                  CLOSED_FORM_TOLERANCE),
            Check("edge Jacobian ∂e/∂δj", "gtsam BetweenFactorPose3", family, m, _scaled_difference(jac_j, ref_j),
                  CLOSED_FORM_TOLERANCE),
        ]
    # Log is discontinuous where the residual's rotation angle reaches π: finite differences skip
    # the (rare) edges within 1e-4 of it; gtsam is compared on all of them above.
    smooth = np.linalg.norm(residuals[:, :3], axis=1) < np.pi - 1e-4
    Xi, Xj, Z, jac_i, jac_j = Xi[smooth], Xj[smooth], Z[smooth], jac_i[smooth], jac_j[smooth]
    m = len(Xi)
    h = np.full(m, FINITE_DIFFERENCE_STEP)
    Zinv = se3.inverse(Z)

    def residual_moving_i(x, d):
        return se3.log(Zinv @ se3.inverse(Xi @ se3.exp(d)) @ Xj)

    def residual_moving_j(x, d):
        return se3.log(Zinv @ se3.inverse(Xi) @ Xj @ se3.exp(d))

    zeros = np.zeros((m, 6))
    fd_i = _central_columns(residual_moving_i, zeros, h)
    fd_j = _central_columns(residual_moving_j, zeros, h)
    checks += [
        Check("edge Jacobian ∂e/∂δi", "finite differences", family, m, _scaled_difference(jac_i, fd_i),
              FINITE_DIFFERENCE_TOLERANCE),
        Check("edge Jacobian ∂e/∂δj", "finite differences", family, m, _scaled_difference(jac_j, fd_j),
              FINITE_DIFFERENCE_TOLERANCE),
    ]
    return checks


def _random_edges(rng, samples: int, residual_scale: float):
    from posegraph.lie import se3

    cases = pose_cases(rng, samples)["random"]
    Xi = se3.exp(cases)
    Xj = se3.exp(pose_cases(rng, samples)["random"])
    # Measurements close to the truth (residual angles ≲ 3·residual_scale, far from π).
    Z = se3.between(Xi, Xj) @ se3.exp(rng.normal(scale=residual_scale, size=(samples, 6)))
    return Xi, Xj, Z


def verify_all(graph=None, *, samples: int = 500, seed: int = 0, use_gtsam: bool = True) -> list[Check]:
    """Run every check; returns the list of :class:`Check` (see the module docstring).

    ``graph``: also check the Jacobians of its edges at its poses. ``use_gtsam``: compare with
    gtsam when it is importable (ImportError with the install hint if asked for and missing).
    """
    gtsam = None
    if use_gtsam:
        from posegraph.gtsam_bridge import require_gtsam

        gtsam = require_gtsam()
    rng = np.random.default_rng(seed)
    samples = max(int(samples), 1)
    checks = _lie_checks(rng, samples, gtsam)
    for label, scale in (("random, small residuals", 0.05), ("random, large residuals", 0.6)):
        checks += _edge_checks(*_random_edges(rng, samples, scale), label, gtsam)
    if graph is not None and graph.num_edges:
        Xi = graph.poses[graph.edge_from]
        Xj = graph.poses[graph.edge_to]
        name = graph.source or "the graph"
        import os

        checks += _edge_checks(Xi, Xj, graph.measurements, f"edges of {os.path.basename(name)}", gtsam)
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
