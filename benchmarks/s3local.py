"""A local S3-compatible server for benchmarks: moto's standalone server on a free port of
127.0.0.1 (a real HTTP S3 API, conditional PUT included; no Docker) with one bucket, and the
standard AWS environment variables that point a store (``tactus_memory.storage.connect``) at it."""

from __future__ import annotations

import logging
from collections.abc import Iterator
from contextlib import contextmanager

ACCESS_KEY = "test-key"
SECRET_KEY = "test-secret"
REGION = "us-east-1"


@contextmanager
def moto_s3(bucket: str) -> Iterator[dict[str, str]]:
    """Start moto's S3 server, create ``bucket``; yield the AWS_* variables for it; stop."""
    import boto3
    from moto.server import ThreadedMotoServer

    logging.getLogger("werkzeug").setLevel(logging.ERROR)  # one log line per request
    server = ThreadedMotoServer(ip_address="127.0.0.1", port=0, verbose=False)
    server.start()
    try:
        host, port = server.get_host_and_port()
        env = {
            "AWS_ENDPOINT_URL": f"http://{host}:{port}",
            "AWS_ACCESS_KEY_ID": ACCESS_KEY,
            "AWS_SECRET_ACCESS_KEY": SECRET_KEY,
            "AWS_REGION": REGION,
            "AWS_ALLOW_HTTP": "true",
        }
        boto3.client(
            "s3",
            endpoint_url=env["AWS_ENDPOINT_URL"],
            aws_access_key_id=ACCESS_KEY,
            aws_secret_access_key=SECRET_KEY,
            region_name=REGION,
        ).create_bucket(Bucket=bucket)
        yield env
    finally:
        server.stop()


def storage_options(env: dict[str, str]) -> dict[str, str]:
    """LanceDB storage options for a reader in this process (same server as ``env``)."""
    return {
        "aws_endpoint": env["AWS_ENDPOINT_URL"],
        "aws_access_key_id": env["AWS_ACCESS_KEY_ID"],
        "aws_secret_access_key": env["AWS_SECRET_ACCESS_KEY"],
        "aws_region": env["AWS_REGION"],
        "allow_http": "true",
    }
