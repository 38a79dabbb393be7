"""Sensors in process: depth cameras and lidars traced on a ``dacrt.Scene`` (docs/sensors.md).

    camera = dacrt.sensors.Camera(640, 480, fx=500, fy=500, cx=319.5, cy=239.5)
    image = camera.capture(scene, pose)                     # image["depth"] (480, 640) ...
    lidar = dacrt.sensors.Lidar("HDL-64E", horizontal_steps=2048, return_mode="dual")
    points = lidar.scan(scene, pose, materials)             # points["xyz"], points["intensity"]
    both = dacrt.sensors.Rig({"roof": lidar, "front": camera}).capture(scene, poses)

Modules: ``cameras`` (pinholes, look-at poses, ``Camera``), ``lidar`` (a revolution's rays,
``Lidar``), ``models`` (the named beam patterns), ``patterns`` (uploaded scan patterns),
``physics`` (materials, intensity, returns, noise, dropout), ``batch`` (several sensors traced
as one batch), ``rig`` (``Rig``), ``pcd`` (PCD files), ``checks`` (option checks naming the
HTTP body's keys).
"""

from .cameras import (
    CAMERA_FIELDS,
    Camera,
    CameraError,
    CameraImage,
    Pinhole,
    check_pose,
    look_at,
    look_at_pose,
)
from .lidar import LIDAR_FIELDS, Lidar, LidarPoints, Scan, make_scan
from .models import MODELS, BeamModel
from .patterns import Pattern
from .pcd import pcd_bytes, write_pcd
from .physics import RETURN_MODES, Dropout, Materials, Noise
from .rig import Rig

__all__ = [
    "CAMERA_FIELDS",
    "Camera",
    "CameraError",
    "CameraImage",
    "Pinhole",
    "check_pose",
    "look_at",
    "look_at_pose",
    "LIDAR_FIELDS",
    "Lidar",
    "LidarPoints",
    "Scan",
    "make_scan",
    "MODELS",
    "BeamModel",
    "Pattern",
    "pcd_bytes",
    "write_pcd",
    "RETURN_MODES",
    "Dropout",
    "Materials",
    "Noise",
    "Rig",
]
