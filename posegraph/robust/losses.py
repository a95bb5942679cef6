"""Robust losses ρ(s) of the squared whitened residual ``s = eᵀΩe``, cost ``½ Σ_edges ρ(s)``.

Convention (Ceres' ``LossFunction``): ρ is a function of the *squared* norm with ``ρ(0) = 0``,
``ρ'(0) = 1``, so ``ρ(s) ≈ s`` for small ``s`` and ``½ Σ ρ(s)`` reduces to the least-squares cost
``½ Σ eᵀΩe`` near zero. Each loss has a scale ``c > 0`` in units of the whitened residual *norm*
``‖e‖_Ω = √s``: residuals with ``√s`` below about ``c`` count as inliers.

Relation to gtsam 4.x. A factor with ``noiseModel.Robust.Create(mEstimator.X.Create(k), Gaussian)``
has error ``L(√s)``, where ``L = mEstimator.loss`` is a function of the whitened *norm*
``x = √s`` with ``L(x) ≈ x²/2``, and ``mEstimator.weight(x) = L'(x)/x``. Hence::

    ρ(s) = 2 L(√s)                 (so ½ ρ(s) is gtsam's factor error)
    ρ'(s) = L'(√s) / √s = weight(√s)

so ``weight`` below is gtsam's ``weight`` at ``x = √s`` and the IRLS weight of the paper and of
Ceres: the gradient of ``½ ρ(s(x))`` is ``ρ'(s) JᵀΩe`` and its Gauss-Newton Hessian
``ρ'(s) JᵀΩJ`` (Triggs et al., "Bundle adjustment — a modern synthesis", §4.3, add
``2 ρ''(s) JᵀΩe eᵀΩJ`` for the second-order correction). All scales are gtsam's ``k``/``c``
except DCS, whose gtsam parameter Φ is in units of ``s``: ``DCS(c)`` here is gtsam's
``DCS.Create(c²)``.

==============  =========================================  ===================  ==============
loss            ρ(s), inlier branch / outlier branch        ρ'(s)                default c
==============  =========================================  ===================  ==============
huber           s  (s ≤ c²) / 2c√s − c²                     1 / c/√s             1.345
cauchy          c² log(1 + s/c²)                            c²/(c² + s)          2.3849
geman_mcclure   c² s/(c² + s)                               c⁴/(c² + s)²         1.0
tukey           c²/3 (1 − (1 − s/c²)³) (s ≤ c²) / c²/3      (1 − s/c²)² / 0      4.6851
dcs             s  (s ≤ c²) / c²(3s − c²)/(c² + s)          1 / 4c⁴/(c² + s)²    1.0
tls             s  (s ≤ c²) / c²                            1 / 0                √χ²₀.₉₉(dim)
==============  =========================================  ===================  ==============

Defaults: Huber 1.345, Cauchy 2.3849 and Tukey 4.6851 are the classical 95 %-efficiency constants
for a Gaussian scalar residual (gtsam's ``Huber``/``Tukey`` defaults, the values Ceres' and gtsam's
docs quote; gtsam's ``Cauchy`` constructor default 0.1 is a placeholder, not a tuning constant);
Geman-McClure ``c = 1`` (gtsam's default); DCS ``Φ = c² = 1`` (Agarwal et al., ICRA 2013, and the
defaults of gtsam and g2o); TLS the square root of the χ² quantile at probability 0.99 for the
residual's dimension (6 for SE(3)), the inlier threshold gtsam's ``GncOptimizer`` uses.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = [
    "RobustLoss",
    "Huber",
    "Cauchy",
    "GemanMcClure",
    "Tukey",
    "DynamicCovarianceScaling",
    "TruncatedLeastSquares",
    "LOSSES",
    "LOSS_NAMES",
    "DEFAULT_SCALES",
    "chi2_quantile",
    "make_loss",
]


def chi2_quantile(probability: float, dimension: int) -> float:
    """The χ² quantile ``x`` with ``P(χ²_dimension ≤ x) = probability`` (Matlab's ``chi2inv``).

    ``2 · gammaincinv(dimension/2, probability)``; scipy is imported here, on first use, so that
    ``import posegraph`` stays free of it.
    """
    if not 0.0 < probability < 1.0:
        raise ValueError(f"probability must be in (0, 1), got {probability!r}")
    if int(dimension) != dimension or dimension < 1:
        raise ValueError(f"dimension must be a positive integer, got {dimension!r}")
    from scipy.special import gammaincinv

    return float(2.0 * gammaincinv(0.5 * dimension, probability))


def _as_array(s) -> np.ndarray:
    return np.asarray(s, dtype=np.float64)


@dataclass(frozen=True)
class RobustLoss:
    """A robust loss ρ of the squared whitened residual ``s ≥ 0`` (any array shape).

    Subclasses implement :meth:`rho`, :meth:`weight` (``ρ'(s)``) and :meth:`second_derivative`
    (``ρ''(s)``); the module docstring states the convention and the formulas.
    """

    scale: float
    """``c > 0`` in units of the whitened residual norm ``√s``."""

    name = "loss"

    def __post_init__(self) -> None:
        if not (isinstance(self.scale, (int, float, np.floating, np.integer)) and math.isfinite(self.scale) and self.scale > 0):
            raise ValueError(f"{self.name}: the scale must be a finite number > 0, got {self.scale!r}")

    def rho(self, s) -> np.ndarray:  # pragma: no cover - abstract
        """ρ(s); ``½ ρ(eᵀΩe)`` is the edge's cost."""
        raise NotImplementedError

    def weight(self, s) -> np.ndarray:  # pragma: no cover - abstract
        """ρ'(s), the IRLS weight (gtsam's ``mEstimator.weight(√s)``)."""
        raise NotImplementedError

    def second_derivative(self, s) -> np.ndarray:  # pragma: no cover - abstract
        """ρ''(s), for Triggs' second-order correction."""
        raise NotImplementedError

    def cost(self, s) -> float:
        """``½ Σ ρ(s)`` over all entries of ``s``."""
        return 0.5 * float(np.sum(self.rho(s)))


@dataclass(frozen=True)
class Huber(RobustLoss):
    """Huber: quadratic up to ``√s = c``, then linear in ``√s``."""

    name = "huber"

    def rho(self, s):
        s, c = _as_array(s), self.scale
        return np.where(s <= c * c, s, 2.0 * c * np.sqrt(s) - c * c)

    def weight(self, s):
        s, c = _as_array(s), self.scale
        inlier = s <= c * c
        return np.where(inlier, 1.0, c / np.sqrt(np.where(inlier, 1.0, s)))

    def second_derivative(self, s):
        s, c = _as_array(s), self.scale
        inlier = s <= c * c
        return np.where(inlier, 0.0, -0.5 * c / np.where(inlier, 1.0, s) ** 1.5)


@dataclass(frozen=True)
class Cauchy(RobustLoss):
    """Cauchy (Lorentzian): ``c² log(1 + s/c²)``."""

    name = "cauchy"

    def rho(self, s):
        c2 = self.scale**2
        return c2 * np.log1p(_as_array(s) / c2)

    def weight(self, s):
        c2 = self.scale**2
        return c2 / (c2 + _as_array(s))

    def second_derivative(self, s):
        c2 = self.scale**2
        return -c2 / (c2 + _as_array(s)) ** 2


@dataclass(frozen=True)
class GemanMcClure(RobustLoss):
    """Geman-McClure: ``c² s / (c² + s)``, bounded by ``c²``."""

    name = "geman_mcclure"

    def rho(self, s):
        s, c2 = _as_array(s), self.scale**2
        return c2 * s / (c2 + s)

    def weight(self, s):
        c2 = self.scale**2
        return (c2 / (c2 + _as_array(s))) ** 2

    def second_derivative(self, s):
        c2 = self.scale**2
        return -2.0 * c2 * c2 / (c2 + _as_array(s)) ** 3


@dataclass(frozen=True)
class Tukey(RobustLoss):
    """Tukey's biweight: ``c²/3 (1 − (1 − s/c²)³)`` up to ``√s = c``, constant ``c²/3`` beyond."""

    name = "tukey"

    def rho(self, s):
        c2 = self.scale**2
        # 1 − (1 − u)³ = u (3 − 3u + u²), u = min(s/c², 1): no cancellation for small s.
        u = np.minimum(_as_array(s) / c2, 1.0)
        return c2 / 3.0 * u * (3.0 - 3.0 * u + u * u)

    def weight(self, s):
        t = np.clip(1.0 - _as_array(s) / self.scale**2, 0.0, None)
        return t * t

    def second_derivative(self, s):
        c2 = self.scale**2
        t = np.clip(1.0 - _as_array(s) / c2, 0.0, None)
        return -2.0 * t / c2


@dataclass(frozen=True)
class DynamicCovarianceScaling(RobustLoss):
    """Dynamic covariance scaling (Agarwal et al., ICRA 2013) with ``Φ = c²``: the residual is
    scaled by ``min(1, 2Φ/(Φ + s))``; least squares up to ``s = Φ``, bounded by ``3Φ``."""

    name = "dcs"

    def rho(self, s):
        s, phi = _as_array(s), self.scale**2
        return np.where(s <= phi, s, phi * (3.0 * s - phi) / (phi + s))

    def weight(self, s):
        s, phi = _as_array(s), self.scale**2
        return np.where(s <= phi, 1.0, (2.0 * phi / (phi + s)) ** 2)

    def second_derivative(self, s):
        s, phi = _as_array(s), self.scale**2
        return np.where(s <= phi, 0.0, -8.0 * phi * phi / (phi + s) ** 3)


@dataclass(frozen=True)
class TruncatedLeastSquares(RobustLoss):
    """Truncated least squares: ``min(s, c²)``; weight 1 for inliers (``s ≤ c²``), 0 beyond."""

    name = "tls"

    def rho(self, s):
        return np.minimum(_as_array(s), self.scale**2)

    def weight(self, s):
        return np.where(_as_array(s) <= self.scale**2, 1.0, 0.0)

    def second_derivative(self, s):
        return np.zeros_like(_as_array(s))


LOSSES = {
    cls.name: cls for cls in (Huber, Cauchy, GemanMcClure, Tukey, DynamicCovarianceScaling, TruncatedLeastSquares)
}
"""Loss classes by name."""

LOSS_NAMES = tuple(LOSSES)
"""The names :func:`make_loss` accepts."""

DEFAULT_SCALES = {"huber": 1.345, "cauchy": 2.3849, "geman_mcclure": 1.0, "tukey": 4.6851, "dcs": 1.0}
"""Default ``c`` per loss (TLS: ``√chi2_quantile(0.99, dimension)``); see the module docstring."""

TLS_INLIER_PROBABILITY = 0.99
"""Probability of the χ² quantile that sets TLS' default scale (gtsam's ``GncOptimizer`` default)."""


def make_loss(name: str, scale: float | None = None, *, dimension: int = 6) -> RobustLoss:
    """The loss ``name`` (one of :data:`LOSS_NAMES`) with scale ``scale`` (``None``: its default).

    ``dimension`` (the residual's, 6 for SE(3)) matters only for TLS' default scale. Raises
    ValueError, naming the allowed values, for an unknown name or a scale that is not > 0.
    """
    key = str(name).lower().replace("-", "_")
    if key not in LOSSES:
        raise ValueError(f"unknown robust loss {name!r}; one of {', '.join(LOSS_NAMES)}")
    if scale is None:
        if key == "tls":
            scale = math.sqrt(chi2_quantile(TLS_INLIER_PROBABILITY, dimension))
        else:
            scale = DEFAULT_SCALES[key]
    return LOSSES[key](float(scale) if isinstance(scale, (int, np.integer)) else scale)
