"""Rigs: several sensors on one scene, their rays traced as one batch (``batch``); each answers
what it answers alone."""

from __future__ import annotations

from collections.abc import Mapping

from ..chunks import map_on_threads
from ..validation import InputError, check_row_count
from .batch import capture, check_query, workers
from .cameras import Camera, CameraImage
from .lidar import Lidar, LidarPoints
from .physics import Materials


class Rig:
    """Named sensors (``Camera`` or ``Lidar``): ``Rig({"roof": lidar, "front": camera})``."""

    def __init__(self, sensors: Mapping[str, Camera | Lidar]):
        _check_mapping(sensors, "sensors")
        if not sensors:
            raise InputError("sensors: name at least one sensor")
        for name, sensor in sensors.items():
            if not isinstance(sensor, (Camera, Lidar)):
                raise InputError(
                    f"sensors.{name} must be a dacrt.sensors.Camera or Lidar, got {sensor!r}"
                )
        self.sensors = dict(sensors)

    def capture(
        self,
        scene,
        poses: Mapping[str, object],
        materials: Materials | dict | None = None,
        poses_end: Mapping[str, object] | None = None,
        **query,
    ) -> dict[str, CameraImage | LidarPoints]:
        """{name: answer} of every sensor at its pose in ``poses`` (4x4 sensor-to-scene), traced
        together; ``poses_end`` names the lidars (with ``period_s``) that move during their
        sweep and their poses at its end; ``materials`` and ``query`` as for a sensor alone."""
        _check_mapping(poses, "poses")
        _check_mapping(poses_end or {}, "poses_end")
        check_query(query)
        poses_end = dict(poses_end or {})
        for name in poses_end:
            if not isinstance(self.sensors.get(name), Lidar):
                raise InputError(f"poses_end.{name}: only a lidar of the rig takes pose_end")
        missing = [name for name in self.sensors if name not in poses]
        unknown = [name for name in poses if name not in self.sensors]
        if missing or unknown:
            raise InputError(
                f"poses must name every sensor of the rig ({', '.join(self.sensors)}): "
                f"missing {missing}, unknown {unknown}"
            )
        names = list(self.sensors)
        n_rays = sum(sensor.n_traced_rays for sensor in self.sensors.values())
        check_row_count(n_rays, "the rig's batch (its sensors' rays together)", "rays")

        def shot(k):
            name = names[k]
            sensor = self.sensors[name]
            try:
                if name in poses_end:
                    return sensor.shot(poses[name], poses_end[name])
                return sensor.shot(poses[name])
            except InputError as error:
                raise InputError(f"sensors.{name}: {error}") from None

        # Each sensor's rays are made side by side (the first bad sensor in order is named).
        shots = map_on_threads(shot, len(names), workers(len(names), query))
        answers = capture(scene, shots, materials, **query)
        return dict(zip(self.sensors, answers))


def _check_mapping(value, key: str) -> None:
    if not isinstance(value, Mapping):
        raise InputError(
            f"{key} must be a mapping of sensor names (a dict), got {type(value).__name__}"
        )
