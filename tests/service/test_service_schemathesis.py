"""The API against its own OpenAPI document: schemathesis (its CLI, every check, the examples,
coverage and stateful phases) drives a real uvicorn server on 127.0.0.1 (HashingSpace and a
stand-in touch sense, so it runs in CI time) and must report 0 failures: no 5xx, every status
documented, every response matching its schema, schema-valid requests accepted and
schema-violating ones rejected (ST201/ST202), ``Allow`` headers right (ST205).

The three cross-field rules JSON Schema cannot state are respected by the generated data
through tests/schemathesis_hooks.py; tests/schemathesis.toml lists 413 among the correct
rejections of a schema-violating request.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from benchmarks.serving import serve_app
from tactus_memory.service.app import create_app
from tactus_memory.settings import Settings
from tests.helpers.service import make_memory, window

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]
MAX_EXAMPLES = 10
PHASES = "examples,coverage,stateful"


@pytest.fixture
def server(tmp_path):
    memory = make_memory(tmp_path / "mem")
    app = create_app(Settings(max_body_bytes=256 * 1024), memory=memory)
    with TestClient(app) as client:  # some rows, so searches and session reads have data
        client.post("/sessions/s1/text", json={"text": "a red ball", "t": 1.0})
        client.post("/sessions/s1/touch", json={"frames": window(k=2).tolist(), "t": 2.0})
        client.post("/senses", json={"name": "motion", "dim": 64})
    with serve_app(app, probe="/ready") as base:
        yield base


def test_schemathesis_all_checks_examples_coverage_stateful_zero_failures(server, tmp_path):
    tmp_path = Path(os.environ.get("ST_LOG_DIR", tmp_path))
    cmd = [
        sys.executable,
        "-c",
        "import sys; from schemathesis.cli import schemathesis; sys.exit(schemathesis())",
        "--config-file",
        str(ROOT / "tests" / "schemathesis.toml"),
        "run",
        server + "/openapi.json",
        "--checks",
        "all",
        "--phases",
        PHASES,
        "--max-examples",
        str(MAX_EXAMPLES),
        "--seed",
        "1",
        "--workers",
        "1",
        # a liveness bound per request (schemathesis' default, 10 s, fails a correct answer
        # that a loaded CPU slows down; response times are the benchmarks' business)
        "--request-timeout",
        "120",
        "--report-dir",
        str(tmp_path / "report"),
    ]
    env = {**os.environ, "SCHEMATHESIS_HOOKS": "tests.schemathesis_hooks", "PYTHONPATH": str(ROOT)}
    done = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    out = done.stdout + done.stderr
    (tmp_path / "st.log").write_text(out)
    assert done.returncode == 0, out[-6000:]
    assert "No issues found" in out or " 0 failures" in out or "passed" in out, out[-3000:]
    assert "Stateful" in out and "Coverage" in out, out[-3000:]
