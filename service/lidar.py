"""Spinning lidars for ``/lidar``: the engine's beam models and revolutions
(``dacrt.sensors.models`` and ``dacrt.sensors.lidar``, whose docstrings state the conventions of
docs/sensors.md and cite each model's source), imported here for the service's modules."""

from __future__ import annotations

from dacrt.sensors.lidar import Scan, make_scan, points
from dacrt.sensors.models import HDL_32E, HDL_64E, MODELS, OS1_64, OS1_128, VLP_16, BeamModel

__all__ = [
    "Scan",
    "make_scan",
    "points",
    "HDL_32E",
    "HDL_64E",
    "MODELS",
    "OS1_64",
    "OS1_128",
    "VLP_16",
    "BeamModel",
]
