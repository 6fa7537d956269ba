#!/usr/bin/env bash
# Checks systemd/op3dsgd.service the way CI does, without a running systemd:
#   1. `systemd-analyze verify`: syntax, directives, and that ExecStart's binary exists. The unit
#      names the installed path (/usr/bin/op3dsgd), which a build machine does not have, so the
#      check verifies a copy whose ExecStart points at the binary just built (every other line
#      unchanged). A warning is a failure.
#   2. `systemd-analyze security --offline=true`: the exposure score must be <= 3.0.
# Usage: scripts/check-systemd.sh [path/to/op3dsgd]   (default: target/debug/op3dsgd)
# Needs systemd-analyze (Debian: the `systemd` package); installs it with apt-get when run as root.
set -euo pipefail
cd "$(dirname "$0")/.."

# OP3DSG_UNIT: check another unit file instead (to test this script itself).
unit="${OP3DSG_UNIT:-systemd/op3dsgd.service}"
binary="${1:-target/debug/op3dsgd}"
max_exposure=3.0

if ! command -v systemd-analyze >/dev/null 2>&1; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
    echo "check-systemd: installing systemd-analyze (apt-get install systemd)"
    apt-get install -y --no-install-recommends systemd >/dev/null
  else
    echo "check-systemd: systemd-analyze not found; install Debian's 'systemd' package" >&2
    exit 1
  fi
fi
if [ ! -x "$binary" ]; then
  echo "check-systemd: $binary not built (cargo build -p op3dsgd --bin op3dsgd)" >&2
  exit 1
fi
grep -q '^ExecStart=/usr/bin/op3dsgd ' "$unit" || {
  echo "check-systemd: $unit: ExecStart no longer starts with /usr/bin/op3dsgd; update this script" >&2
  exit 1
}

work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
abs_binary="$(cd "$(dirname "$binary")" && pwd)/$(basename "$binary")"
sed "s#^ExecStart=/usr/bin/op3dsgd #ExecStart=${abs_binary} #" "$unit" >"$work/op3dsgd.service"

echo "== systemd-analyze verify $unit (ExecStart=$abs_binary) =="
verify_out="$(systemd-analyze verify "$work/op3dsgd.service" 2>&1)" || {
  echo "$verify_out" >&2
  echo "check-systemd: systemd-analyze verify failed" >&2
  exit 1
}
if [ -n "$verify_out" ]; then
  echo "$verify_out" >&2
  echo "check-systemd: systemd-analyze verify printed warnings" >&2
  exit 1
fi
echo "clean"

echo "== systemd-analyze security --offline=true $unit =="
security_out="$(systemd-analyze security --offline=true "$work/op3dsgd.service" 2>&1)" || true
exposure="$(printf '%s\n' "$security_out" | sed -n 's/.*Overall exposure level for op3dsgd.service: \([0-9.]*\).*/\1/p')"
if [ -z "$exposure" ]; then
  echo "$security_out" >&2
  echo "check-systemd: no exposure level in systemd-analyze security's output" >&2
  exit 1
fi
printf '%s\n' "$security_out" | grep -v '^✓' || true
if awk -v e="$exposure" -v m="$max_exposure" 'BEGIN { exit !(e > m) }'; then
  echo "check-systemd: exposure $exposure exceeds $max_exposure" >&2
  exit 1
fi
echo "exposure $exposure <= $max_exposure: ok"
