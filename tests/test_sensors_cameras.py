"""dacrt.sensors.Camera: its rays are bit for bit docs/sensors.md's (re-derived in
``sensor_reference``), for intrinsics and a pose and for a look-at camera; its images are
``Scene.closest``'s answers for those rays."""

from __future__ import annotations

import numpy as np
import pytest
from sensor_reference import look_at, pinhole_rays
from sensor_scenes import ROOM

import dacrt
from dacrt.sensors import Camera, Rig, check_pose, look_at_pose
from dacrt.sensors.checks import FLOAT32_MAX

POSE = np.array([[1, 0, 0, 0], [0, 0, 1, -7], [0, -1, 0, 1], [0, 0, 0, 1]], np.float64)
LOOK_ATS = [
    ((8.0, -6.0, 4.0), (0.0, 0.0, 1.0), (0.0, 0.0, 1.0), 45.0, 64, 48),
    ((-3.0, 2.5, 1.0), (3.0, 1.0, 1.0), (0.0, 0.3, 2.0), 70.0, 33, 21),
]


@pytest.fixture(scope="module")
def room():
    return dacrt.Scene(ROOM)


def test_intrinsics_and_a_pose_make_the_documented_rays():
    camera = Camera(64, 48, fx=50.0, fy=52.0, cx=31.5, cy=23.0, near=0.1, far=50.0)
    rays = camera.shot(POSE).rays
    origins, directions = pinhole_rays(50.0, 52.0, 31.5, 23.0, POSE, 64, 48)
    np.testing.assert_array_equal(rays.directions, directions)
    np.testing.assert_array_equal(rays.origins, origins)
    assert (rays.tmin, rays.tmax) == (0.1, 50.0)


@pytest.mark.parametrize("view", LOOK_ATS)
def test_a_look_at_camera_makes_the_documented_rays(view):
    eye, target, up, fov, width, height = view
    rays = Camera.from_fov(width, height, fov).shot(look_at_pose(eye, target, up)).rays
    pose, focal = look_at(eye, target, up, fov, height)
    origins, directions = pinhole_rays(
        focal, focal, (width - 1) / 2, (height - 1) / 2, pose, width, height
    )
    np.testing.assert_array_equal(rays.directions, directions)
    np.testing.assert_array_equal(rays.origins, origins)


@pytest.mark.parametrize("view", LOOK_ATS)
def test_the_image_is_closests_answer(room, view):
    eye, target, up, fov, width, height = view
    image = Camera.from_fov(width, height, fov, near=0.5).capture(
        room, look_at_pose(eye, target, up)
    )
    pose, focal = look_at(eye, target, up, fov, height)
    origins, directions = pinhole_rays(
        focal, focal, (width - 1) / 2, (height - 1) / 2, pose, width, height
    )
    hits = room.closest(origins, directions, 0.5, np.inf)
    shape = (height, width)
    length = np.linalg.norm(directions.astype(np.float64), axis=1)
    np.testing.assert_array_equal(image["depth"], hits.t.reshape(shape))
    np.testing.assert_array_equal(
        image["range"], (hits.t * length).astype(np.float32).reshape(shape)
    )
    np.testing.assert_array_equal(image["mesh"], hits.mesh.reshape(shape))
    np.testing.assert_array_equal(image["prim"], hits.prim.reshape(shape))
    np.testing.assert_array_equal(image["normal"], hits.normal.reshape(*shape, 3))
    assert np.isfinite(image["depth"]).mean() > 0.3


