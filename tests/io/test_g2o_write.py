"""write_g2o: lossless round trips, the file layout, and never losing or half-writing a file."""

from __future__ import annotations

import os
import tempfile
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from posegraph.errors import InputWarning, OutputError
from posegraph.model.graph import PoseGraph
from posegraph.io.g2o import format_g2o, read_g2o, write_g2o
from tests.conftest import INDEFINITE_INFORMATION


def rotations_from_xyzw(q):
    """Unit quaternions (..., 4) as x, y, z, w to rotation matrices, written out independently of posegraph."""
    q = np.asarray(q, dtype=float)
    x, y, z, w = np.moveaxis(q / np.linalg.norm(q, axis=-1, keepdims=True), -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def random_graph(rng, n=6, m=9, id_range=10**9, scale=1.0, source=None) -> PoseGraph:
    """A connected graph with sparse, unordered ids, random poses, PD information and a fixed vertex."""
    ids = rng.choice(id_range, size=n, replace=False).astype(np.int64)
    def poses(k):
        out = np.zeros((k, 4, 4))
        out[:, :3, :3] = rotations_from_xyzw(rng.normal(size=(k, 4)))
        out[:, :3, 3] = scale * rng.normal(size=(k, 3))
        out[:, 3, 3] = 1
        return out
    chain = rng.permutation(n)
    edge_from = list(chain[:-1])
    edge_to = list(chain[1:])
    while len(edge_from) < m:
        i, j = rng.choice(n, size=2, replace=False)
        edge_from.append(i)
        edge_to.append(j)
    a = rng.normal(size=(m, 6, 6))
    information = (a @ np.swapaxes(a, 1, 2) + 1e-3 * np.eye(6)) * scale
    fixed = np.zeros(n, dtype=bool)
    fixed[rng.integers(n)] = True
    return PoseGraph(
        ids=ids,
        poses=poses(n),
        edge_from=np.array(edge_from, dtype=np.int64),
        edge_to=np.array(edge_to, dtype=np.int64),
        measurements=poses(m),
        information=information,
        fixed=fixed,
        source=source,
    )


def read_quietly(path, **options):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", InputWarning)
        return read_g2o(path, **options)


def assert_same_graph(actual: PoseGraph, expected: PoseGraph, poses=None):
    """Ids, topology and fixed exactly; translations and information exactly; rotations to rounding."""
    poses = expected.poses if poses is None else poses
    np.testing.assert_array_equal(actual.ids, expected.ids)
    np.testing.assert_array_equal(actual.edge_from, expected.edge_from)
    np.testing.assert_array_equal(actual.edge_to, expected.edge_to)
    np.testing.assert_array_equal(actual.fixed, expected.fixed)
    np.testing.assert_array_equal(actual.information, expected.information)
    np.testing.assert_array_equal(actual.poses[:, :3, 3], poses[:, :3, 3])
    np.testing.assert_array_equal(actual.measurements[:, :3, 3], expected.measurements[:, :3, 3])
    np.testing.assert_allclose(actual.poses[:, :3, :3], poses[:, :3, :3], rtol=0, atol=1e-14)
    np.testing.assert_allclose(actual.measurements[:, :3, :3], expected.measurements[:, :3, :3], rtol=0, atol=1e-14)
    np.testing.assert_array_equal(actual.poses[:, 3], np.tile([0, 0, 0, 1.0], (len(poses), 1)))


def test_round_trip_with_sparse_unordered_ids(tmp_path):
    graph = random_graph(np.random.default_rng(0), n=8, m=14)
    assert not np.all(np.diff(graph.ids) > 0)
    path = tmp_path / "out.g2o"
    write_g2o(path, graph)
    assert_same_graph(read_quietly(path), graph)


def test_rewriting_a_written_file_changes_only_quaternion_rounding(tmp_path):
    graph = random_graph(np.random.default_rng(1))
    write_g2o(tmp_path / "a.g2o", graph)
    write_g2o(tmp_path / "b.g2o", read_quietly(tmp_path / "a.g2o"))
    first = [line.split() for line in (tmp_path / "a.g2o").read_text().splitlines()]
    second = [line.split() for line in (tmp_path / "b.g2o").read_text().splitlines()]
    assert len(first) == len(second)
    for a, b in zip(first, second):
        quaternion = slice(5, 9) if a[0] == "VERTEX_SE3:QUAT" else slice(6, 10)
        assert a[: quaternion.start] + a[quaternion.stop :] == b[: quaternion.start] + b[quaternion.stop :]
        np.testing.assert_allclose(np.array(a[quaternion], float), np.array(b[quaternion], float), rtol=0, atol=1e-14)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(2, 7),
    extra=st.integers(0, 6),
    exponent=st.integers(-200, 48),  # up to the reader's bound posegraph.io.g2o.MAX_MAGNITUDE (1e50)
)
def test_round_trip_property(seed, n, extra, exponent):
    """Any ids, any magnitude the reader accepts (1e-200 … 1e48 here): every number comes back."""
    graph = random_graph(np.random.default_rng(seed), n=n, m=n - 1 + extra, id_range=2**62, scale=10.0**exponent)
    with tempfile.TemporaryDirectory() as folder:
        path = os.path.join(folder, "g.g2o")
        write_g2o(path, graph)
        assert_same_graph(read_quietly(path), graph)


