#!/usr/bin/env bash
# Foxglove's published JSON schemas (npm package @foxglove/schemas, MIT, generated from the
# foxglove-sdk schema definitions) into .deps/foxglove-schemas/<version>/, one file per message
# type (foxglove.SceneUpdate.json, ...). The recorder tests validate every foxglove.* message of
# a recording against them (tests/python/mcap_check.py).
#
# Idempotent: when the folder is there (a stamp records the tarball's hash) nothing is fetched.
# Usage: ./scripts/setup-foxglove-schemas.sh
# Needs Node.js and npm (Debian: apt-get install nodejs npm); fetches only from the npm registry.
set -euo pipefail
cd "$(dirname "$0")/.."

VERSION=2.1.0
# sha256 of foxglove-schemas-2.1.0.tgz as the registry serves it (npm also checks its integrity).
SHA256=c6d2746e10bbb451a680307b6e5ec3b186de3263df2a41869a7757b3042fcbf0
DEST=".deps/foxglove-schemas/$VERSION"
stamp="$DEST/.sha256"

if [[ -f "$stamp" && "$(cat "$stamp")" == "$SHA256" ]]; then
  echo "setup-foxglove-schemas.sh: $DEST is current"
  exit 0
fi
for tool in node npm; do
  if ! command -v "$tool" >/dev/null 2>&1; then
    echo "setup-foxglove-schemas.sh: $tool not found (Debian: apt-get install nodejs npm)" >&2
    exit 2
  fi
done

work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
(cd "$work" && npm pack --silent "@foxglove/schemas@$VERSION" >/dev/null)
tarball="$work/foxglove-schemas-$VERSION.tgz"
got="$(sha256sum "$tarball" | cut -d' ' -f1)"
if [[ "$got" != "$SHA256" ]]; then
  echo "setup-foxglove-schemas.sh: @foxglove/schemas@$VERSION has sha256 $got, expected $SHA256" >&2
  exit 2
fi
tar -xzf "$tarball" -C "$work"

rm -rf "$DEST"
mkdir -p "$DEST"
# dist/jsonschema/index.js exports one JSON schema object per message type, titled by its name.
node -e '
const fs = require("fs");
const path = require("path");
const [pkg, dest] = process.argv.slice(1);
const schemas = require(path.resolve(pkg, "dist/jsonschema/index.js"));
let n = 0;
for (const schema of Object.values(schemas)) {
  if (!schema || typeof schema.title !== "string" || !schema.title.startsWith("foxglove.")) continue;
  fs.writeFileSync(path.join(dest, schema.title + ".json"), JSON.stringify(schema, null, 1) + "\n");
  n++;
}
if (n < 20) { console.error("only " + n + " schemas in " + pkg); process.exit(1); }
console.log("setup-foxglove-schemas.sh: " + n + " schemas in " + dest);
' "$work/package" "$DEST"
cp "$work/package/package.json" "$DEST/package.json"
echo "$SHA256" >"$stamp"
