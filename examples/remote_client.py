"""The Python API from another machine: `tactus_memory.Client` against a running server.

    python examples/remote_client.py     # beside `make run` (http://127.0.0.1:8000)
    python examples/remote_client.py --url http://127.0.0.1:9000 --timeout 60 --token TOKEN

Pass `token=` when the server has one (`tactus serve --token`, or a key). The names,
arguments and results are `Memory`'s.
"""

import argparse

import numpy as np

from tactus_memory import Client

ap = argparse.ArgumentParser(description="The Python API against a running server.")
ap.add_argument("--url", default="http://127.0.0.1:8000", help="the server (make run's port)")
ap.add_argument("--token", default=None, help="the server's token or a key, if it has one")
ap.add_argument("--timeout", type=float, default=60.0, help="seconds to wait for an answer")
opts = ap.parse_args()

rest = np.full((32, 32), 512, np.int16)  # one raw glove frame, the hand at rest...
frame = rest.copy()
frame[10:22, 8:20] = 640  # ...and a palm pressing
windows = np.stack([np.stack([frame] * 8)] * 3)  # (B, K, 32, 32): three 8-frame windows
times = [20.0, 21.0, 22.0]
frames = [frame] * 16  # a glove's stream: two windows of 8 frames

with Client(opts.url, token=opts.token, timeout=opts.timeout) as memory:
    memory.add("desk", "text", "put the mug on the shelf", t=12.0)
    memory.add_many("desk", "touch", windows, t=times)  # (B, K, 32, 32) raw: one commit
    hits = memory.search("holding a mug", k=5, session="desk")  # list[Hit]
    print([(h.sense, h.t, h.match) for h in hits])
    print(memory.last("put the mug on the shelf", session="desk"))  # Moment | None
    with memory.stream_touch("desk", hz=30, t0=30.0) as glove:  # the WebSocket stream
        for f in frames:  # (32, 32) raw sensor units
            glove.send(f)
    print(glove.ids, glove.errors)  # every full window answered before the block ends