def test_round_trip_of_a_shared_dataset(shared_g2o_file, tmp_path):
    # A repaired file is written with its repaired (positive definite) matrices, read back as they are.
    graph = read_quietly(shared_g2o_file, repair_information=shared_g2o_file.name in INDEFINITE_INFORMATION)
    path = tmp_path / shared_g2o_file.name
    write_g2o(path, graph)
    again = read_quietly(path)
    assert_same_graph(again, graph)


def test_written_poses_replace_the_graphs(tmp_path):
    rng = np.random.default_rng(2)
    graph = random_graph(rng)
    new_poses = random_graph(rng, n=graph.num_vertices).poses
    write_g2o(tmp_path / "out.g2o", graph, new_poses)
    assert_same_graph(read_quietly(tmp_path / "out.g2o"), graph, poses=new_poses)


def test_file_layout_vertices_fix_edges_in_graph_order(tmp_path):
    graph = random_graph(np.random.default_rng(4), n=4, m=5)
    rows = [line.split() for line in format_g2o(graph).splitlines()]
    tags = [row[0] for row in rows]
    assert tags == ["VERTEX_SE3:QUAT"] * 4 + ["FIX"] + ["EDGE_SE3:QUAT"] * 5
    assert [int(row[1]) for row in rows[:4]] == graph.ids.tolist()
    assert int(rows[4][1]) == graph.ids[graph.fixed][0]
    assert [(int(r[1]), int(r[2])) for r in rows[5:]] == list(
        zip(graph.ids[graph.edge_from].tolist(), graph.ids[graph.edge_to].tolist())
    )
    assert all(len(row) == 9 for row in rows[:4]) and all(len(row) == 31 for row in rows[5:])
    quaternions = np.array([[float(v) for v in row[5:9]] for row in rows[:4]])
    assert (quaternions[:, 3] >= 0).all()
    np.testing.assert_allclose(rotations_from_xyzw(quaternions), graph.poses[:, :3, :3], atol=1e-14)
    # Information back in g2o's order: the first entry is the x-x (translation) information.
    assert float(rows[5][10]) == graph.information[0, 3, 3]
    assert float(rows[5][10 + 15]) == graph.information[0, 0, 0]  # entry 16 of 21 is g2o (3,3): rotation x-x


@pytest.mark.parametrize("shared", ["every edge", "some values", "nothing"])
def test_information_entries_are_each_written_as_their_repr(shared, tmp_path):
    """The writer formats each distinct information value once (and one text when all edges share
    one matrix): the text must still be every entry's own repr, −0.0 keeping its sign."""
    rng = np.random.default_rng(6)
    graph = random_graph(rng, n=5, m=8)
    information = graph.information.copy()
    if shared == "every edge":
        information[:] = information[0]
    elif shared == "some values":
        information = np.round(information, 1)  # few distinct values, repeated across edges
    information += 10.0 * np.eye(6)  # stays positive definite with an entry zeroed below
    information[:, 1, 4] = information[:, 4, 1] = -0.0  # an off-diagonal entry
    graph = PoseGraph(
        ids=graph.ids, poses=graph.poses, edge_from=graph.edge_from, edge_to=graph.edge_to,
        measurements=graph.measurements, information=information, fixed=graph.fixed,
    )
    g2o_order = information[:, [3, 4, 5, 0, 1, 2]][:, :, [3, 4, 5, 0, 1, 2]]
    upper = g2o_order[:, np.triu_indices(6)[0], np.triu_indices(6)[1]]
    edge_rows = [line.split() for line in format_g2o(graph).splitlines() if line.startswith("EDGE_SE3:QUAT")]
    assert [row[10:] for row in edge_rows] == [[repr(x) for x in entries] for entries in upper.tolist()]
    negative_zero = (upper == 0) & np.signbit(upper)
    assert negative_zero.sum(axis=1).min() == 1
    assert all(
        [row[10 + k] for k in np.flatnonzero(marks)] == ["-0.0"] * int(marks.sum())
        for row, marks in zip(edge_rows, negative_zero)
    )
    write_g2o(tmp_path / "out.g2o", graph)
    again = read_quietly(tmp_path / "out.g2o")
    np.testing.assert_array_equal(again.information, information)
    np.testing.assert_array_equal(np.signbit(again.information), np.signbit(information))


