"""The memory for agents: a Model Context Protocol server (``tactus mcp``).

:mod:`~tactus_memory.mcp.server` builds the server and its tools,
:mod:`~tactus_memory.mcp.hits` the compact results they answer with. Needs the
``mcp`` extra (``pip install 'tactus-memory[mcp]'``).
"""
