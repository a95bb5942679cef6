"""Side-by-side benchmarks against gtsam (``python -m benchmarks``) and the scaling study
(``python -m benchmarks.scaling``). Not installed with the package; run from the project root.
See ``docs/benchmarks.md``.
"""