def test_refuses_to_overwrite_the_input(tmp_path):
    source = tmp_path / "in.g2o"
    write_g2o(source, random_graph(np.random.default_rng(5)))
    before = source.read_bytes()
    graph = read_quietly(source)
    for same in (source, os.path.relpath(source), tmp_path / "." / "in.g2o"):
        with pytest.raises(OutputError, match="refusing to overwrite the input file"):
            write_g2o(same, graph, graph.poses * 1.0)
    link = tmp_path / "link.g2o"
    os.link(source, link)  # another name for the same file
    with pytest.raises(OutputError):
        write_g2o(link, graph)
    assert source.read_bytes() == before
    assert sorted(os.listdir(tmp_path)) == ["in.g2o", "link.g2o"]


def test_overwrite_input_when_asked(tmp_path):
    rng = np.random.default_rng(6)
    source = tmp_path / "in.g2o"
    write_g2o(source, random_graph(rng))
    graph = read_quietly(source)
    new_poses = random_graph(rng, n=graph.num_vertices).poses
    write_g2o(source, graph, new_poses, overwrite_input=True)
    assert_same_graph(read_quietly(source), graph, poses=new_poses)
    assert os.listdir(tmp_path) == ["in.g2o"]


def test_missing_output_folder(tmp_path):
    target = tmp_path / "absent" / "out.g2o"
    with pytest.raises(OutputError, match="does not exist") as info:
        write_g2o(target, random_graph(np.random.default_rng(7)))
    assert info.value.path == str(target)
    assert os.listdir(tmp_path) == []


def test_output_path_that_is_a_folder(tmp_path):
    with pytest.raises(OutputError, match="is a folder"):
        write_g2o(tmp_path, random_graph(np.random.default_rng(8)))
    assert os.listdir(tmp_path) == []


def test_non_finite_poses_are_not_written(tmp_path):
    graph = random_graph(np.random.default_rng(9))
    poses = graph.poses.copy()
    poses[2, 0, 3] = np.nan
    with pytest.raises(OutputError, match="NaN or infinite"):
        write_g2o(tmp_path / "out.g2o", graph, poses)
    with pytest.raises(ValueError, match="shape"):
        write_g2o(tmp_path / "out.g2o", graph, poses[:-1])
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize("interruption", [KeyboardInterrupt, OSError(28, "No space left on device")])
@pytest.mark.parametrize("where", ["fsync", "replace"])
def test_no_partial_file_and_old_file_kept_on_interruption(tmp_path, monkeypatch, interruption, where):
    target = tmp_path / "out.g2o"
    target.write_text("previous content\n")
    graph = random_graph(np.random.default_rng(10))

    def fail(*args, **kwargs):
        raise interruption

    monkeypatch.setattr(os, where, fail)
    expected = KeyboardInterrupt if interruption is KeyboardInterrupt else OutputError
    with pytest.raises(expected):
        write_g2o(target, graph)
    monkeypatch.undo()
    assert os.listdir(tmp_path) == ["out.g2o"]
    assert target.read_text() == "previous content\n"


