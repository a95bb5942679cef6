"""Bundled example pose graphs and synthetic generators with ground truth (not installed with the package).

:mod:`datasets.synthetic` makes sphere, torus, 3D-grid and parking-garage graphs; ``example_sphere.g2o``
(and its ``_groundtruth.g2o``) is one of them, small enough to ship. See ``datasets/README.md``.
"""
