"""MCP answers as HTTP does (issue 38), driven by the MCP SDK's own client: an unknown
session is a tool error (not ``found: false`` or a count of 0), every scored item carries
``match`` and ``bar``, and ``tactus mcp --http`` loads the models before its port answers."""

from __future__ import annotations

import json
from typing import Any

import anyio
import pytest
from mcp import Client

from tactus_memory.mcp.server import build_server
from tests.helpers.mcp import fill
from tests.helpers.service import make_memory

#: every tool that takes a session, called on one that does not exist
UNKNOWN = [
    ("search", {"query": "mug", "session": "nowhere"}),
    ("last", {"query": "mug", "session": "nowhere"}),
    ("first", {"query": "mug", "session": "nowhere"}),
    ("count", {"query": "mug", "session": "nowhere"}),
    ("before", {"anchor": "mug", "session": "nowhere"}),
    ("after", {"anchor": "mug", "session": "nowhere"}),
    ("timeline", {"session": "nowhere"}),
]


def scored(answer: dict[str, Any]) -> list[dict[str, Any]]:
    """Every item of a tool's answer that has a score."""
    items = list(answer.get("hits", []))
    items += [answer["anchor"]] if answer.get("anchor") else []
    moments = answer.get("occurrences", []) + ([answer["moment"]] if "moment" in answer else [])
    items += [i for m in moments for i in m["items"]]
    return [i for i in items if i.get("score") is not None]


def test_unknown_sessions_are_tool_errors_and_hits_carry_match_and_bar(tmp_path) -> None:
    memory = make_memory(tmp_path / "mem")
    fill(memory)

    async def main() -> dict[str, Any]:
        answers = {}
        async with Client(build_server(memory)) as client:
            for name, args in UNKNOWN:
                r = await client.call_tool(name, args)
                assert r.is_error, (name, r.content)
                assert "no session 'nowhere'" in r.content[0].text, r.content[0].text
            calls = {
                "search": {"query": "put the mug on the shelf", "k": 5},
                "search_touch": {"query": "mug", "senses": ["touch"]},
                "last": {"query": "put the mug on the shelf", "session": "kitchen"},
                "count": {"query": "wiped the table", "session": "kitchen"},
                "before": {"anchor": "wiped the table", "window": 15.0},
            }
            for name, args in calls.items():
                r = await client.call_tool(name.split("_")[0], args)
                assert not r.is_error, (name, r.content)
                answers[name] = json.loads(r.content[0].text)
        return answers

    answers = anyio.run(main)
    for name, answer in answers.items():
        items = scored(answer)
        assert items, name
        for item in items:
            assert isinstance(item["match"], bool) and isinstance(item["bar"], float), item
            assert item["match"] == (item["score"] >= item["bar"]), item
    top = answers["search"]["hits"][0]
    assert top["text"] == "put the mug on the shelf" and top["match"] is True
    assert answers["search_touch"]["hits"][0]["grasp_windows"] == 1
    # the same session known: an answer, not an error (found or not)
    assert answers["last"]["found"] is True and answers["count"]["count"] == 1


@pytest.mark.parametrize("filled", [True, False])
def test_http_loads_the_models_before_the_port_answers(tmp_path, monkeypatch, filled) -> None:
    import uvicorn

    from tactus_memory.service.mcp_http import run_mcp_http
    from tactus_memory.settings import Settings

    memory = make_memory(tmp_path / "mem")
    if filled:
        fill(memory)
    events: list[str] = []
    encode = memory.space.embed_texts

    def spy_encode(texts: Any, **kw: Any) -> Any:
        events.append("encode")
        return encode(texts, **kw)

    monkeypatch.setattr(memory.space, "embed_texts", spy_encode)
    monkeypatch.setattr(uvicorn, "run", lambda *a, **kw: events.append("listen"))
    said: list[str] = []
    settings = Settings(data=str(tmp_path / "mem"), port=8001)
    run_mcp_http(memory, settings, False, said.append, build_server)
    assert events[-1] == "listen" and "encode" in events[:-1], events
    assert said[0].startswith("tactus mcp: loading the models"), said