def test_no_partial_file_for_a_new_target(tmp_path, monkeypatch):
    def fail(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(os, "replace", fail)
    with pytest.raises(KeyboardInterrupt):
        write_g2o(tmp_path / "new.g2o", random_graph(np.random.default_rng(11)))
    monkeypatch.undo()
    assert os.listdir(tmp_path) == []


def test_new_file_gets_ordinary_permissions(tmp_path):
    umask = os.umask(0o022)
    os.umask(umask)
    write_g2o(tmp_path / "out.g2o", random_graph(np.random.default_rng(12)))
    assert (tmp_path / "out.g2o").stat().st_mode & 0o777 == 0o666 & ~umask


def test_graph_built_in_memory_has_no_source_and_writes_anywhere(tmp_path):
    graph = random_graph(np.random.default_rng(13))
    assert graph.source is None
    write_g2o(str(tmp_path / "x.g2o"), graph)
    assert_same_graph(read_quietly(tmp_path / "x.g2o"), graph)


# --- edges read from a file are written as they were read (posegraph.model.graph.EdgeSource)

INFORMATION_TEXT = " ".join(["1e2", "0", "0", "0", "0", "0", "100.0", "0", "0", "0", "0", "1E+2", "0", "0", "0",
                             "400", "0", "0", "4.0e2", "0", "400"])  # fmt: skip
ODD_EDGES = (
    "EDGE_SE3:QUAT 0 1 1 0.0 0 0 0 0 1 " + INFORMATION_TEXT + "  \r\n",  # CRLF and trailing blanks
    "EDGE_SE3:QUAT\t1\t2\t+1.5 -0 2e-3 0 0 0.3 0.9  " + INFORMATION_TEXT + "   # a comment\n",  # tabs, unnormalised q
    "EDGE_SE3:QUAT 2 0 -2.5 0 0 0 0 0 -1 " + INFORMATION_TEXT + "\n",  # qw < 0
)
VERTICES = "".join(f"VERTEX_SE3:QUAT {k} {k} 0 0 0 0 0 1\n" for k in range(3))


def edge_lines(text: str) -> list[str]:
    return [line for line in text.splitlines() if line.startswith("EDGE_SE3:QUAT")]


def test_edges_read_from_a_file_are_written_as_they_were_read(text_file, tmp_path):
    graph = read_quietly(text_file(VERTICES + "".join(ODD_EDGES)))
    assert graph.edge_source is not None and graph.edge_source.matches(graph)
    write_g2o(tmp_path / "out.g2o", graph, graph.poses + 0.0)
    written = (tmp_path / "out.g2o").read_text()
    # the text after the tag as read, comment and trailing blanks dropped
    expected = ["EDGE_SE3:QUAT " + line.partition("\t")[2].partition("#")[0].rstrip() if "\t" in line.split(" ")[0]
                else line.partition("#")[0].rstrip() for line in ODD_EDGES]  # fmt: skip
    assert edge_lines(written) == expected
    again = read_quietly(tmp_path / "out.g2o")
    for name in ("edge_from", "edge_to", "measurements", "information"):
        np.testing.assert_array_equal(getattr(again, name), getattr(graph, name))  # bit for bit


def test_a_shared_dataset_is_rewritten_with_its_own_edge_lines(shared_dataset, tmp_path):
    source = shared_dataset("smallGrid3D")
    graph = read_quietly(source)
    write_g2o(tmp_path / "out.g2o", graph)
    original = [line.rstrip() for line in source.read_text().splitlines() if line.startswith("EDGE_SE3:QUAT")]
    assert edge_lines((tmp_path / "out.g2o").read_text()) == original
    again = read_quietly(tmp_path / "out.g2o")
    np.testing.assert_array_equal(again.measurements, graph.measurements)
    np.testing.assert_array_equal(again.information, graph.information)


@pytest.mark.parametrize("change", ["information replaced", "measurement edited in place", "ids replaced", "edge reversed"])
def test_edges_changed_since_reading_are_formatted_from_their_values(change, text_file, tmp_path):
    from dataclasses import replace

    graph = read_quietly(text_file(VERTICES + "".join(ODD_EDGES)))
    if change == "information replaced":
        graph = replace(graph, information=2.0 * graph.information)
    elif change == "measurement edited in place":
        graph.measurements[0, 0, 3] += 0.25
    elif change == "ids replaced":
        graph = replace(graph, ids=graph.ids + 10)
    else:
        graph = replace(graph, edge_from=graph.edge_to, edge_to=graph.edge_from)
    assert graph.edge_source is not None and not graph.edge_source.matches(graph)
    write_g2o(tmp_path / "out.g2o", graph)
    rows = [line.split() for line in edge_lines((tmp_path / "out.g2o").read_text())]
    assert all(len(row) == 31 for row in rows)  # formatted: every number as its repr
    again = read_quietly(tmp_path / "out.g2o")
    np.testing.assert_array_equal(again.ids, graph.ids)
    np.testing.assert_array_equal(again.edge_from, graph.edge_from)
    np.testing.assert_array_equal(again.information, graph.information)
    np.testing.assert_allclose(again.measurements, graph.measurements, rtol=0, atol=1e-15)


def test_edges_are_not_kept_when_not_all_g2o_quaternion_lines_or_repaired(text_file):
    euler = "EDGE3 0 2 1 0 0 0 0 0 " + INFORMATION_TEXT + "\n"
    assert read_quietly(text_file(VERTICES + ODD_EDGES[0] + euler)).edge_source is None
    indefinite = "EDGE_SE3:QUAT 2 0 1 0 0 0 0 0 1 " + INFORMATION_TEXT.replace("400", "-400", 1) + "\n"

    def read_repairing(text):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", InputWarning)
            return read_g2o(text_file(text), repair_information=True)

    assert read_repairing(VERTICES + ODD_EDGES[0] + ODD_EDGES[1] + indefinite).edge_source is None
    # asked to repair, but nothing needed it: the lines still state the edges
    kept = read_repairing(VERTICES + "".join(ODD_EDGES))
    assert kept.edge_source is not None and kept.edge_source.matches(kept)
