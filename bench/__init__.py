"""Benchmarks of the dacrt engine against Embree and Open3D (see bench/README.md)."""
