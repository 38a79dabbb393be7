"""What /metrics counts, in process: requests by the method the client sent and by the route
that served them, and rays as DACRT_MAX_RAYS_PER_REQUEST counts them."""

from __future__ import annotations

import httpx
import pytest
from service_helpers import metric_sample


def requests(app_client, method: str, route: str, status: int) -> float:
    text = app_client.get("/metrics").text
    labels = f'method="{method}",route="{route}",status="{status}"'
    return metric_sample(text, f"dacrt_requests_total{{{labels}}}")


def test_head_is_counted_as_head(app_client):
    """A HEAD is served as its GET, and counted as the HEAD the client sent."""
    heads, gets = (
        requests(app_client, "HEAD", "/v1/capabilities", 200),
        requests(app_client, "GET", "/v1/capabilities", 200),
    )
    assert app_client.head("/v1/capabilities").status_code == 200
    assert requests(app_client, "HEAD", "/v1/capabilities", 200) == heads + 1
    assert requests(app_client, "GET", "/v1/capabilities", 200) == gets


@pytest.mark.parametrize(
    "path, route",
    [
        ("/openapi.json", "/openapi.json"),
        ("/static/swagger-ui/swagger-ui.css", "/static/swagger-ui/{path}"),
        ("/docs", "/docs"),
    ],
)
def test_routes_without_a_fastapi_route_are_counted_by_their_template(app_client, path, route):
    before = requests(app_client, "GET", route, 200), requests(app_client, "GET", "unmatched", 200)
    assert app_client.get(path).status_code == 200
    assert requests(app_client, "GET", route, 200) == before[0] + 1
    assert requests(app_client, "GET", "unmatched", 200) == before[1]


def test_a_path_no_route_matches_is_counted_as_unmatched(app_client):
    before = requests(app_client, "GET", "unmatched", 404)
    assert app_client.get("/no/such/path").status_code == 404
    assert requests(app_client, "GET", "unmatched", 404) == before + 1


BOX = {
    "vertices": [[-5, -5, -1], [5, -5, -1], [5, 5, -1], [-5, 5, -1], [-5, -5, 1], [5, -5, 1]],
    "faces": [[0, 2, 1], [0, 3, 2], [4, 5, 1]],
}
POSE = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]
#: VLP-16 (16 beams a step), 32 steps, 2 sub-rays a beam, 3 returns each: 3072 rays
LIDAR = {"pose": POSE, "model": "VLP-16", "horizontal_steps": 32, "beam_samples": 2}
ALL_RETURNS = {"max_returns": 3, "return_mode": "all"}


@pytest.mark.parametrize(
    "query, path, body, rays",
    [
        ("lidar", "lidar", {**LIDAR, **ALL_RETURNS}, 16 * 32 * 2 * 3),
        ("lidar", "lidar", {**LIDAR, "max_returns": 3, "return_mode": "strongest"}, 16 * 32 * 2),
        ("sensors", "sensors", {"sensors": {"a": {"kind": "lidar", **LIDAR, **ALL_RETURNS}}}, 3072),
        ("nearest", "nearest?sign=true&nsamples=5", {"points": [[0, 0, 0], [0, 0, 3]]}, 2 * 5),
        ("nearest", "nearest", {"points": [[0, 0, 0], [0, 0, 3]]}, 2),
    ],
    ids=["lidar all", "lidar strongest", "rig", "nearest sign", "nearest"],
)
def test_rays_are_counted_as_the_limit_counts_them(app_client, scene_name, query, path, body, rays):
    """dacrt_rays_traced_total counts what DACRT_MAX_RAYS_PER_REQUEST bounds (API.md): a
    lidar's beams x beam_samples (x max_returns with "all"), a point query's points (x nsamples
    with its inside test)."""
    app_client.put(f"/v1/scenes/{scene_name}/meshes/box", json=BOX).raise_for_status()
    sample = f'dacrt_rays_traced_total{{query="{query}"}}'
    before = metric_sample(app_client.get("/metrics").text, sample)
    app_client.post(f"/v1/scenes/{scene_name}/{path}", json=body).raise_for_status()
    assert metric_sample(app_client.get("/metrics").text, sample) == before + rays


def test_a_request_refused_for_its_host_is_counted(app_client):
    """A DNS-rebinding refusal (403 before any route runs) is counted as route ``refused``."""
    before = requests(app_client, "GET", "refused", 403)
    # arriving on the loopback address, where only the loopback names are allowed
    with httpx.Client(transport=app_client._transport, base_url="http://localhost") as loopback:
        answer = loopback.get("/v1/capabilities", headers={"Host": "attacker.example"})
    assert answer.status_code == 403 and "DACRT_ALLOWED_HOSTS" in answer.json()["detail"]
    assert requests(app_client, "GET", "refused", 403) == before + 1
