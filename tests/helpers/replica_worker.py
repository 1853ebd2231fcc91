"""A writer process for the replica and S3 tests: ``python -m tests.helpers.replica_worker DATA
PREFIX N``.

Opens the memory at DATA (a folder or s3:// URI, storage options from the AWS environment)
with the fake hashing space, without maintenance (a replica), then adds N text rows one
commit each (plain appends; the text names PREFIX and i), printing each returned id once
its commit returned (the acknowledgement). ``--maintain`` makes it the maintainer instead;
``--delay`` sleeps between writes (so a test can kill it mid-stream).
"""

from __future__ import annotations

import argparse
import time

from tactus_memory.memory.main import Memory
from tactus_memory.policies import MaintenanceConfig
from tactus_memory.storage.tables import IndexConfig
from tests.helpers.fakes import HashingSpace


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("data")
    ap.add_argument("prefix")
    ap.add_argument("n", type=int)
    ap.add_argument("--maintain", action="store_true")
    ap.add_argument("--delay", type=float, default=0.0)
    args = ap.parse_args()
    mem = Memory.open(
        args.data,
        HashingSpace(),
        maintenance=MaintenanceConfig(maintain=args.maintain, retain_seconds=5.0),
        index=IndexConfig(compact_every=8),
    )
    print("ready", flush=True)
    for i in range(args.n):
        item_id = mem.add("fleet", "text", f"note {i} from {args.prefix} about the red mug")
        print(item_id, flush=True)
        if args.delay:
            time.sleep(args.delay)
    mem.close()


if __name__ == "__main__":
    main()
