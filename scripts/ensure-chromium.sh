#!/usr/bin/env bash
# Debian's Chromium for the end-to-end browser tests (Playwright drives /usr/bin/chromium;
# `playwright install` downloads a browser build and is never used).
set -euo pipefail
if command -v chromium >/dev/null 2>&1 || [ -n "${TACTUS_CHROMIUM:-}" ]; then
  exit 0
fi
SUDO=""
[ "$(id -u)" -eq 0 ] || SUDO="sudo"
echo "installing Debian's chromium for the browser tests" >&2
$SUDO apt-get update -qq
DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq chromium >/dev/null
