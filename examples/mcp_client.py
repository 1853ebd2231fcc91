"""An agent's view of the memory: the MCP SDK's own client starts `tactus mcp` over stdio on
the store `make run` serves and calls a few tools, places and grasps included.

    python examples/mcp_client.py    # from the checkout, after the places guide's example
"""

import json

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


async def main() -> None:
    server = StdioServerParameters(command="tactus", args=["mcp", "--data", "./memory"])
    async with Client(server, read_timeout_seconds=120) as agent:
        print("tools:", ", ".join(tool.name for tool in (await agent.list_tools()).tools))
        for name, args in QUESTIONS:
            answer = await agent.call_tool(name, args)
            assert not answer.is_error, answer.content[0].text
            print(name, json.dumps(json.loads(answer.content[0].text))[:300])


anyio.run(main)
