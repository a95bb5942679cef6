"""Shared helpers of the g2o tests."""

import warnings

from posegraph.errors import InputWarning
from posegraph.io.g2o import read_g2o


def read_with_warnings(path, **options):
    """``(graph, messages)``: ``read_g2o(path, **options)`` and the texts of the InputWarnings it gave."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        graph = read_g2o(path, **options)
    return graph, [str(w.message) for w in caught if issubclass(w.category, InputWarning)]
