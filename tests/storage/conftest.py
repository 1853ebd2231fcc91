"""Fixtures of the storage tests: a real S3-compatible server on 127.0.0.1 (moto) and the
AWS environment that points LanceDB at it."""

import uuid
from collections.abc import Iterator

import pytest

from benchmarks.s3local import moto_s3
from tests.helpers.s3 import BUCKET


@pytest.fixture(scope="module")
def s3_endpoint() -> Iterator[dict[str, str]]:
    """moto's S3 server on a free port of 127.0.0.1 with one bucket (benchmarks/s3local.py);
    its AWS_* variables; stopped afterwards."""
    with moto_s3(BUCKET) as env:
        yield env


@pytest.fixture
def aws_env(s3_endpoint: dict[str, str], monkeypatch: pytest.MonkeyPatch) -> dict[str, str]:
    """The standard AWS variables pointing at the local server (read by the store)."""
    keys = ("AWS_ENDPOINT_URL", "AWS_ACCESS_KEY_ID", "AWS_SECRET_ACCESS_KEY", "AWS_REGION")
    env = {key: s3_endpoint[key] for key in keys}
    for key, value in env.items():
        monkeypatch.setenv(key, value)
    return env


@pytest.fixture
def uri(aws_env: dict[str, str]) -> str:
    return f"s3://{BUCKET}/{uuid.uuid4().hex[:12]}"