@pytest.mark.parametrize(
    ("make", "words"),
    [
        (lambda: Camera(0, 4, 1.0, 1.0, 0.0, 0.0), "width must be >= 1"),
        (lambda: Camera(4, 4, -1.0, 1.0, 0.0, 0.0), "fx must be > 0"),
        (lambda: Camera(4, 4, 1.0, 1.0, np.inf, 0.0), "cx must be a finite number"),
        (lambda: Camera(4, 4, 1.0, 1.0, 0.0, 0.0, near=-1), "near must be >= 0"),
        (lambda: Camera(4, 4, 1.0, 1.0, 0.0, 0.0, near=2, far=1), "far must be > 2"),
        (lambda: Camera(4, 4, 1.0, 1.0, 0.0, 0.0, near=1e39), "near must be <= 3.40282e+38"),
        (lambda: Camera.from_fov(4, 4, near=10**39), "near must be <= 3.40282e+38"),
        (lambda: Camera(4, 4, 1e-300, 1.0, 0.0, 0.0), "fx: 1e-300 is too small"),
        (lambda: Camera.from_fov(4, 4, 180.0), "fov_deg must be between 0 and 180"),
        # integers beyond float64 (JSON has them): named, not an OverflowError
        (lambda: Camera(10**400, 4, 1.0, 1.0, 0.0, 0.0), "width must be >= 1 and <= 2147483647"),
        (lambda: Camera(4, 4, 10**400, 1.0, 0.0, 0.0), "fx must be a finite number"),
        (lambda: Camera(4, 4, 1.0, 1.0, 0.0, -(10**400)), "cy must be a finite number"),
        (lambda: Camera.from_fov(10**400, 4), "width must be >= 1 and <= 2147483647, got an"),
        (lambda: Camera.from_fov(4, 10**400), "height must be >= 1 and <= 2147483647"),
        (lambda: Camera.from_fov(4, 4, 10**400), "fov_deg must be a finite number"),
        (lambda: look_at_pose((0, 0, 0), (0, 0, 0), (0, 1, 0)), "eye and target"),
        (lambda: look_at_pose((0, 0, 0), (0, 1, 0), (0, 2, 0)), "parallel"),
        (lambda: Camera(4, 4, 1.0, 1.0, 0.0, 0.0).shot(np.diag([1, 1, -1, 1])), "pose[:3, :3]"),
        (lambda: Camera(4, 4, 1.0, 1.0, 0.0, 0.0).shot("I"), "pose must be numbers"),
        (lambda: Camera(4, 4, 1.0, 1.0, 0.0, 0.0).shot(np.eye(4) * 1j), "got complex128"),
        (lambda: look_at_pose((0, 0), (1, 0, 0), (0, 1, 0)), "eye must have shape (3,)"),
        (
            lambda: Camera.from_fov(2**16, 2**15).shot(np.eye(4)),
            "an image (width x height) has 2,147,483,648",
        ),
        (lambda: look_at_pose((0, 0, 0), "abc", (0, 1, 0)), "target must be numbers"),
        (lambda: look_at_pose((0, 0, 0), (1, 0, 0), [[0, 1, 0]]), "up must have shape (3,)"),
        (lambda: look_at_pose((np.nan, 0, 0), (1, 0, 0), (0, 1, 0)), "eye has non-finite"),
        (lambda: look_at_pose((1e308, 0, 0), (-1e308, 0, 0), (0, 1, 0)), "too far apart"),
    ],
)
def test_a_bad_camera_is_refused_naming_its_key(make, words):
    with pytest.raises(dacrt.InputError) as error:
        make()
    assert words in str(error.value)


def test_a_far_beyond_float32_is_no_limit():
    """The depth window is the rays' float32 tmin and tmax, as a lidar's range window is."""
    assert Camera(4, 4, 1.0, 1.0, 0.0, 0.0, far=1e39).far == np.inf
    assert Camera(4, 4, 1.0, 1.0, 0.0, 0.0, far=FLOAT32_MAX).far == FLOAT32_MAX
    assert Camera(4, 4, 1.0, 1.0, 0.0, 0.0, near=FLOAT32_MAX).near == FLOAT32_MAX


def test_near_and_far_round_to_the_nearest_float32_as_documented():
    """A camera's window is rounded to the nearest float32, as its rays are (docs/sensors.md):
    a near of 2.00000001 or a far of 1.99999999 is float32's 2.0, so a hit at depth 2.0 is seen,
    though the engine's query with those float64 bounds (rounded inward) sees nothing."""
    floor = dacrt.Scene([(np.float32([[-9, -9, 0], [9, -9, 0], [0, 9, 0]]), [[0, 1, 2]])])
    pose = look_at_pose((0.0, 0.0, 2.0), (0.0, 0.0, 0.0), (0.0, 1.0, 0.0))
    for window in ({"near": 2.00000001}, {"far": 1.99999999}):
        image = Camera.from_fov(1, 1, 60.0, **window).capture(floor, pose)
        assert image["depth"][0, 0] == 2.0, window
    rays = Camera.from_fov(1, 1, 60.0).shot(pose).rays
    assert floor.closest(rays.origins, rays.directions).t[0] == 2.0
    assert floor.closest(rays.origins, rays.directions, 2.00000001).mesh[0] == -1
    assert floor.closest(rays.origins, rays.directions, 0.0, 1.99999999).mesh[0] == -1


