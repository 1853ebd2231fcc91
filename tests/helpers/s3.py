"""Constants of the object-storage tests (their fixtures: tests/storage/conftest.py)."""

#: seconds a replica waits to see another's writes (on s3://, slower than a local store)
WAIT_S = 60.0  # a liveness bound: visibility itself is measured by benchmarks/fleet.py
#: the bucket the local S3 server (moto) serves the tests from
BUCKET = "tactus-test"
