"""Binary PCD v0.7 files of a lidar's points: read back by hand (``sensor_reference.read_pcd``)
and by Open3D, organized answers as HEIGHT x WIDTH."""

from __future__ import annotations

import numpy as np
import pytest
from sensor_reference import read_pcd
from sensor_scenes import POSES, ROOM, box_mesh

import dacrt
from dacrt.sensors import Lidar, Materials, pcd_bytes


@pytest.fixture(scope="module")
def points():
    return Lidar("VLP-16", horizontal_steps=90).scan(
        dacrt.Scene(ROOM), POSES[0], Materials(reflectivity=[0.3, 0.6, 0.9], label=[1, 2, 3])
    )


def test_the_fields_asked_come_back_by_hand(points):
    header, table = read_pcd(pcd_bytes(points, ["x", "y", "z", "intensity", "ring", "label"]))
    assert header["VERSION"] == ["0.7"]
    assert header["FIELDS"] == ["x", "y", "z", "intensity", "ring", "label"]
    assert header["TYPE"] == ["F", "F", "F", "F", "U", "U"]
    assert header["SIZE"] == ["4", "4", "4", "4", "2", "4"]
    assert header["HEIGHT"] == ["1"] and header["WIDTH"] == [str(points.n_points)]
    assert header["DATA"] == ["binary"]
    np.testing.assert_array_equal(np.stack([table["x"], table["y"], table["z"]], 1), points["xyz"])
    for name in ("intensity", "ring", "label"):
        np.testing.assert_array_equal(table[name], points[name])


def test_every_field_by_default(points):
    header, table = read_pcd(pcd_bytes(points))
    assert header["FIELDS"] == ["x", "y", "z"] + [name for name in points if name != "xyz"]
    for name in points:
        if name != "xyz":
            np.testing.assert_array_equal(table[name], points[name])


def test_open3d_reads_it(points, tmp_path):
    o3d = pytest.importorskip("open3d")
    path = tmp_path / "frame.pcd"
    points.write_pcd(path, ["x", "y", "z", "intensity", "ring"])
    cloud = o3d.io.read_point_cloud(str(path))
    np.testing.assert_array_equal(np.asarray(cloud.points), points["xyz"].astype(np.float64))
    tensor = o3d.t.io.read_point_cloud(str(path))
    intensity = tensor.point["intensity"].numpy().reshape(-1)
    np.testing.assert_array_equal(intensity, points["intensity"])


def test_an_organized_answer_is_height_by_width():
    grid = Lidar("VLP-16", horizontal_steps=90, organized=True).scan(dacrt.Scene(ROOM), POSES[0])
    header, table = read_pcd(pcd_bytes(grid, ["x", "y", "z", "range"]))
    assert header["HEIGHT"] == ["16"] and header["WIDTH"] == ["90"]
    np.testing.assert_array_equal(table["range"], grid["range"].reshape(-1))


def test_an_unknown_field_is_refused(points):
    with pytest.raises(dacrt.InputError, match="fields: 'colour' is not a field"):
        pcd_bytes(points, ["x", "colour"])
    with pytest.raises(dacrt.InputError, match="fields: 'x' is named more than once"):
        pcd_bytes(points, ["x", "range", "x"])
    with pytest.raises(dacrt.InputError, match="fields: 'x' is named more than once"):
        pcd_bytes(points, ["xyz", "x"])


def test_velocity_is_three_fields_as_pcl_names_them():
    box = box_mesh((-1.0, 9.0, -1.0), (1.0, 11.0, 1.0))
    moved = np.eye(4)
    moved[0, 3] = 2.0
    scene = dacrt.Scene([box], transforms_end=[moved])
    points = Lidar(vertical_angles_deg=[0.0], horizontal_steps=360, period_s=0.1).scan(
        scene, np.eye(4)
    )
    assert points.n_points > 10
    header, table = read_pcd(pcd_bytes(points, ["velocity", "range"]))
    assert header["FIELDS"] == ["velocity_x", "velocity_y", "velocity_z", "range"]
    for axis, name in enumerate(["velocity_x", "velocity_y", "velocity_z"]):
        np.testing.assert_array_equal(table[name], points["velocity"][:, axis])
    everything, _ = read_pcd(pcd_bytes(points))
    assert everything["FIELDS"][:3] == ["x", "y", "z"] and "velocity_z" in everything["FIELDS"]
    alone, table = read_pcd(pcd_bytes({"velocity": points["velocity"]}))
    assert alone["POINTS"] == [str(points.n_points)] and alone["HEIGHT"] == ["1"]
    np.testing.assert_array_equal(table["velocity_y"], points["velocity"][:, 1])
