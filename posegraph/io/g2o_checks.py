"""Checks on what was read from a g2o file: ids, finite values, quaternions, information matrices, topology.

Each check returns the error for the first offending line (or None) rather than raising, so that
all checks of a stage run and :func:`raise_first` reports the problem that comes first in the
file; the stages, the tolerances and the information policy (reject, repair, accept singular
with a warning) are described in ``docs/g2o.md``. Warnings are returned as texts for the reader
to issue once the whole file is accepted.
"""

from __future__ import annotations

import numpy as np

from posegraph.errors import G2oFormatError, GraphError, InputError
from posegraph.model.graph import PoseGraph, connected_components, edge_components
from posegraph.model.landmarks import observed_pairs
from posegraph.io.g2o_format import RECORDS
from posegraph.io.g2o_lines import Lines

QUATERNION_NORM_TOLERANCE = 1e-6
"""A quaternion whose norm differs from 1 by more than this is reported when normalised."""
ZERO_QUATERNION_NORM = 1e-12
"""A quaternion with a norm at or below this has no direction: rejected."""
PSD_TOLERANCE = 1e-5
"""Information with an eigenvalue below ``−PSD_TOLERANCE · max|λ|`` is not PSD: rejected."""
SINGULAR_TOLERANCE = 1e-12
"""Information with ``λ_min ≤ SINGULAR_TOLERANCE · max|λ|`` is singular: accepted with a warning."""
REPAIR_EIGENVALUE_FLOOR = 1e-9
"""With ``repair_information=True``, a non-PSD matrix's eigenvalues are raised to at least this times its largest."""
MAX_MAGNITUDE = 1e50
"""Numbers above this in magnitude are refused: the cost multiplies an information entry by two
residual entries and the Hessian one by two Jacobian entries (≤ 1e150), and the Cholesky
factorisation squares those (≤ 1e300, below double precision's ~1.8e308)."""


def raise_first(errors: list[InputError | None]) -> None:
    """Raise the error that comes first in the file (errors without a line last)."""
    found = [e for e in errors if e is not None]
    if found:
        raise min(found, key=lambda e: (e.line is None, e.line or 0))


def space_dimension(groups: dict[str, Lines], first_line: dict[str, int], path: str) -> int:
    """3 for a 3D file, 2 for a 2D one (by the tags of :data:`RECORDS` it holds; 3 when it holds none).

    Refuses a file mixing 2D and 3D lines, naming the first line of the dimension that comes
    second in the file.
    """
    firsts = {}  # space dimension -> (first line, tag)
    for tag in RECORDS.keys() & groups.keys():
        found = (first_line[tag], tag)
        firsts[RECORDS[tag].space_dim] = min(firsts.get(RECORDS[tag].space_dim, found), found)
    if len(firsts) < 2:
        return next(iter(firsts), 3)
    (first, first_tag), (second, second_tag) = sorted(firsts.values())
    raise G2oFormatError(
        f"{second_tag} after {first_tag} (line {first}): the file mixes 2D and 3D lines; a pose graph is "
        "either planar (SE(2)) or spatial (SE(3))",
        path,
        second,
    )


def check_negative_ids(ids: np.ndarray, numbers: np.ndarray, tag: str, path: str) -> G2oFormatError | None:
    bad = np.flatnonzero(ids < 0)
    if bad.size == 0:
        return None
    k = bad[0]
    return G2oFormatError(
        f"{tag} id {ids[k]} is negative; vertex ids must be non-negative integers", path, int(numbers[k])
    )


def check_finite(
    records: np.ndarray, numbers: np.ndarray, tag: str, fields: tuple[str, ...], path: str
) -> G2oFormatError | None:
    """An error naming the first line and field holding NaN, an infinity or a number above :data:`MAX_MAGNITUDE`."""
    names = [name for name in records.dtype.names if records.dtype[name].base.kind == "f"]
    widths = [int(np.prod(records.dtype[name].shape)) for name in names]
    values = np.concatenate([records[name].reshape(len(records), w) for name, w in zip(names, widths)], axis=1)
    finite = np.abs(values) <= MAX_MAGNITUDE  # False for NaN too
    bad_rows = np.flatnonzero(~finite.all(axis=1))
    if bad_rows.size == 0:
        return None
    row = bad_rows[0]
    col = int(np.flatnonzero(~finite[row])[0])
    field = len(fields) - values.shape[1] + col  # the float fields come after the integer ids
    bound = "finite" if not np.isfinite(values[row, col]) else f"at most {MAX_MAGNITUDE:g} in magnitude (the solver squares products of them)"
    return G2oFormatError(
        f"{tag} field {field + 1} ({fields[field]}) is {values[row, col]}; values must be {bound}",
        path,
        int(numbers[row]),
    )


