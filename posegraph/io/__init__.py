"""Files in and out: the g2o reader and writer (:mod:`posegraph.io.g2o`), TUM/KITTI trajectories
(:mod:`posegraph.io.trajectory`), compressed and streamed input (:mod:`posegraph.io.text_input`),
all-or-nothing output files (:mod:`posegraph.io.atomic`) and the Open3D export
(:mod:`posegraph.io.export_open3d`). Above the data model; nothing here solves."""


from posegraph import submodule_getattr as _submodule_getattr  # noqa: E402

__getattr__ = _submodule_getattr(__name__)  # its modules on first use (PEP 562)
