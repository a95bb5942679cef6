"""Files in and out: the g2o reader and writer (:mod:`posegraph.io.g2o`), TUM/KITTI trajectories
(:mod:`posegraph.io.trajectory`), compressed and streamed input (:mod:`posegraph.io.text_input`),
all-or-nothing output files (:mod:`posegraph.io.atomic`) and the Open3D export
(:mod:`posegraph.io.export_open3d`). Above the data model; nothing here solves."""