def unit_quaternions(
    q: np.ndarray, numbers: np.ndarray, tag: str, path: str
) -> tuple[np.ndarray, G2oFormatError | None]:
    """``q (k,4)`` divided by its norm (as gtsam does); an error for the first zero-norm one."""
    norm = np.sqrt(np.einsum("ij,ij->i", q, q))
    zero = np.flatnonzero(norm <= ZERO_QUATERNION_NORM)  # NaN rows compare False: reported as non-finite
    if zero.size:
        k = zero[0]
        error = G2oFormatError(
            f"{tag} quaternion (qx qy qz qw) = {tuple(q[k].tolist())} has zero norm: it is not a rotation",
            path,
            int(numbers[k]),
        )
        return q, error
    return q / norm[:, None], None


def quaternion_note(quaternions: list[np.ndarray], numbers: list[np.ndarray], path: str) -> list[str]:
    """One warning for all quaternions whose norm is off by more than the tolerance."""
    norms = np.concatenate([np.sqrt(np.einsum("ij,ij->i", q, q)) for q in quaternions])
    lines = np.concatenate(numbers)
    off = np.flatnonzero(np.abs(norms - 1.0) > QUATERNION_NORM_TOLERANCE)
    if off.size == 0:
        return []
    first = off[np.argmin(lines[off])]
    return [
        f"{path}:{int(lines[first])}: normalised {off.size} quaternion(s) whose norm was off by more "
        f"than {QUATERNION_NORM_TOLERANCE:g} (this one: {norms[first]:.9g})"
    ]


def check_information(
    information: np.ndarray, numbers: np.ndarray, tags: np.ndarray, path: str, *, repair: bool
) -> tuple[np.ndarray, G2oFormatError | None, list[str]]:
    """Check (and, if ``repair``, repair) the ``(m, d, d)`` information matrices, in tangent order.

    Returns the matrices, an error for the first refused one, and warning texts (repaired or
    singular matrices); see ``docs/g2o.md`` for the policy. Rows holding NaN or
    infinities are left to :func:`check_finite`.
    """
    finite = np.isfinite(information).all(axis=(1, 2))
    checked = information if finite.all() else np.where(finite[:, None, None], information, np.eye(information.shape[-1]))
    # Fast path: Cholesky succeeds for the whole batch iff every matrix is positive definite.
    try:
        np.linalg.cholesky(checked)
        return information, None, []
    except np.linalg.LinAlgError:
        pass
    eigenvalues = np.linalg.eigvalsh(checked)  # ascending
    scale = np.abs(eigenvalues).max(axis=1)
    lowest = eigenvalues[:, 0]
    zero = ~np.any(information != 0, axis=(1, 2))
    not_psd = lowest < -PSD_TOLERANCE * scale
    # Clipping a matrix without a positive eigenvalue would leave (almost) nothing: refused even when repairing.
    hopeless = not_psd & (eigenvalues[:, -1] <= 0)
    singular = (lowest <= SINGULAR_TOLERANCE * scale) & ~not_psd & ~zero
    bad = np.flatnonzero(zero | (hopeless if repair else not_psd))
    if bad.size:
        e = bad[0]
        reason = _refusal_reason(eigenvalues[e], zero[e], hopeless[e])
        return information, G2oFormatError(f"{tags[e]}: {reason}", path, int(numbers[e])), []
    notes = []
    if repair and not_psd.any():
        repaired = np.flatnonzero(not_psd)
        information = information.copy()
        information[repaired] = _nearest_positive_definite(checked[repaired])
        first = repaired[0]
        shown = np.array2string(eigenvalues[first], precision=4, separator=", ", max_line_width=1000)
        notes.append(
            f"{path}:{int(numbers[first])}: repaired {repaired.size} information matrices that were not positive "
            f"semi-definite: each replaced by the nearest matrix (Frobenius norm) with eigenvalues at least "
            f"{REPAIR_EIGENVALUE_FLOOR:g} times its largest (this one's eigenvalues were {shown})"
        )
    if singular.any():
        first = np.flatnonzero(singular)[0]
        kinds = set(tags[singular].tolist())
        kind = kinds.pop() if len(kinds) == 1 else "edge"
        notes.append(
            f"{path}:{int(numbers[first])}: {np.count_nonzero(singular)} {kind} information matrices are "
            "singular: accepted as given; other edges must constrain the directions they leave free "
            "(gtsam's Gaussian noise model does not represent singular matrices exactly)"
        )
    return information, None, notes


def _refusal_reason(eigenvalues: np.ndarray, zero: bool, hopeless: bool) -> str:
    """Why one information matrix (its ``(d,)`` ascending ``eigenvalues``) is refused."""
    shown = np.array2string(eigenvalues, precision=4, separator=", ", max_line_width=1000)
    if zero:
        return "the information matrix is all zero: the edge would constrain nothing"
    if hopeless:
        return (
            f"the information matrix has no positive eigenvalue (eigenvalues {shown}): "
            "nothing would be left of it after clipping to a positive semi-definite matrix"
        )
    return (
        f"the information matrix is not positive semi-definite (eigenvalues {shown}); use "
        "--repair-information (read_g2o(..., repair_information=True)) to clip it to the nearest "
        "positive semi-definite matrix"
    )


