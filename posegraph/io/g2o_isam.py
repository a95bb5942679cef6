"""iSAM's text files and the noise entries of the landmark tags: what the numbers after a measurement mean.

iSAM (Kaess et al., ``isam/Loader.cpp``) writes every measurement as
``NAME id1 id2 measurement_1 … measurement_r sqrtinf_1 … sqrtinf_n``, the ``sqrtinf`` entries the upper
triangle, row by row, of the square-root information ``R`` (``Ω = RᵀR``):

* ``ODOMETRY i j x y θ`` + 6 entries (``xx xy xθ yy yθ θθ``): a 2D pose edge, read like ``EDGE_SE2``;
* ``LANDMARK i l x y`` + 3 entries: pose ``i`` sees point ``l`` at ``(x, y)`` in its frame;
* ``POINT3 i l x y z`` + 6 entries (or none: ``R = I``): the same in 3D.

Landmark ids are their own id space there (iSAM's point mapper; gtsam's ``L(id)``): a file has no
landmark vertex lines. The same tags come with other numbers in other hands: gtsam's ``readG2o`` (2D)
reads ``ODOMETRY``'s 6 entries as the *information* in g2o's order (how gtsam gets cost 73.0393643 from
iSAM's ``manhattanOlson3500.txt``), and gtsam's bundled ``victoria_park.txt`` holds *covariances*
(``0.0001 0 0 4e-06 0 4e-06`` where iSAM's ``victoriaPark.txt`` has ``100 0 0 500 0 500``). A file does
not say which; ``isam_information`` (``--isam-information``) names it: ``"sqrt"`` (iSAM's own format, the
default), ``"information"`` or ``"covariance"``.

The entry conventions of every landmark tag are one of :data:`ENTRY_MEANINGS`; :func:`information_of`
turns a tag's entries into Ω, row by row of the upper triangle.
"""

from __future__ import annotations

import numpy as np

from posegraph.errors import G2oFormatError

ODOMETRY_TAG = "ODOMETRY"
ISAM_INFORMATION = ("sqrt", "information", "covariance")
"""The values of ``isam_information``: what the upper-triangular entries of iSAM's tags are."""
ENTRY_MEANINGS = ISAM_INFORMATION + ("sigmas",)
"""``"sigmas"``: gtsam's ``BR`` lines, standard deviations of the residual's entries (Ω = diag(1/σ²))."""


def symmetric_from_upper(entries: np.ndarray, size: int) -> np.ndarray:
    """``(q, size, size)`` symmetric matrices from their upper triangles ``(q, size(size+1)/2)``, row by row."""
    rows, cols = np.triu_indices(size)
    out = np.zeros((len(entries), size, size))
    out[:, rows, cols] = entries
    out[:, cols, rows] = entries
    return out


def upper_from_symmetric(matrices: np.ndarray) -> np.ndarray:
    """The upper triangles ``(q, s(s+1)/2)`` of ``(q, s, s)`` matrices, row by row (the files' order)."""
    rows, cols = np.triu_indices(matrices.shape[-1])
    return matrices[:, rows, cols]


def information_of(entries: np.ndarray, size: int, meaning: str, numbers: np.ndarray, tag: str, path: str) -> np.ndarray:
    """Ω ``(q, size, size)`` of the noise entries ``entries`` of ``q`` lines of ``tag`` (``numbers``: their lines).

    ``meaning`` is one of :data:`ENTRY_MEANINGS`. Non-finite entries are left for the finite-value
    check; a covariance that cannot be inverted or a standard deviation ≤ 0 is refused on its line.
    """
    entries = np.where(np.isfinite(entries), entries, 0.0)
    if meaning == "sigmas":
        bad = np.flatnonzero((entries <= 0).any(axis=1))
        if bad.size:
            raise G2oFormatError(f"{tag}: the standard deviations {entries[bad[0]].tolist()} must be positive", path,
                                 int(numbers[bad[0]]))
        out = np.zeros((len(entries), size, size))
        out[:, np.arange(size), np.arange(size)] = 1.0 / entries**2
        return out
    if meaning == "information":
        return symmetric_from_upper(entries, size)
    if meaning == "sqrt":
        rows, cols = np.triu_indices(size)
        root = np.zeros((len(entries), size, size))
        root[:, rows, cols] = entries
        return np.swapaxes(root, 1, 2) @ root
    if meaning == "covariance":
        return _inverse_covariances(symmetric_from_upper(entries, size), numbers, tag, path)
    raise ValueError(f"unknown noise entry meaning {meaning!r}; one of {ENTRY_MEANINGS}")


