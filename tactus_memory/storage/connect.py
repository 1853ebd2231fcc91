"""How a process connects to a store that others share: read consistency and object storage.

Replicas (several ``tactus serve`` processes, a ``tactus maintain``, scripts) on one store see
each other's commits through LanceDB's *read consistency interval*: a table handle checks for
a newer version at most this often, so a commit by another process is visible within about
that long (``TACTUS_READ_CONSISTENCY`` seconds, default 1; ``off`` never checks, as LanceDB
does by default; 0 checks on every read, one object-store request per read).

Object storage: ``s3://bucket/prefix`` takes its endpoint and credentials from the usual AWS
environment variables or from explicit ``storage_options`` (which win), mapped here to
LanceDB's option keys (``aws_endpoint``, ``aws_access_key_id``, ``aws_secret_access_key``,
``aws_session_token``, ``aws_region``, ``allow_http``). Concurrent writers need no lock
service: Lance commits a version with a conditional PUT (``If-None-Match``) and retries on
conflict, as on a local folder with an atomic rename.
"""

from __future__ import annotations

import os
from datetime import timedelta

from tactus_memory.errors import InvalidInputError
from tactus_memory.limits import DEFAULT_READ_CONSISTENCY_S

#: AWS environment variable -> LanceDB storage option (first variable set wins)
S3_ENV: dict[str, tuple[str, ...]] = {
    "aws_endpoint": ("AWS_ENDPOINT_URL_S3", "AWS_ENDPOINT_URL", "AWS_ENDPOINT"),
    "aws_access_key_id": ("AWS_ACCESS_KEY_ID",),
    "aws_secret_access_key": ("AWS_SECRET_ACCESS_KEY",),
    "aws_session_token": ("AWS_SESSION_TOKEN",),
    "aws_region": ("AWS_REGION", "AWS_DEFAULT_REGION"),
    "allow_http": ("AWS_ALLOW_HTTP",),
}


def read_consistency_interval(
    value: float | timedelta | None = DEFAULT_READ_CONSISTENCY_S,
) -> timedelta | None:
    """The interval to connect with: a timedelta/seconds as given, None for never. Storage
    reads no settings: the memory or the service passes what the operator configured."""
    if value is None or isinstance(value, timedelta):
        return value
    if isinstance(value, bool) or not isinstance(value, (int, float)) or value < 0:
        raise InvalidInputError(f"read consistency must be seconds >= 0 or None, got {value!r}")
    return timedelta(seconds=float(value))


def storage_options_for(uri: str, given: dict[str, str] | None = None) -> dict[str, str]:
    """LanceDB storage options for ``uri``: for ``s3://``, the AWS environment mapped to
    LanceDB's keys, then ``given`` on top. ``allow_http`` is set when the endpoint is
    ``http://`` (a local S3-compatible server). Other schemes: ``given`` only."""
    out: dict[str, str] = {}
    if uri.startswith(("s3://", "s3+ddb://")):
        for key, names in S3_ENV.items():
            for name in names:
                if os.environ.get(name):
                    out[key] = os.environ[name]
                    break
    out.update({str(k): str(v) for k, v in (given or {}).items()})
    endpoint = out.get("aws_endpoint") or out.get("endpoint") or ""
    if endpoint.startswith("http://") and "allow_http" not in out:
        out["allow_http"] = "true"
    return out


# --------------------------------------------------------------------------- locations
#: object-storage schemes a memory may live under
REMOTE_SCHEMES = ("s3://", "s3+ddb://", "gs://", "az://", "abfs://", "memory://")


def is_remote_uri(uri: str) -> bool:
    return uri.startswith(REMOTE_SCHEMES)


def normalise_uri(uri: str) -> str:
    """Local paths and ``file://`` URIs -> a local path; object-storage URIs pass through.

    Unknown ``scheme://`` prefixes are rejected (InvalidInputError).
    """
    if not isinstance(uri, str) or not uri.strip():
        raise InvalidInputError(f"memory location must be a non-empty string, got {uri!r}")
    if uri.startswith("file://"):
        return uri[len("file://") :]
    if "://" in uri:
        if is_remote_uri(uri) and len(uri.split("://", 1)[1].strip("/")) > 0:
            return uri
        raise InvalidInputError(
            f"unsupported memory location {uri!r}: use a local path, file://, s3://, gs:// or az://"
        )
    return uri
