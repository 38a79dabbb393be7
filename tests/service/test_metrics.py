"""What /metrics counts, in process: requests by the method the client sent and by the route
that served them."""

from __future__ import annotations

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
