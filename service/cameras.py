"""Pinhole cameras for ``/render`` and ``/camera``: the engine's (``dacrt.sensors.cameras``, whose
docstring states the conventions of docs/sensors.md), imported here for the service's modules."""

from __future__ import annotations

from dacrt.sensors.cameras import (
    PARALLEL_SINE,
    ROTATION_TOLERANCE,
    CameraError,
    Pinhole,
    check_pose,
    look_at,
)

__all__ = ["PARALLEL_SINE", "ROTATION_TOLERANCE", "CameraError", "Pinhole", "check_pose", "look_at"]
