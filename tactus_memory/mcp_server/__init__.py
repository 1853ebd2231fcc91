"""The memory for agents: a Model Context Protocol server (``tactus mcp``).

:mod:`~tactus_memory.mcp_server.server` builds the server and its tools,
:mod:`~tactus_memory.mcp_server.results` the compact results they answer with. Needs the
``mcp`` extra (``pip install 'tactus-memory[mcp]'``).
"""
