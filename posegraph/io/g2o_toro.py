"""TORO's 2D files: ``VERTEX2`` / ``EDGE2`` lines, the order of their information, ``EQUIV`` merges.

``VERTEX2 id x y θ`` and ``EDGE2 i j dx dy dθ`` + 6 information entries read like g2o's
``VERTEX_SE2`` / ``EDGE_SE2`` (:data:`posegraph.io.g2o_format.RECORDS`), except for the order of
those 6 entries, which files disagree on:

* TORO's documented order, ``xx xy yy θθ xθ yθ`` ("ff fs ss rr fr sr"): TORO's own files and
  gtsam's ``w100.graph``, ``w10000.graph``, ``example.graph`` (all ``1 0 1 1 0 0``, the identity);
* g2o's upper triangle, ``xx xy xθ yy yθ θθ``: gtsam's ``w100_30.g2o`` and ``w20000.txt``
  (``1 0 0 1 0 1``; ``3.16228 0 0 3.16228 0 5``), which is how gtsam reads every ``EDGE2`` (it
  refuses the other order with "not G2O matrix order").

The rule (:func:`edge2_information_order`), per file: each line's 6 entries are read both ways;
the order in which every line gives a positive semi-definite, non-zero matrix is the file's. When
both orders give such matrices on every line and the two matrices differ on some line, the file
is ambiguous and refused at that line; the user then names the order (``edge2_information="toro"``
or ``"g2o"``, ``--edge2-information``), which overrides the rule. When neither order fits every
line, the order that fits more lines is taken, and the first line it does not fit is refused by
the information checks as for any edge (``--repair-information`` applies). Mistaking one order for
the other cannot pass silently: on the files above the wrong order makes every matrix indefinite.

``EQUIV a b`` says vertices ``a`` and ``b`` are one place: ``b`` is merged into ``a``
(:func:`merge_equivalent`) — edges naming ``b`` name ``a``, ``b``'s vertex is dropped; an edge
between the two becomes a loop on ``a``, a constant of the cost, and is dropped too (counted in
a warning). Chains (``EQUIV a b``, ``EQUIV b c``) merge into the first. The writer copies the
``EQUIV`` lines, the dropped vertices' lines and the dropped edges' lines as they came
(``PoseGraph.kept_lines``), so the output reads back to the same graph.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from posegraph.errors import G2oFormatError, GraphError, excerpt
from posegraph.io.g2o_checks import PSD_TOLERANCE
from posegraph.io.g2o_format import SYMMETRIC_FROM_UPPER_2D
from posegraph.io.g2o_lines import Lines

VERTEX2_TAG = "VERTEX2"
EDGE2_TAG = "EDGE2"
EQUIV_TAG = "EQUIV"
ORDERS = ("auto", "g2o", "toro")
"""The values of ``edge2_information``: the rule, or the order named."""
TORO_TO_UPPER = np.array([0, 1, 4, 2, 5, 3])
"""Entry ``k`` of g2o's upper triangle (``xx xy xθ yy yθ θθ``) is TORO's entry ``TORO_TO_UPPER[k]``."""


def _fits(upper: np.ndarray) -> np.ndarray:
    """``(m,)`` bool: the upper-triangular entries ``(m, 6)`` in g2o's order make a PSD, non-zero, finite matrix."""
    matrices = upper[:, SYMMETRIC_FROM_UPPER_2D].reshape(-1, 3, 3)
    finite = np.isfinite(matrices).all(axis=(1, 2))
    eigenvalues = np.linalg.eigvalsh(np.where(finite[:, None, None], matrices, 0.0))
    scale = np.abs(eigenvalues).max(axis=1)
    return finite & (scale > 0) & (eigenvalues[:, 0] >= -PSD_TOLERANCE * scale)


def edge2_information_order(info: np.ndarray, numbers: np.ndarray, path: str, choice: str = "auto") -> str:
    """``"g2o"`` or ``"toro"``: the order of the ``EDGE2`` lines' entries ``info`` ``(m, 6)`` (module docstring)."""
    if choice not in ORDERS:
        raise ValueError(f"edge2_information must be one of {ORDERS}, got {choice!r}")
    if choice != "auto" or len(info) == 0:
        return "g2o" if choice == "auto" else choice
    as_toro = info[:, TORO_TO_UPPER]
    g2o_fits, toro_fits = _fits(info), _fits(as_toro)
    if g2o_fits.all() and toro_fits.all():
        differ = np.flatnonzero(np.any(info != as_toro, axis=1))
        if differ.size:
            raise G2oFormatError(
                f"{EDGE2_TAG}: the 6 information entries make a valid matrix read in g2o's order (xx xy xθ yy yθ θθ) "
                "and in TORO's (xx xy yy θθ xθ yθ) on every line, and the two differ: the file does not tell which "
                "it uses; name it with --edge2-information g2o|toro (read_g2o(..., edge2_information=...))",
                path, int(numbers[differ[0]]),
            )  # fmt: skip
        return "g2o"
    return "toro" if np.count_nonzero(toro_fits) > np.count_nonzero(g2o_fits) else "g2o"


def edge2_records_in_g2o_order(records: dict, lines: dict, path: str, choice: str) -> dict:
    """``records`` (by tag) with the ``EDGE2`` entries in g2o's order (:func:`edge2_information_order`)."""
    edges = records.get(EDGE2_TAG)
    if edges is None or len(edges) == 0:
        return records
    if edge2_information_order(edges["info"], lines[EDGE2_TAG].numbers, path, choice) == "g2o":
        return records
    converted = edges.copy()
    converted["info"] = edges["info"][:, TORO_TO_UPPER]
    return {**records, EDGE2_TAG: converted}


