"""CHOLMOD 3's ``cholmod_factor``, read in place from the capsule cvxopt keeps it in (ctypes, read only).

cvxopt exposes no accessor for the factor's sizes or arrays; :func:`read_factor` gives its fields as
integers (sizes, and addresses for the pointers) for :func:`posegraph.linalg.cholmod._supernodal_sizes`
and :class:`posegraph.linalg.supernodal.SupernodalPaths`, each of which checks that the read describes
the factor it expects before trusting it.
"""

from __future__ import annotations

import ctypes

__all__ = ["read_factor", "FACTOR_FIELDS", "FACTOR_FLAGS"]

FACTOR_FIELDS = ("n", "minor", "Perm", "ColCount", "IPerm", "nzmax", "p", "i", "x", "z", "nz", "next", "prev",
                 "nsuper", "ssize", "xsize", "maxcsize", "maxesize", "super", "pi", "px", "s")  # fmt: skip
"""The word-sized fields at the head of CHOLMOD 3's ``cholmod_factor`` (``cholmod_core.h``), in order."""

FACTOR_FLAGS = ("ordering", "is_ll", "is_super", "is_monotonic", "itype", "xtype", "dtype", "useGPU")
"""The ``int`` fields that follow them."""


def read_factor(capsule) -> dict[str, int] | None:
    """The fields of the ``cholmod_factor`` in cvxopt's ``capsule`` (``FACTOR_FIELDS`` then ``FACTOR_FLAGS``),
    or None when ``capsule`` is not a CHOLMOD factor capsule or words are not 64-bit."""
    get_name = ctypes.pythonapi.PyCapsule_GetName
    get_name.restype, get_name.argtypes = ctypes.c_char_p, [ctypes.py_object]
    get_pointer = ctypes.pythonapi.PyCapsule_GetPointer
    get_pointer.restype, get_pointer.argtypes = ctypes.c_void_p, [ctypes.py_object, ctypes.c_char_p]
    if ctypes.sizeof(ctypes.c_size_t) != 8 or type(capsule).__name__ != "PyCapsule":
        return None
    name = get_name(capsule)
    if not name or not name.startswith(b"CHOLMOD FACTOR"):
        return None
    words = (ctypes.c_size_t * len(FACTOR_FIELDS)).from_address(get_pointer(capsule, name))
    flags = (ctypes.c_int * len(FACTOR_FLAGS)).from_address(ctypes.addressof(words) + ctypes.sizeof(words))
    return {**dict(zip(FACTOR_FIELDS, words)), **dict(zip(FACTOR_FLAGS, flags))}