def _nearest_positive_definite(matrices: np.ndarray) -> np.ndarray:
    """Symmetric ``(k, d, d)`` ``A = V diag(λ) Vᵀ`` to ``V diag(max(λ, f·λ_max)) Vᵀ``, f the repair floor.

    With ``f =`` :data:`REPAIR_EIGENVALUE_FLOOR`, it is the nearest symmetric matrix in Frobenius
    norm whose eigenvalues are all ``≥ f·λ_max``
    (Higham 1988, "Computing a nearest symmetric positive semidefinite matrix": clipping the
    eigenvalues; with ``f = 0`` it is the nearest positive semi-definite matrix, from which this one
    differs by at most ``√d·f·λ_max``). The floor keeps each repaired matrix positive definite, so
    that it is a proper Gaussian on its own (Cholesky succeeds; gtsam's noise model represents it
    exactly) and leaves no direction of the edge entirely free.
    """
    eigenvalues, vectors = np.linalg.eigh(matrices)
    clipped = np.maximum(eigenvalues, REPAIR_EIGENVALUE_FLOOR * eigenvalues[:, -1:])
    out = (vectors * clipped[:, None, :]) @ np.swapaxes(vectors, -1, -2)
    return 0.5 * (out + np.swapaxes(out, -1, -2))  # exactly symmetric, as the file's matrices are


def topology(
    ids: np.ndarray,
    vertex_numbers: np.ndarray,
    edge_ids: np.ndarray,
    edge_numbers: np.ndarray,
    fix_ids: np.ndarray,
    fix_numbers: np.ndarray,
    path: str,
    vertex_tags: str,
) -> tuple[np.ndarray, np.ndarray]:
    """Edge endpoints as vertex indices ``(m, 2)`` and the fixed mask ``(n,)``, after the graph checks.

    ``vertex_tags`` names the vertex tags in messages (e.g. ``"VERTEX_SE2"``)."""
    order = np.argsort(ids, kind="stable")
    sorted_ids = ids[order]
    duplicate = _check_duplicates(ids, order, vertex_numbers, path)
    edge_index, missing = _resolve(
        edge_ids.reshape(-1), order, sorted_ids, np.repeat(edge_numbers, 2), "edge", path, vertex_tags
    )
    loops = np.flatnonzero(edge_ids[:, 0] == edge_ids[:, 1])
    loop = None
    if loops.size:
        e = loops[0]
        loop = GraphError(f"self-loop: the edge joins vertex {edge_ids[e, 0]} to itself", path, int(edge_numbers[e]))
    fixed_index, fix_missing = _resolve(fix_ids, order, sorted_ids, fix_numbers, "FIX", path, vertex_tags)
    raise_first([duplicate, missing, loop, fix_missing])
    fixed = np.zeros(len(ids), dtype=bool)
    fixed[fixed_index] = True
    return edge_index.reshape(-1, 2), fixed


def _check_duplicates(ids: np.ndarray, order: np.ndarray, numbers: np.ndarray, path: str) -> GraphError | None:
    sorted_ids = ids[order]
    repeat = np.flatnonzero(sorted_ids[1:] == sorted_ids[:-1]) + 1
    if repeat.size == 0:
        return None
    # With a stable sort, order[r] is a later line than order[r - 1]; report the earliest repeat.
    r = repeat[np.argmin(order[repeat])]
    first = r
    while first > 0 and sorted_ids[first - 1] == sorted_ids[r]:
        first -= 1
    return GraphError(
        f"duplicate vertex id {sorted_ids[r]} (first defined on line {int(numbers[order[first]])})",
        path,
        int(numbers[order[r]]),
    )


def _resolve(
    wanted: np.ndarray, order: np.ndarray, sorted_ids: np.ndarray, numbers: np.ndarray, what: str, path: str,
    vertex_tags: str,
) -> tuple[np.ndarray, GraphError | None]:
    """Vertex indices of ``wanted`` ids; an error naming the first line with an unknown id."""
    pos = np.clip(np.searchsorted(sorted_ids, wanted), 0, len(sorted_ids) - 1)
    found = sorted_ids[pos] == wanted
    if found.all():
        return order[pos], None
    k = np.flatnonzero(~found)[0]
    return np.zeros(0, np.int64), GraphError(
        f"{what} names vertex {wanted[k]}, which has no {vertex_tags}", path, int(numbers[k])
    )


def components_note(graph: PoseGraph, path: str) -> list[str]:
    """A warning for a graph of several connected components; landmarks join the poses that see them."""
    if graph.landmarks is None:
        count, labels = connected_components(graph)
    else:
        pose, landmark = observed_pairs(graph.landmarks)
        n = graph.num_vertices
        count, labels = edge_components(n + graph.landmarks.count, np.concatenate([graph.edge_from, pose]),
                                        np.concatenate([graph.edge_to, landmark + n]))
    if count == 1:
        return []
    sizes = np.sort(np.bincount(labels))[::-1]
    shown = ", ".join(str(size) for size in sizes[:5]) + (", …" if count > 5 else "")
    return [
        f"{path}: the graph has {count} connected components (vertex counts {shown}, landmarks included); "
        if graph.landmarks is not None else
        f"{path}: the graph has {count} connected components (vertex counts {shown}); "
        "the solver anchors each component separately"
    ]
