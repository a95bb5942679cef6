"""Seeded fuzzing of the public API: every mutated file reads or raises InputError, and every graph
that reads optimises or raises InputError — never another exception (a traceback for the user).

The seed file is tinyGrid3D (shared datasets; 9 vertices, 11 edges, small enough for hundreds of
runs). Mutations: a token replaced by a number at the edge of double precision, a non-number or
an id; a number of an edge scaled by up to 10^±320; a line deleted, duplicated, swapped or cut short; a byte flipped, inserted or deleted; a
vertex id of an edge replaced. Each case is reproducible from its index.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import posegraph
from posegraph.errors import G2oFormatError, InputError

TOKENS = (
    "nan", "inf", "-inf", "1e308", "-1e308", "1e-308", "5e-324", "0", "-0", "1e99", "-1e99", "1e100", "1e101",
    "1e200", "abc", "1.5", "-1", "99999999999999999999", "0x10", "1e", "+", "7", "3",
)  # fmt: skip
CASES = 240


def _tokens_mutated(lines: list[str], rng: np.random.Generator) -> list[str]:
    row = int(rng.integers(len(lines)))
    tokens = lines[row].split()
    if tokens:
        tokens[int(rng.integers(len(tokens)))] = str(rng.choice(TOKENS))
        lines[row] = " ".join(tokens)
    return lines


def _number_scaled(lines: list[str], rng: np.random.Generator) -> list[str]:
    """A number of an edge line (measurement or information) times 10^k, k up to ±320."""
    edges = [i for i, line in enumerate(lines) if line.startswith("EDGE")]
    row = edges[int(rng.integers(len(edges)))]
    tokens = lines[row].split()
    column = 3 + int(rng.integers(len(tokens) - 3))
    try:
        tokens[column] = repr(float(tokens[column]) * 10.0 ** int(rng.integers(-320, 321)))
    except (ValueError, OverflowError):
        tokens[column] = "1e308"
    lines[row] = " ".join(tokens)
    return lines


def _lines_mutated(lines: list[str], rng: np.random.Generator) -> list[str]:
    row, other = (int(i) for i in rng.integers(len(lines), size=2))
    kind = int(rng.integers(4))
    if kind == 0:
        del lines[row]
    elif kind == 1:
        lines.insert(other, lines[row])
    elif kind == 2:
        lines[row], lines[other] = lines[other], lines[row]
    else:
        tokens = lines[row].split()
        lines[row] = " ".join(tokens[: int(rng.integers(len(tokens) + 1))])
    return lines


def _ids_mutated(lines: list[str], rng: np.random.Generator) -> list[str]:
    edges = [i for i, line in enumerate(lines) if line.startswith("EDGE")]
    row = edges[int(rng.integers(len(edges)))]
    tokens = lines[row].split()
    tokens[1 + int(rng.integers(2))] = str(int(rng.choice([0, 1, 2, 8, 9, 100, -1, 2**40])))
    lines[row] = " ".join(tokens)
    return lines


def _bytes_mutated(data: bytes, rng: np.random.Generator) -> bytes:
    position = int(rng.integers(len(data)))
    value = bytes([int(rng.integers(256))])
    kind = int(rng.integers(3))
    if kind == 0:
        return data[:position] + value + data[position + 1 :]
    if kind == 1:
        return data[:position] + value + data[position:]
    return data[:position] + data[position + 1 :]


def mutated(text: str, case: int) -> bytes:
    """The ``case``-th mutation of ``text`` (one to three mutations, by a generator seeded with ``case``)."""
    rng = np.random.default_rng(case)
    lines = text.splitlines()
    for _ in range(int(rng.integers(1, 4))):
        kind = int(rng.integers(5))
        if kind == 4:
            return _bytes_mutated("\n".join(lines).encode(), rng)
        lines = (_tokens_mutated, _number_scaled, _lines_mutated, _ids_mutated)[kind](lines, rng)
    return ("\n".join(lines) + "\n").encode()


@pytest.fixture(scope="module")
def seed_text() -> str:
    from tests.conftest import SHARED_DATASETS

    path = SHARED_DATASETS / "tinyGrid3D.g2o"
    if not path.is_file():
        pytest.skip(f"{path} is absent")
    return path.read_text()


@pytest.mark.parametrize("block", range(CASES // 40))
def test_mutated_files_read_or_raise_input_error_and_optimise_or_raise_input_error(block, seed_text, tmp_path):
    outcomes = {"refused at reading": 0, "optimised": 0, "refused by the solver": 0}
    for case in range(40 * block, 40 * (block + 1)):
        path = tmp_path / f"case{case}.g2o"
        path.write_bytes(mutated(seed_text, case))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                graph = posegraph.read_g2o(path)
            except InputError as err:
                assert str(err).startswith(str(path)), (case, str(err))
                outcomes["refused at reading"] += 1
                continue
            params = posegraph.SolverParams(max_iterations=30, linear_solver=("auto", "scipy")[case % 2])
            try:
                result = posegraph.optimize(graph, params=params)
            except InputError:
                outcomes["refused by the solver"] += 1
                continue
        assert np.isfinite(result.final_cost) and np.isfinite(result.poses).all(), case
        outcomes["optimised"] += 1
    assert outcomes["optimised"] > 0 and outcomes["refused at reading"] > 0, outcomes  # both paths exercised


def test_a_huge_but_finite_information_entry_is_refused_at_reading_with_its_line(seed_text, tmp_path):
    lines = seed_text.splitlines()
    row = next(i for i, line in enumerate(lines) if line.startswith("EDGE_SE3:QUAT"))
    tokens = lines[row].split()
    tokens[10] = "1e308"  # the first diagonal entry of the information (translation x)
    lines[row] = " ".join(tokens)
    path = tmp_path / "huge.g2o"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(G2oFormatError, match="at most 1e\\+50 in magnitude") as caught:
        posegraph.read_g2o(path)
    assert caught.value.line == row + 1 and caught.value.path == str(path)
    tokens[10] = "1e49"  # below the bound: reads, and the solver either optimises or refuses cleanly
    lines[row] = " ".join(tokens)
    path.write_text("\n".join(lines) + "\n")
    graph = posegraph.read_g2o(path)
    try:
        result = posegraph.optimize(graph)
    except InputError:
        return
    assert np.isfinite(result.final_cost)
