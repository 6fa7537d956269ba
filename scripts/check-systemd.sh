#!/usr/bin/env bash
# Checks the units systemd/op3dsgd.service and systemd/op3dsg-detectd.service the way CI does,
# without a running systemd:
#   1. `systemd-analyze verify`: syntax, directives, and that ExecStart's binary exists. A unit
#      names the installed path (/usr/bin/op3dsgd), which a build machine does not have, so the
#      check verifies a copy whose ExecStart points at the binary just built, found beside the
#      given op3dsgd (every other line unchanged). A warning is a failure.
#   2. `systemd-analyze security --offline=true`: the exposure score must be <= 3.0.
# Usage: scripts/check-systemd.sh [path/to/op3dsgd]   (default: target/debug/op3dsgd)
# Needs systemd-analyze (Debian: the `systemd` package); installs it with apt-get when run as root.
set -euo pipefail
cd "$(dirname "$0")/.."

# OP3DSG_UNIT: check that unit file alone, with the given binary (to test this script itself).
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
bin_dir="$(cd "$(dirname "$binary")" && pwd)"

# check UNIT BINARY: verify and score one unit whose ExecStart is /usr/bin/<name of BINARY>.
check() {
  local unit="$1" binary="$2" name work verify_out security_out exposure
  name="$(basename "$unit")"
  if [ ! -x "$binary" ]; then
    echo "check-systemd: $binary not built (cargo build -p op3dsgd --bins)" >&2
    exit 1
  fi
  grep -q "^ExecStart=/usr/bin/$(basename "$binary") " "$unit" || {
    echo "check-systemd: $unit: ExecStart no longer starts with /usr/bin/$(basename "$binary"); update this script" >&2
    exit 1
  }
  work="$(mktemp -d)"
  sed "s#^ExecStart=/usr/bin/$(basename "$binary") #ExecStart=${binary} #" "$unit" >"$work/$name"

  echo "== systemd-analyze verify $unit (ExecStart=$binary) =="
  verify_out="$(systemd-analyze verify "$work/$name" 2>&1)" || {
    echo "$verify_out" >&2
    echo "check-systemd: systemd-analyze verify failed on $unit" >&2
    rm -rf "$work"
    exit 1
  }
  if [ -n "$verify_out" ]; then
    echo "$verify_out" >&2
    echo "check-systemd: systemd-analyze verify printed warnings on $unit" >&2
    rm -rf "$work"
    exit 1
  fi
  echo "clean"

  echo "== systemd-analyze security --offline=true $unit =="
  security_out="$(systemd-analyze security --offline=true "$work/$name" 2>&1)" || true
  rm -rf "$work"
  exposure="$(printf '%s\n' "$security_out" | sed -n "s/.*Overall exposure level for $name: \([0-9.]*\).*/\1/p")"
  if [ -z "$exposure" ]; then
    echo "$security_out" >&2
    echo "check-systemd: no exposure level in systemd-analyze security's output for $unit" >&2
    exit 1
  fi
  printf '%s\n' "$security_out" | grep -v '^✓' || true
  if awk -v e="$exposure" -v m="$max_exposure" 'BEGIN { exit !(e > m) }'; then
    echo "check-systemd: $unit: exposure $exposure exceeds $max_exposure" >&2
    exit 1
  fi
  echo "$unit: exposure $exposure <= $max_exposure: ok"
}

if [ -n "${OP3DSG_UNIT:-}" ]; then
  check "$OP3DSG_UNIT" "$bin_dir/$(basename "$binary")"
else
  check systemd/op3dsgd.service "$bin_dir/op3dsgd"
  check systemd/op3dsg-detectd.service "$bin_dir/op3dsg-detectd"
fi
