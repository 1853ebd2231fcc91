"""Property-based API test: schemathesis generates requests from the OpenAPI schema (valid and
invalid), and no request may produce a server error (5xx)."""

from __future__ import annotations

import atexit
import tempfile
from pathlib import Path

import schemathesis
from fastapi.testclient import TestClient
from hypothesis import HealthCheck, settings
from schemathesis.checks import not_a_server_error
from schemathesis.specs.openapi.checks import (
    content_type_conformance,
    response_schema_conformance,
)

from tactus_memory.service.app import create_app
from tactus_memory.service.settings import Settings
from tests.test_service_helpers import make_memory, window

_TMP = tempfile.TemporaryDirectory(prefix="tactus-schemathesis-")
atexit.register(_TMP.cleanup)


def _app():
    memory = make_memory(Path(_TMP.name) / "mem")
    app = create_app(Settings(max_body_bytes=256 * 1024), memory=memory)
    with TestClient(app) as client:  # some rows, so searches and session reads have data
        client.post("/sessions/s1/text", json={"text": "a red ball", "t": 1.0})
        client.post("/sessions/s1/touch", json={"frames": window(k=2).tolist(), "t": 2.0})
        client.post("/senses", json={"name": "motion", "dim": 64})
    return app


@schemathesis.serializer("application/x-npy")
def _npy_body(ctx, value):
    """Generated 'binary' bodies go out as they are (mostly not valid .npy: must be 4xx)."""
    if isinstance(value, bytes):
        return value
    return str(value).encode()


# Built at import (schemathesis parametrizes per operation at collection time).
schema = schemathesis.openapi.from_asgi("/openapi.json", _app())


@schema.parametrize()
@settings(
    max_examples=20,
    deadline=None,
    suppress_health_check=list(HealthCheck),
    derandomize=True,
)
def test_no_input_produces_a_server_error(case):
    case.call_and_validate(
        checks=[
            not_a_server_error,
            content_type_conformance,
            response_schema_conformance,  # a documented status's body matches its schema
            # status_code_conformance is not on yet: a body that is not JSON gets an
            # undocumented 400 on the JSON routes (issue 16 note)
        ]
    )
