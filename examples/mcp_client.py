"""An agent's view of the memory: the MCP SDK's own client starts `tactus mcp` over stdio on
the store `make run` serves (or joins a `tactus mcp --http` server at --url) and calls a few
tools, places and grasps included.

    python examples/mcp_client.py    # from the checkout, after the places guide's example
    python examples/mcp_client.py --data DIR --timeout 60 --read-timeout 10
    python examples/mcp_client.py --url http://127.0.0.1:8001/mcp --token TOKEN

`tactus mcp` answers at once and loads its models behind: a tool that needs one answers
"loading: ..." until they are in, and this client asks again until --timeout. Each request
must be answered within --read-timeout (30 s, the MCP Inspector's limit per request).
"""

import argparse
import json
import time

import anyio
from mcp import Client, StdioServerParameters

#: what an agent asks: (tool, arguments); the places guide made session "yard" (a drill
#: picked up at x = 6 m), Getting started the recording "run1" (a mug held 0-3 s)
QUESTIONS = [
    ("where", {"query": "picked up the drill", "session": "yard"}),
    ("search", {"query": "picked up the drill", "near": [6.0, 0.0, 0.0, 1.0], "k": 3}),
    ("at", {"x": 6.0, "y": 0.0, "z": 0.0, "r": 0.5, "session": "yard"}),
    ("count", {"query": "holding a mug", "session": "run1", "group": "grasp"}),
]


def arguments() -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", default="./memory", help="the store `tactus mcp` opens (stdio)")
    ap.add_argument("--command", default="tactus", help="the `tactus` to start (stdio)")
    ap.add_argument("--url", default=None, help="a `tactus mcp --http` server's /mcp URL")
    ap.add_argument("--token", default=None, help="with --url: the server's bearer token")
    ap.add_argument(
        "--timeout", type=float, default=120.0, help="seconds to ask again while models load"
    )
    ap.add_argument("--read-timeout", type=float, default=30.0, help="seconds one request may take")
    return ap.parse_args()


async def ask(agent: Client, name: str, args: dict, deadline: float):
    """One tool call; asked again while the server says its models are loading."""
    while True:
        answer = await agent.call_tool(name, args)
        text = answer.content[0].text
        if not (answer.is_error and "loading:" in text) or time.monotonic() > deadline:
            return answer
        await anyio.sleep(1.0)


async def main(opts: argparse.Namespace) -> None:
    if opts.url and opts.token:  # the SDK's HTTP client (httpx2), with the bearer token
        import httpx2
        from mcp.client.streamable_http import streamable_http_client

        auth = {"Authorization": f"Bearer {opts.token}"}
        http = httpx2.AsyncClient(headers=auth, timeout=opts.read_timeout)
        server = streamable_http_client(opts.url, http_client=http)
    elif opts.url:
        server = opts.url
    else:
        server = StdioServerParameters(command=opts.command, args=["mcp", "--data", opts.data])
    deadline = time.monotonic() + opts.timeout
    async with Client(server, read_timeout_seconds=opts.read_timeout) as agent:
        print("tools:", ", ".join(tool.name for tool in (await agent.list_tools()).tools))
        for name, args in QUESTIONS:
            answer = await ask(agent, name, args, deadline)
            assert not answer.is_error, answer.content[0].text
            print(name, json.dumps(json.loads(answer.content[0].text))[:300])


anyio.run(main, arguments())
