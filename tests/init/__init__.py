"""Tests of posegraph.init (initialisation)."""
