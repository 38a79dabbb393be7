"""Schema fuzzing: schemathesis builds requests from the OpenAPI document, bodies in every declared
media type included, that follow it (positive) and that break it (negative), and sends them to a
real server; none may answer 5xx, and every error is a JSON ``{"detail": str}``."""

from __future__ import annotations

import httpx
import pytest
import schemathesis
from hypothesis import HealthCheck, given, settings
from schemathesis import GenerationMode

from service.app import create_app
from service.settings import Settings

#: Examples per operation and mode: 25 x 24 cases, 600 requests in all.
EXAMPLES = 25
DOCUMENT = create_app(Settings()).openapi()
OPERATIONS = {
    f"{op.method.upper()} {op.path}": op
    for op in (
        result.ok() for result in schemathesis.openapi.from_dict(DOCUMENT).get_all_operations()
    )
}

#: (operation, mode) pairs; an operation that takes no input has no negative case.
CASES = [
    (name, mode)
    for name, op in sorted(OPERATIONS.items())
    for mode in GenerationMode
    if mode is GenerationMode.POSITIVE or op.query or op.path_parameters or op.body
]


def test_the_server_serves_the_fuzzed_document(hostile_server):
    assert httpx.get(f"{hostile_server.url}/openapi.json").json() == DOCUMENT


@pytest.mark.parametrize("name, mode", CASES, ids=[f"{n} {m.value}" for n, m in CASES])
def test_no_request_gets_a_server_error(hostile_server, name, mode):
    @given(case=OPERATIONS[name].as_strategy(generation_mode=mode))
    @settings(
        max_examples=EXAMPLES,
        deadline=None,
        derandomize=True,
        database=None,
        suppress_health_check=list(HealthCheck),
    )
    def call(case):
        response = case.call(base_url=hostile_server.url, timeout=30)
        assert response.status_code < 500, (name, response.status_code, response.text[:300])
        if response.status_code >= 400:
            assert response.headers["content-type"] == ["application/json"], response.text[:300]
            body = response.json()
            assert list(body) == ["detail"] and isinstance(body["detail"], str), body

    call()
