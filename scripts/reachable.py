"""Exit 0 when an HTTP(S) URL answers within a few seconds, else 1 (used by the Makefile to
pick PyTorch's CPU index only where it can be reached). Standard library only: it runs
before anything is installed."""

from __future__ import annotations

import sys
import urllib.request

TIMEOUT_S = 5.0


def main(url: str) -> int:
    try:
        with urllib.request.urlopen(url, timeout=TIMEOUT_S) as response:  # noqa: S310
            return 0 if response.status < 400 else 1
    except Exception:  # noqa: BLE001  (unreachable, refused, TLS, timeout: all mean "no")
        return 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))
