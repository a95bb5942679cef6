"""The data model: the pose graph (:mod:`posegraph.model.graph`) and its priors, unary edges
(:mod:`posegraph.model.priors`). Above the Lie groups; below everything that reads, writes or solves a graph."""
