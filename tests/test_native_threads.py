"""NativeThreads: the system OpenBLAS and OpenMP run the asked number of threads inside, their own after."""

from __future__ import annotations

import numpy as np
import pytest

from posegraph.native_threads import NativeThreads, openmp_libraries, system_openblas_libraries

cholmod = pytest.importorskip("sksparse.cholmod", reason="scikit-sparse (CHOLMOD) is not installed")


def openblas_or_skip():
    libraries = system_openblas_libraries()
    if not libraries:
        pytest.skip("no system OpenBLAS loaded in this process (reference BLAS, MKL or not Linux)")
    return libraries


def openmp_or_skip():
    libraries = openmp_libraries()
    if not libraries:
        pytest.skip("no OpenMP runtime loaded in this process")
    return libraries


@pytest.fixture
def openblas_threads():
    """The system OpenBLAS set to 2 threads for the test (restored after), so that 1 is a change."""
    libraries = openblas_or_skip()
    saved = [lib.openblas_get_num_threads() for lib in libraries]
    for lib in libraries:
        lib.openblas_set_num_threads(2)
    yield libraries
    for lib, value in zip(libraries, saved):
        lib.openblas_set_num_threads(value)


def test_one_thread_inside_and_the_previous_settings_after(openblas_threads):
    openmp = openmp_or_skip()
    levels = [lib.omp_get_max_active_levels() for lib in openmp]
    assert all(level > 0 for level in levels)
    threads = NativeThreads(1)
    assert threads.active
    with threads:
        assert [lib.openblas_get_num_threads() for lib in openblas_threads] == [1] * len(openblas_threads)
        assert [lib.omp_get_max_active_levels() for lib in openmp] == [0] * len(openmp)  # regions run serially
    assert [lib.openblas_get_num_threads() for lib in openblas_threads] == [2] * len(openblas_threads)
    assert [lib.omp_get_max_active_levels() for lib in openmp] == levels
    with threads:  # reusable
        assert openblas_threads[0].openblas_get_num_threads() == 1
    assert openblas_threads[0].openblas_get_num_threads() == 2


def test_restored_after_an_exception(openblas_threads):
    with pytest.raises(ZeroDivisionError), NativeThreads(1):
        assert openblas_threads[0].openblas_get_num_threads() == 1
        1 / 0
    assert openblas_threads[0].openblas_get_num_threads() == 2


def test_more_threads_leave_openmp_alone(openblas_threads):
    openmp = openmp_or_skip()
    levels = [lib.omp_get_max_active_levels() for lib in openmp]
    with NativeThreads(3):
        assert openblas_threads[0].openblas_get_num_threads() == 3
        assert [lib.omp_get_max_active_levels() for lib in openmp] == levels
    assert openblas_threads[0].openblas_get_num_threads() == 2


def test_none_changes_nothing(openblas_threads):
    threads = NativeThreads(None)
    assert not threads.active
    with threads:
        assert openblas_threads[0].openblas_get_num_threads() == 2


@pytest.mark.parametrize("bad", [0, -1, 1.5, 2.0000001])
def test_bad_thread_counts_are_refused(bad):
    with pytest.raises(ValueError, match="positive integer"):
        NativeThreads(bad)


def test_cholmod_factorizes_the_same_with_one_thread():
    """The supernodal factorisation inside gives CHOLMOD's own result (a dense solve's, to round-off)."""
    import scipy.sparse as sp

    rng = np.random.default_rng(0)
    n = 600
    a = sp.random(n, n, density=0.02, random_state=1)
    matrix = (a @ a.T + sp.identity(n) * 5.0).tocsc()
    rhs = rng.normal(size=n)
    with NativeThreads(1):
        solution = cholmod.cholesky(matrix, mode="supernodal")(rhs)
    np.testing.assert_allclose(solution, np.linalg.solve(matrix.toarray(), rhs), rtol=1e-10, atol=1e-12)
