"""NativeThreads: the threaded BLAS bundled with cvxopt is capped inside the block and restored after."""

from __future__ import annotations

import numpy as np
import pytest

from posegraph.linalg import native_threads
from posegraph.linalg.native_threads import NativeThreads, cholmod_blas_libraries

THREADED = {"user_api": "blas", "filepath": "/venv/site-packages/cvxopt.libs/libopenblas-r0.so", "threading_layer": "pthreads"}
SERIAL = dict(THREADED, threading_layer="disabled")
NUMPY = dict(THREADED, filepath="/venv/site-packages/numpy.libs/libscipy_openblas64_.so")


def test_only_a_threaded_blas_bundled_with_cvxopt_is_controlled():
    assert cholmod_blas_libraries([THREADED, SERIAL, NUMPY, dict(THREADED, user_api="openmp")]) == [THREADED]
    windows = dict(THREADED, filepath="C:\\Python\\Lib\\site-packages\\cvxopt\\.libs\\libopenblas.dll")
    assert cholmod_blas_libraries([windows]) == [windows]


class FakeController:
    """threadpoolctl's controller over one library whose thread count the test reads."""

    def __init__(self):
        self.threads = 4

    def info(self):
        return [THREADED]

    def select(self, filepath):
        assert filepath == [THREADED["filepath"]]
        return self

    def limit(self, limits):
        saved, self.threads = self.threads, limits
        controller = self

        class Limiter:
            def restore_original_limits(self):
                controller.threads = saved

        return Limiter()


def test_one_thread_inside_and_the_previous_setting_after(monkeypatch):
    fake = FakeController()
    monkeypatch.setattr(native_threads, "_CONTROLLER", [fake])
    monkeypatch.delenv("OPENBLAS_NUM_THREADS", raising=False)
    threads = NativeThreads(1)
    assert threads.active
    with threads:
        assert fake.threads == 1
    assert fake.threads == 4
    with pytest.raises(KeyError):
        with threads:
            raise KeyError("inside")
    assert fake.threads == 4
    assert not NativeThreads(None).active  # None changes nothing


def test_one_thread_set_in_the_environment_needs_no_control(monkeypatch):
    fake = FakeController()
    monkeypatch.setattr(native_threads, "_CONTROLLER", [fake])
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "1")
    assert not NativeThreads(1).active
    two = NativeThreads(2)  # more than the environment says: controlled
    with two:
        assert fake.threads == 2
    assert fake.threads == 4


@pytest.mark.parametrize("bad", [0, -1, 1.5, "2"])
def test_bad_thread_counts_are_refused(bad):
    with pytest.raises((ValueError, TypeError)):
        NativeThreads(bad)


def test_cholmod_factorizes_the_same_with_any_thread_setting():
    from posegraph.linalg import cholmod

    if cholmod.load() is None:
        pytest.skip(cholmod.unavailable_reason())
    rng = np.random.default_rng(0)
    a = rng.normal(size=(200, 200)) * (rng.random((200, 200)) < 0.05)
    matrix = a @ a.T + np.eye(200)
    lower = np.tril(matrix)
    columns = [np.flatnonzero(lower[:, j]) for j in range(200)]
    indptr = np.concatenate([[0], np.cumsum([c.size for c in columns])])
    indices = np.concatenate(columns)
    data = np.concatenate([lower[c, j] for j, c in enumerate(columns)])
    solutions = []
    for threads in (1, 2, None):
        factor = cholmod.SparseCholesky(indptr, indices, 200, threads=threads)
        factor.factorize(data)
        solutions.append(factor.solve(np.ones(200)))
    np.testing.assert_array_equal(solutions[0], solutions[1])
    np.testing.assert_array_equal(solutions[0], solutions[2])