def _inverse_covariances(covariances: np.ndarray, numbers: np.ndarray, tag: str, path: str) -> np.ndarray:
    """Ω = Σ⁻¹ of each covariance; a Σ that is not positive definite refused on its line."""
    try:
        np.linalg.cholesky(covariances)
    except np.linalg.LinAlgError:
        bad = next(k for k in range(len(covariances)) if np.linalg.eigvalsh(covariances[k])[0] <= 0)
        raise G2oFormatError(
            f"{tag}: the covariance {upper_from_symmetric(covariances[bad:bad + 1])[0].tolist()} is not positive "
            "definite (--isam-information covariance reads the entries as a covariance)", path, int(numbers[bad]),
        ) from None  # fmt: skip
    inverse = np.linalg.inv(covariances)
    return 0.5 * (inverse + np.swapaxes(inverse, 1, 2))


def odometry_noise_note(records: dict, lines: dict, path: str, meaning: str) -> list[str]:
    """A warning when ``ODOMETRY``'s entries, read as iSAM's square-root information, cannot be that.

    Read as ``R`` (upper triangular, ``Ω = RᵀR``) the heading's standard deviation is ``1/|R_θθ|``
    exactly, whatever the other entries; above π the edges say nothing about the heading — no file
    means that, while covariances read as square roots give it (gtsam's ``victoria_park.txt``:
    ``R_θθ = 4e-06``, σ_θ = 2.5e5 rad, and LM stops at its iteration cap). The note gives the
    median σ_θ of both readings and the option that reads them as covariances. ``[]`` otherwise,
    and for any other ``meaning``.
    """
    edges = records.get(ODOMETRY_TAG)
    if meaning != "sqrt" or edges is None or len(edges) == 0:
        return []
    heading = np.abs(edges["info"][:, 5])  # R_θθ, the last entry of the upper triangle
    heading = heading[np.isfinite(heading) & (heading > 0)]
    if heading.size == 0 or np.median(1.0 / heading) <= np.pi:
        return []
    first = int(lines[ODOMETRY_TAG].numbers[0])
    return [f"{path}:{first}: ODOMETRY's noise entries read as iSAM's square-root information (the default) give "
            f"a median heading standard deviation of {np.median(1.0 / heading):.3g} rad, more than π: no "
            f"information; read as covariances {np.median(np.sqrt(heading)):.3g} rad. They look like covariances "
            "(as in gtsam's victoria_park.txt): --isam-information covariance "
            "(read_g2o(..., isam_information=\"covariance\"))"]


def odometry_records_in_g2o_order(records: dict, lines: dict, path: str, meaning: str) -> dict:
    """``records`` (by tag) with the ``ODOMETRY`` lines' 6 entries turned into g2o's information entries."""
    if meaning not in ISAM_INFORMATION:
        raise ValueError(f"isam_information must be one of {ISAM_INFORMATION}, got {meaning!r}")
    edges = records.get(ODOMETRY_TAG)
    if edges is None or len(edges) == 0 or meaning == "information":
        return records
    converted = edges.copy()
    omega = information_of(edges["info"], 3, meaning, lines[ODOMETRY_TAG].numbers, ODOMETRY_TAG, path)
    converted["info"] = np.where(np.isfinite(edges["info"]), upper_from_symmetric(omega), edges["info"])
    return {**records, ODOMETRY_TAG: converted}