def test_a_look_at_pose_far_from_the_origin_looks_at_its_target():
    """eye and target 2e300 apart: the view's length overflows float64, its direction does not."""
    pose = look_at_pose((1e300, 0, 0), (-1e300, 0, 0), (0, 0, 1))
    np.testing.assert_array_equal(pose[:3, 2], [-1.0, 0.0, 0.0])
    np.testing.assert_array_equal(pose[:3, 3], [1e300, 0.0, 0.0])
    np.testing.assert_allclose(pose[:3, :3].T @ pose[:3, :3], np.eye(3), atol=1e-15)
    tiny_up = look_at_pose((0, 0, 0), (1, 0, 0), (0, 0, 1e-300))
    np.testing.assert_array_equal(tiny_up, look_at_pose((0, 0, 0), (1, 0, 0), (0, 0, 1)))


def test_a_camera_whose_edge_rays_just_fit_float32_is_accepted():
    """The guard on the edge rays' slope uses the outermost pixel, width - 1 - cx."""
    fx = 1 / (0.75 * FLOAT32_MAX)  # the edge ray's slope (1 - 0) / fx is 0.75 of float32's max
    camera = Camera(2, 1, fx=fx, fy=1.0, cx=0.0, cy=0.0)
    directions = camera.shot(np.eye(4)).rays.directions
    assert np.isfinite(directions).all()
    assert directions[1, 0] == np.float32(0.75 * FLOAT32_MAX)


def test_edge_rays_a_legal_pose_takes_beyond_float32_name_the_cameras_keys(room):
    """A rotation orthonormal within the tolerance lengthens the columns by up to 5e-5: edge rays
    whose slope just fits float32 may not, and the camera says so in its own keys."""
    pose = np.eye(4)
    pose[0, 0], pose[:3, 3] = 1.00004, (0.5, 0.5, -3.0)
    check_pose(pose)  # a legal pose
    camera = Camera(2, 1, fx=1 / FLOAT32_MAX, fy=1.0, cx=0.0, cy=0.0)
    with pytest.raises(dacrt.InputError, match=r"^fx: .* is too small for cx 0.0 at this pose"):
        camera.shot(pose)
    rig = Rig({"ok": Camera(2, 2, 1.0, 1.0, 0.5, 0.5), "bad": camera})
    with pytest.raises(dacrt.InputError, match=r"^sensors.bad: fx: .* at this pose"):
        rig.capture(room, {"ok": POSE, "bad": pose})


def far_wall_view():
    """A triangle at depth 3.2e38 before a 3x1 camera whose side pixels' rays are 1.077 long:
    the side pixels' range, 3.45e38, is beyond float32, their depth is not."""
    x, half = 1.6e38, 3.3e38
    wall = np.array([[x, -half, -half], [x, half, -half], [x, 0, half]], np.float32)
    pose = np.array([[0, 0, 1, -x], [-1, 0, 0, 0], [0, -1, 0, 0], [0, 0, 0, 1]], np.float64)
    return dacrt.Scene([(wall, [[0, 1, 2]])]), Camera(3, 1, fx=2.5, fy=2.5, cx=1.0, cy=0.0), pose


def test_a_hit_whose_range_is_beyond_float32_is_a_miss_in_every_key():
    scene, camera, pose = far_wall_view()
    image = camera.capture(scene, pose)
    hit = np.isfinite(image["depth"])
    assert hit.tolist() == [[False, True, False]]
    assert image["depth"][0, 1] == np.float32(3.2e38)
    assert image["range"][0, 1] == image["depth"][0, 1]
    np.testing.assert_array_equal(np.isfinite(image["range"]), hit)
    np.testing.assert_array_equal(image["mesh"] >= 0, hit)
    np.testing.assert_array_equal(image["prim"] >= 0, hit)
    np.testing.assert_array_equal(image["normal"].any(axis=2), hit)
    assert image["mesh"].dtype == np.int32 and image["depth"].dtype == np.float32
    assert image["normal"].dtype == np.float32