def _equivalences(lines: Lines, path: str) -> tuple[np.ndarray, np.ndarray]:
    """``(pairs (q, 2) ids a b, line numbers (q,))`` of the ``EQUIV`` lines."""
    pairs = []
    for number, rest in zip(lines.numbers.tolist(), lines.rests):
        tokens = rest.split()
        if len(tokens) != 2 or not all(t.lstrip("+-").isdigit() for t in tokens):
            raise G2oFormatError(f"{EQUIV_TAG} needs two integer vertex ids (a b: b merged into a), found {excerpt(rest.strip())}",
                                 path, number)
        pairs.append((int(tokens[0]), int(tokens[1])))
    return np.array(pairs, dtype=np.int64).reshape(-1, 2), lines.numbers


def _representatives(graph, pairs: np.ndarray, numbers: np.ndarray, path: str) -> np.ndarray:
    """``(n,)`` the vertex each vertex is merged into (itself when kept); chains followed to their first vertex."""
    try:
        a, b = graph.index_of(pairs[:, 0]), graph.index_of(pairs[:, 1])
    except KeyError:
        known = set(graph.ids.tolist())
        k = next(k for k, (x, y) in enumerate(pairs.tolist()) if x not in known or y not in known)
        missing = pairs[k, 0] if pairs[k, 0] not in known else pairs[k, 1]
        raise GraphError(f"{EQUIV_TAG} names vertex {missing}, which has no vertex line", path, int(numbers[k])) from None
    target = np.arange(graph.num_vertices)
    for x, y, number in zip(a.tolist(), b.tolist(), numbers.tolist()):  # few lines; order matters for chains
        root_x, root_y = target[x], target[y]
        if root_x == root_y:
            continue
        target[target == root_y] = root_x
    return target


def _line_texts(groups: dict, numbers: set) -> dict:
    """``{line number: "TAG rest"}`` for the lines ``numbers`` of any tag of ``groups``."""
    found = {}
    for tag, group in groups.items():
        for k in np.flatnonzero(np.isin(group.numbers, list(numbers))).tolist():
            found[int(group.numbers[k])] = f"{tag} {group.rests[k].strip()}"
    return found


def _vertex_line_numbers(groups: dict, tags: tuple, ids: set) -> set:
    """Line numbers of the vertex lines (of ``tags``) of the vertices ``ids``."""
    numbers = set()
    for tag in tags:
        group = groups.get(tag)
        for number, rest in zip(group.numbers.tolist() if group else [], group.rests if group else []):
            head = rest.split(None, 1)
            if head and head[0].lstrip("+-").isdigit() and int(head[0]) in ids:
                numbers.add(number)
    return numbers


def _remapped_landmarks(landmarks, vertex_map: np.ndarray):
    """``landmarks`` with each observing pose index ``k`` replaced by ``vertex_map[k]`` (priors, −1, kept)."""
    if landmarks is None:
        return None
    families = tuple(replace(f, pose=np.where(f.pose >= 0, vertex_map[np.maximum(f.pose, 0)], -1))
                     for f in landmarks.observations)
    return replace(landmarks, observations=families)


def merge_equivalent(graph, groups: dict, vertex_tags: tuple, path: str):
    """``(graph with the EQUIV lines of ``groups`` merged, warning texts)`` (module docstring).

    ``groups`` holds the file's lines by tag (:func:`posegraph.io.g2o_lines.group_lines`), from
    which the dropped vertices' lines (of ``vertex_tags``) and the dropped loops' lines are copied.
    """
    lines = groups.get(EQUIV_TAG)
    if lines is None or not lines.rests:
        return graph, []
    pairs, numbers = _equivalences(lines, path)
    target = _representatives(graph, pairs, numbers, path)
    kept = target == np.arange(graph.num_vertices)
    new_index = np.cumsum(kept) - 1
    edge_from, edge_to = new_index[target[graph.edge_from]], new_index[target[graph.edge_to]]
    edges, loops = np.flatnonzero(edge_from != edge_to), np.flatnonzero(edge_from == edge_to)
    fixed = np.zeros(int(kept.sum()), dtype=bool)
    np.logical_or.at(fixed, new_index[target[graph.fixed]], True)
    copied = _vertex_line_numbers(groups, vertex_tags, set(graph.ids[~kept].tolist())) | set(lines.numbers.tolist())
    if graph.edge_lines is not None:
        copied |= set(graph.edge_lines[loops].tolist())
    texts = _line_texts(groups, copied)
    merged = replace(
        graph, ids=graph.ids[kept], poses=graph.poses[kept], fixed=fixed, edge_from=edge_from[edges],
        edge_to=edge_to[edges], measurements=graph.measurements[edges], information=graph.information[edges],
        edge_lines=None if graph.edge_lines is None else graph.edge_lines[edges], edge_source=None,
        priors=None if graph.priors is None else graph.priors.remapped(new_index[target]),
        landmarks=_remapped_landmarks(graph.landmarks, new_index[target]),
        kept_lines=tuple(graph.kept_lines) + tuple(texts[number] for number in sorted(texts)),
    )  # fmt: skip
    note = (f"{path}:{int(numbers[0])}: merged {int((~kept).sum())} vertices into the vertex their {EQUIV_TAG} line "
            f"names first" + (f"; dropped the {loops.size} edge(s) between merged vertices (constant terms of the "
                               "cost, written back as read)" if loops.size else ""))
    return merged, [note]
