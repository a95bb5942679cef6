"""Bad g2o input: one test per case, each asserting the error type, the line in the message, and no output file."""

from __future__ import annotations

import os
import warnings

import pytest

from posegraph.errors import G2oFormatError, GraphError, InputError, InputWarning
from posegraph.io.g2o import read_g2o, write_g2o

UPPER = [(r, c) for r in range(6) for c in range(r, 6)]
IDENTITY_UPPER = " ".join("1" if r == c else "0" for r, c in UPPER)


def vertex(i, rest="0 0 0 0 0 0 1"):
    return f"VERTEX_SE3:QUAT {i} {rest}"


def edge(i, j, measurement="1 0 0 0 0 0 1", upper=IDENTITY_UPPER):
    return f"EDGE_SE3:QUAT {i} {j} {measurement} {upper}"


def upper_with(entries: dict[tuple[int, int], str]) -> str:
    """The identity's 21 upper entries with some replaced, keyed by (row, column) in g2o order."""
    return " ".join(entries.get((r, c), "1" if r == c else "0") for r, c in UPPER)


def lines(*body):
    return "\n".join(body) + "\n"


GOOD = [vertex(0), vertex(1), vertex(2), edge(0, 1), edge(1, 2)]


def convert(source, target):
    """What the command line does: read, then write elsewhere."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", InputWarning)
        graph = read_g2o(source)
    write_g2o(target, graph)


def check(text_file, text, error_type, line, *reason_parts):
    """Read ``text`` through ``convert``; the error must name file and line, and no output may appear."""
    source = text_file(text)
    target = source.parent / "output.g2o"
    with pytest.raises(error_type) as info:
        convert(source, target)
    err = info.value
    assert isinstance(err, InputError) and isinstance(err, ValueError)
    assert err.path == str(source)
    assert err.line == line
    prefix = f"{source}:{line}: " if line is not None else f"{source}: "
    assert str(err).startswith(prefix), str(err)
    for part in reason_parts:
        assert part in err.reason, (part, err.reason)
    assert not target.exists()
    assert os.listdir(source.parent) == [source.name]
    return err


# ----------------------------------------------------------------------------- format


def test_vertex_with_too_few_fields(text_file):
    text = lines(vertex(0), vertex(1, "0 0 0 0 0 1"), edge(0, 1))
    check(text_file, text, G2oFormatError, 2, "needs 8 fields", "found 7")


def test_vertex_with_too_many_fields(text_file):
    check(text_file, lines(vertex(0), edge(0, 1), vertex(1, "0 0 0 0 0 0 1 5")), G2oFormatError, 3, "found 9")


def test_edge_with_missing_information_entry(text_file):
    short = " ".join(IDENTITY_UPPER.split()[:-1])
    check(text_file, lines(*GOOD, edge(2, 0, upper=short)), G2oFormatError, 6, "needs 30 fields", "found 29")


def test_tag_without_fields(text_file):
    check(text_file, lines(*GOOD, "VERTEX_SE3:QUAT"), G2oFormatError, 6, "found 0")


def test_field_that_is_not_a_number(text_file):
    text = lines(vertex(0), vertex(1, "0 0 abc 0 0 0 1"), edge(0, 1))
    check(text_file, text, G2oFormatError, 2, "field 4 (z)", "'abc'", "not a number")


@pytest.mark.parametrize("token", ["1.2.3", "1_0", "0x1p3", "1,5"])
def test_malformed_numbers(text_file, token):
    text = lines(*GOOD, edge(2, 0, measurement=f"1 {token} 0 0 0 0 1"))
    check(text_file, text, G2oFormatError, 6, "field 4 (y)", repr(token))


def test_information_entry_that_is_not_a_number(text_file):
    upper = upper_with({(2, 5): "x"})
    err = check(text_file, lines(*GOOD, edge(0, 2, upper=upper)), G2oFormatError, 6, "not a number")
    assert "information(3,6)" in err.reason


@pytest.mark.parametrize("token", ["1.5", "1e3", "one", "1_0", "99999999999999999999"])
def test_id_that_is_not_an_integer(text_file, token):
    check(text_file, lines(*GOOD, edge(token, 2)), G2oFormatError, 6, "field 1 (id_from)", "not an integer id")


def test_negative_vertex_id(text_file):
    check(text_file, lines(*GOOD, vertex(-4)), G2oFormatError, 6, "negative")


def test_toro_edge2_information_of_ambiguous_order_is_refused(text_file):
    """(More TORO cases: tests/io/test_g2o_toro.py.)"""
    text = lines("# a TORO file", "VERTEX2 0 0 0 0", "VERTEX2 1 1 0 0", "EDGE2 0 1 1 0 0 2 0 1 2 0 1")
    check(text_file, text, G2oFormatError, 4, "EDGE2", "--edge2-information")


@pytest.mark.parametrize("first, second", [(0, 1), (1, 0)])
def test_a_file_mixing_two_and_three_dimensional_lines_is_refused(text_file, first, second):
    planar = ["VERTEX_SE2 7 0 0 0", "EDGE_SE2 7 0 1 0 0 1 0 0 1 0 1"]
    blocks = [list(GOOD), planar]
    text = lines(*blocks[first], *blocks[second])
    line = len(blocks[first]) + 1
    tag = blocks[second][0].split()[0]
    check(text_file, text, G2oFormatError, line, f"{tag} after", "mixes 2D and 3D lines")


def test_fix_without_ids(text_file):
    check(text_file, lines(*GOOD, "FIX"), G2oFormatError, 6, "FIX needs at least one vertex id")


def test_fix_with_a_non_integer(text_file):
    check(text_file, lines(*GOOD, "FIX 1 two"), G2oFormatError, 6, "'two'", "not an integer id")


# ----------------------------------------------------------------------------- values


@pytest.mark.parametrize("token", ["nan", "NaN", "inf", "-Infinity"])
def test_non_finite_vertex_value(text_file, token):
    text = lines(vertex(0), vertex(1, f"0 {token} 0 0 0 0 1"), edge(0, 1))
    check(text_file, text, G2oFormatError, 2, "field 3 (y)", "finite")


def test_non_finite_measurement(text_file):
    text = lines(*GOOD, edge(2, 0, measurement="1 0 0 0 0 nan 1"))
    check(text_file, text, G2oFormatError, 6, "field 8 (qz)", "finite")


def test_non_finite_information(text_file):
    upper = upper_with({(4, 4): "inf"})
    check(text_file, lines(*GOOD, edge(2, 0, upper=upper)), G2oFormatError, 6, "information(5,5)", "finite")


def test_zero_norm_vertex_quaternion(text_file):
    check(text_file, lines(vertex(0), vertex(1, "1 2 3 0 0 0 0"), edge(0, 1)), G2oFormatError, 2, "zero norm")


def test_zero_norm_edge_quaternion(text_file):
    check(text_file, lines(*GOOD, edge(2, 0, measurement="1 0 0 0 0 0 0")), G2oFormatError, 6, "zero norm")


def test_information_not_positive_semi_definite(text_file):
    # An off-diagonal entry larger than the diagonal: eigenvalue 1 − 3 = −2.
    upper = upper_with({(0, 3): "3"})
    check(text_file, lines(*GOOD, edge(2, 0, upper=upper)), G2oFormatError, 6, "not positive semi-definite")


def test_negative_diagonal_information(text_file):
    upper = upper_with({(5, 5): "-1"})
    check(text_file, lines(*GOOD, edge(2, 0, upper=upper)), G2oFormatError, 6, "not positive semi-definite")


def test_all_zero_information(text_file):
    zero = " ".join(["0"] * 21)
    check(text_file, lines(*GOOD, edge(2, 0, upper=zero)), G2oFormatError, 6, "all zero")


# ----------------------------------------------------------------------------- graph


def test_duplicate_vertex_id(text_file):
    text = lines(*GOOD, vertex(1, "5 5 5 0 0 0 1"))
    check(text_file, text, GraphError, 6, "duplicate vertex id 1", "first defined on line 2")


def test_edge_naming_a_missing_vertex(text_file):
    check(text_file, lines(*GOOD, edge(2, 17)), GraphError, 6, "vertex 17", "no VERTEX_SE3:QUAT line")


def test_self_loop(text_file):
    check(text_file, lines(*GOOD, edge(2, 2)), GraphError, 6, "self-loop", "vertex 2")


def test_fix_of_an_unknown_id(text_file):
    check(text_file, lines(*GOOD, "FIX 0 99"), GraphError, 6, "FIX names vertex 99")


def test_empty_file(text_file):
    check(text_file, "", GraphError, None, "no VERTEX_SE3:QUAT lines")


def test_only_comments(text_file):
    check(text_file, lines("# nothing here", "", "   # still nothing"), GraphError, None, "no VERTEX_SE3:QUAT lines")


def test_vertices_without_edges(text_file):
    check(text_file, lines(vertex(0), vertex(1)), GraphError, None, "no EDGE_SE3:QUAT lines")


def test_value_problems_come_before_a_missing_edge_list(text_file):
    check(text_file, lines(vertex(0), vertex(1, "nan 0 0 0 0 0 1")), G2oFormatError, 2, "finite")


def test_only_unsupported_tags_are_named(text_file):
    text = lines("VERTEX_CAM 0 1 2 3", "EDGE_PROJECT_DISPARITY 0 1 0 1 2 3 1 0 0 1 0 1")  # (landmark tags are read now)
    check(text_file, text, GraphError, None, "no VERTEX_SE3:QUAT", "EDGE_PROJECT_DISPARITY", "VERTEX_CAM")


# ----------------------------------------------------------------------------- reporting


def test_the_first_problem_in_the_file_is_reported(text_file):
    # Two format errors (lines 3 and 5): the earlier one is named, whatever its tag.
    text = lines(vertex(0), vertex(1), edge(0, 1, measurement="1 0 0 0 0 1"), vertex(2), vertex(3, "x 0 0 0 0 0 1"))
    check(text_file, text, G2oFormatError, 3, "found 29")


@pytest.mark.parametrize("first_bad", [1, 2, 511, 512, 777, 1000])
def test_first_bad_line_of_a_large_group_is_found(text_file, first_bad):
    # The reader parses a tag's lines in one call, then bisects for the first bad line.
    body = [vertex(k) for k in range(1000)]
    body[first_bad - 1] = vertex(first_bad - 1, "0 0 0 0 0 0 1.5.3")
    if first_bad < 1000:
        body[999] = vertex(999, "0 0 0 0 0 1")  # a later problem of another kind
    check(text_file, lines(*body, edge(0, 1)), G2oFormatError, first_bad, "'1.5.3'", "not a number")


def test_format_problems_come_before_graph_problems(text_file):
    text = lines(vertex(0), vertex(0), edge(0, 0), vertex(2, "0 0 0 0 0 0"))
    check(text_file, text, G2oFormatError, 4, "found 7")


def test_line_numbers_count_comments_blank_lines_and_crlf(text_file):
    text = "# header\r\n\r\n" + "\r\n".join([vertex(0), "   ", vertex(1), edge(0, 1), "# x", edge(1, 1)]) + "\r\n"
    check(text_file, text, GraphError, 8, "self-loop")


def test_missing_input_file(tmp_path):
    path = tmp_path / "absent.g2o"
    with pytest.raises(InputError) as info:
        read_g2o(path)
    assert info.value.path == str(path)
    assert "cannot read the file" in str(info.value)
    assert os.listdir(tmp_path) == []


def test_what_a_message_quotes_from_the_file_is_cut_to_about_sixty_characters(tmp_path):
    """A 500 kB unknown tag, field, FIX id or EQUIV line: the message quotes ~60 characters and an
    ellipsis, not the whole (a 100 MB field once made a 105 MB error line)."""
    from tests.io.helpers import read_with_warnings

    long_tag, long_field = "T" * 500_000, "7" * 500_000 + "x"
    path = tmp_path / "tag.g2o"
    path.write_text("\n".join([vertex(0), vertex(1), edge(0, 1), f"{long_tag} 1 2"]) + "\n")
    _, messages = read_with_warnings(path)
    assert len(messages) == 1 and f"{'T' * 59}… ×1" in messages[0] and len(messages[0]) < 200
    cases = {
        "VERTEX_SE3:QUAT field 2 (x) is '" + "7" * 59 + "…', not a number": vertex(2, long_field + " 0 0 0 0 0 1"),
        "FIX field 1 is '" + "7" * 59 + "…', not an integer id": "FIX " + long_field,
    }
    for expected, line in cases.items():
        path.write_text("\n".join([vertex(0), vertex(1), edge(0, 1), line]) + "\n")
        with pytest.raises(G2oFormatError) as info:
            read_g2o(path)
        assert str(info.value) == f"{path}:4: {expected}"
