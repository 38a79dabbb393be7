"""Independent engines that the tests compare dacrt with and the benchmarks time beside it: one
adapter each, shared by ``tests/`` and ``bench/`` (run from the repository's root, or with it on
``sys.path``; the package is not installed with dacrt).

``embree``: Embree through ``embreex`` (closest hits and occlusion). ``open3d_hits``: Open3D's
``RaycastingScene`` (every hit and crossing counts). ``open3d_points``: its point queries
(distance, signed distance). Each imports its engine when used, so
importing the package never fails. The plain NumPy reference of the tests is ``tests/reference.py``.
"""
