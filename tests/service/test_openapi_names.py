"""OpenAPI operation ids say what each call does (``search``, ``add_touch``, ``last``), tags
group them per resource, and a client generated from ``/openapi.json`` by
openapi-python-client has modules of those names that work against the app."""

from __future__ import annotations

import importlib
import json
import subprocess
import sys
from collections import Counter
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from tactus_memory.service.app import create_app
from tactus_memory.settings import Settings
from tests.helpers.service import make_memory

#: (method, path) -> (operation id, tag): what a user of a generated client calls
EXPECTED = {
    ("get", "/search"): ("search", "search"),
    ("post", "/search/like"): ("search_like", "search"),
    ("post", "/sessions/{session}/text"): ("add_text", "items"),
    ("post", "/sessions/{session}/vectors"): ("add_vectors", "items"),
    ("post", "/sessions/{session}/touch"): ("add_touch", "touch"),
    ("get", "/sessions"): ("list_sessions", "sessions"),
    ("get", "/sessions/{session}"): ("get_session", "sessions"),
    ("delete", "/sessions/{session}"): ("delete_session", "sessions"),
    ("get", "/senses"): ("list_senses", "senses"),
    ("post", "/senses"): ("add_sense", "senses"),
    ("get", "/last"): ("last", "temporal"),
    ("get", "/first"): ("first", "temporal"),
    ("get", "/count"): ("count", "temporal"),
    ("get", "/before"): ("before", "temporal"),
    ("get", "/after"): ("after", "temporal"),
    ("get", "/moments"): ("moments", "temporal"),
    ("get", "/sessions/{session}/timeline"): ("timeline", "temporal"),
    ("put", "/sessions/{session}/clock"): ("set_clock", "temporal"),
    ("get", "/health"): ("health", "health"),
}


@pytest.fixture
def app_client(tmp_path):
    memory = make_memory(tmp_path / "mem")
    with TestClient(create_app(Settings(), memory=memory)) as c:
        yield c


def operations(doc: dict) -> dict[tuple[str, str], dict]:
    return {(m, p): op for p, item in doc["paths"].items() for m, op in item.items()}


def test_operation_ids_are_named_after_what_they_do(app_client) -> None:
    ops = operations(app_client.get("/openapi.json").json())
    for key, (op_id, tag) in EXPECTED.items():
        assert ops[key]["operationId"] == op_id, key
        assert ops[key]["tags"] == [tag], key
    ids = Counter(op["operationId"] for op in ops.values())
    assert [i for i, n in ids.items() if n > 1] == []  # unique across the document
    for op_id in ids:  # never the path or the method glued on (FastAPI's default)
        assert "_get" not in op_id and "_post" not in op_id and "sessions_session" not in op_id
    assert all(len(op["tags"]) == 1 for op in ops.values())


def test_generated_client_has_readable_names_and_works(app_client, tmp_path) -> None:
    spec = tmp_path / "openapi.json"
    spec.write_text(json.dumps(app_client.get("/openapi.json").json()))
    out = tmp_path / "gen" / "tactus_api"
    tool = Path(sys.executable).parent / "openapi-python-client"
    run = subprocess.run(
        [str(tool), "generate", "--path", str(spec), "--meta", "none", "--output-path", str(out)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert run.returncode == 0, run.stdout + run.stderr
    modules = {f"{p.parent.name}/{p.stem}" for p in (out / "api").glob("*/*.py")}
    for op_id, tag in EXPECTED.values():
        assert f"{tag}/{op_id}" in modules
    assert not [m for m in modules if m.endswith(("_get", "_post", "_put", "_delete"))]

    sys.path.insert(0, str(out.parent))
    try:
        gen_client = importlib.import_module("tactus_api.client")
        add_text = importlib.import_module("tactus_api.api.items.add_text")
        text_in = importlib.import_module("tactus_api.models.text_in")
        search = importlib.import_module("tactus_api.api.search.search")
        client = gen_client.Client(base_url="http://testserver").set_httpx_client(app_client)
        stored = add_text.sync(
            session="kitchen", client=client, body=text_in.TextIn(text="the mug was hot", t=3.0)
        )
        assert stored.count == 1
        found = search.sync(client=client, q="the mug was hot", k=3)
        assert [h.id for h in found.hits][:1] == stored.ids
    finally:
        sys.path.remove(str(out.parent))
        for name in [n for n in sys.modules if n == "tactus_api" or n.startswith("tactus_api.")]:
            del sys.modules[name]
