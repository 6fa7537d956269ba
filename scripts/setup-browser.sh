#!/usr/bin/env bash
# What the live view's browser test needs (tests/tests/it/live_view.rs): Debian's chromium, and
# Foxglove Studio's app code with the headless driver from npm (tests/browser/package.json and
# its lock: @foxglove/studio-base 1.48.0, react 17, puppeteer-core, pngjs) in .deps/browser/.
#
# Idempotent: chromium is installed only when missing (apt-get, as root), the npm packages only
# when the lock file changed (a stamp records its hash). Nothing is fetched at run time: the test
# serves the app from .deps/browser on loopback.
# Usage: ./scripts/setup-browser.sh
# Needs Node.js and npm (Debian: apt-get install nodejs npm); fetches only from the Debian mirrors
# and the npm registry.
set -euo pipefail
cd "$(dirname "$0")/.."

if ! command -v chromium >/dev/null 2>&1; then
  if [[ "$(id -u)" == 0 ]] && command -v apt-get >/dev/null 2>&1; then
    echo "setup-browser.sh: installing chromium (apt-get install chromium)"
    apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null
  else
    echo "setup-browser.sh: chromium not found: install it (Debian: sudo apt-get install chromium)" >&2
    exit 2
  fi
fi
for tool in node npm; do
  if ! command -v "$tool" >/dev/null 2>&1; then
    echo "setup-browser.sh: $tool not found (Debian: apt-get install nodejs npm)" >&2
    exit 2
  fi
done

DEST=.deps/browser
want="$(sha256sum tests/browser/package-lock.json | cut -d' ' -f1)"
stamp="$DEST/.lock-sha256"
if [[ -f "$stamp" && "$(cat "$stamp")" == "$want" && -d "$DEST/node_modules/@foxglove/studio-base" ]]; then
  echo "setup-browser.sh: $DEST is current ($(chromium --version 2>/dev/null | head -n 1))"
  exit 0
fi
mkdir -p "$DEST"
rm -f "$stamp"
cp tests/browser/package.json tests/browser/package-lock.json "$DEST/"
(cd "$DEST" && npm ci --no-audit --no-fund --loglevel=error)
echo "$want" >"$stamp"
echo "setup-browser.sh: $DEST installed ($(chromium --version 2>/dev/null | head -n 1))"
