"""Queries from several threads while another thread keeps posting frames: every answer is
computed on exactly one scene version, the one its X-Scene-Version names."""

from __future__ import annotations

import threading

import numpy as np
from service_helpers import down_rays, quad

from service.client import Client

HEIGHT = 100.0


def frame_at(z: float) -> dict:
    """Two meshes, left and right halves of [0, 2] x [0, 1], both at height z."""
    return {"left": quad(0, 1, 0, 1, z), "right": quad(1, 2, 0, 1, z)}


def test_each_answer_matches_exactly_one_version(server, scene_name):
    rng = np.random.default_rng(0)
    xy = np.column_stack([rng.uniform(0.05, 1.95, 400), rng.uniform(0.05, 0.95, 400)])
    origins, directions = down_rays(xy, z=HEIGHT)
    height_of: dict[int, float] = {}  # version -> height of both meshes in it
    answers: list[tuple[int, np.ndarray, np.ndarray]] = []
    stop, errors = threading.Event(), []

    with Client(server) as setup:
        height_of[setup.frame(scene_name, frame_at(0.0))["version"]] = 0.0

    def post_frames():
        with Client(server) as client:
            z = 0.0
            while not stop.is_set():
                z += 1.0
                height_of[client.frame(scene_name, frame_at(z))["version"]] = z

    def query(n: int):
        try:
            with Client(server) as client:
                for _ in range(n):
                    hits = client.closest(scene_name, origins, directions, fields="t,mesh")
                    answers.append((hits.version, hits.t, hits.mesh))
        except Exception as exc:  # noqa: BLE001 - reported below
            errors.append(exc)

    poster = threading.Thread(target=post_frames)
    queriers = [threading.Thread(target=query, args=(30,)) for _ in range(4)]
    poster.start()
    for thread in queriers:
        thread.start()
    for thread in queriers:
        thread.join()
    stop.set()
    poster.join()

    assert not errors, errors
    assert len(answers) == 120 and len(height_of) > 5
    assert len({version for version, _, _ in answers}) > 1  # the queries did overlap changes
    expected_mesh = np.where(xy[:, 0] < 1, 0, 1)
    for version, t, mesh in answers:
        # both halves at the height of the version named: a frame is never seen half-applied
        # (heights differ by 1 between versions; float32 rounding is far below that)
        np.testing.assert_allclose(t, HEIGHT - height_of[version], atol=1e-3, err_msg=str(version))
        assert np.array_equal(mesh, expected_mesh)
