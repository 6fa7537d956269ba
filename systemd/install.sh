#!/usr/bin/env bash
# Installs op3dsg on the robot's computer as a system service:
#   /usr/bin/op3dsgd, /usr/bin/op3dsg                   the daemon and the CLI (release build)
#   /lib/systemd/system/op3dsgd.service                 the unit (systemd/op3dsgd.service)
#   /usr/share/op3dsg/profiles/                         the profiles and the knowledge base
#   /usr/share/doc/op3dsg/                              README.md, systemd/README.md
#   /etc/op3dsg/op3dsgd.toml                            the robot's profile (kept if present)
#   /etc/op3dsg/credentials/llm-api-key                 empty, root only (kept if present)
#   system user and group `op3dsg`                      (no login, no home; the unit adds video, plugdev)
# /var/lib/op3dsg (snapshots) and /var/log/op3dsg (MCAP) are made by systemd from the unit.
#
# Usage: sudo systemd/install.sh [--bin-dir target/release] [--destdir DIR]
#   --bin-dir  where the built binaries are (default target/release: cargo build --release -p op3dsgd)
#   --destdir  stage everything under DIR instead of / (no user, no systemctl; for packaging and tests)
# Updating: build, run this again (binaries, unit and shared files are replaced, /etc and
# /var/lib are kept), then `sudo systemctl restart op3dsgd`. The map snapshot survives.
set -euo pipefail
cd "$(dirname "$0")/.."

bin_dir=target/release
destdir=""
while [ $# -gt 0 ]; do
  case "$1" in
    --bin-dir) bin_dir="$2"; shift 2 ;;
    --destdir) destdir="$2"; shift 2 ;;
    -h|--help) sed -n '2,20p' "$0"; exit 0 ;;
    *) echo "install.sh: unknown argument '$1' (see --help)" >&2; exit 2 ;;
  esac
done

for b in op3dsgd op3dsg; do
  if [ ! -x "$bin_dir/$b" ]; then
    echo "install.sh: $bin_dir/$b not built; run: cargo build --release -p op3dsgd" >&2
    exit 1
  fi
done
if [ -z "$destdir" ] && [ "$(id -u)" != 0 ]; then
  echo "install.sh: run as root (sudo), or stage with --destdir DIR" >&2
  exit 1
fi

root="${destdir%/}"
install -d "$root/usr/bin" "$root/lib/systemd/system" "$root/usr/share/op3dsg" "$root/usr/share/doc/op3dsg" \
  "$root/etc/op3dsg" "$root/etc/op3dsg/credentials"
install -m 0755 "$bin_dir/op3dsgd" "$bin_dir/op3dsg" "$root/usr/bin/"
install -m 0644 systemd/op3dsgd.service "$root/lib/systemd/system/op3dsgd.service"
rm -rf "$root/usr/share/op3dsg/profiles"
cp -r profiles "$root/usr/share/op3dsg/profiles"
install -m 0644 README.md "$root/usr/share/doc/op3dsg/README.md"
install -m 0644 systemd/README.md "$root/usr/share/doc/op3dsg/systemd.md"

profile="$root/etc/op3dsg/op3dsgd.toml"
if [ ! -e "$profile" ]; then
  cat >"$profile" <<'PROFILE'
# The robot's op3dsgd profile, layered over the built-in base (every key is documented in
# /usr/share/op3dsg/profiles/base.toml). `op3dsgd --profile /etc/op3dsg/op3dsgd.toml
# --print-config` shows the result. After a change: sudo systemctl restart op3dsgd.
#
# Until the camera source is configured here, the daemon runs the built-in synthetic kitchen.

[snapshot]
# dir = ""          # "": /var/lib/op3dsg/snapshots (systemd's StateDirectory)
period_s = 30.0

# [reasoner]
# kind = "llm"      # the key goes on the first line of /etc/op3dsg/credentials/llm-api-key
PROFILE
  chmod 0644 "$profile"
  echo "installed $profile (edit it for the robot)"
else
  echo "kept $profile"
fi
key="$root/etc/op3dsg/credentials/llm-api-key"
if [ ! -e "$key" ]; then
  install -m 0600 /dev/null "$key"
fi
chmod 0700 "$root/etc/op3dsg/credentials"

if [ -n "$destdir" ]; then
  echo "staged under $destdir (no user created, systemd not told)"
  exit 0
fi

getent group plugdev >/dev/null || groupadd --system plugdev
getent group video >/dev/null || groupadd --system video
if ! getent passwd op3dsg >/dev/null; then
  useradd --system --user-group --no-create-home --home-dir /var/lib/op3dsg --shell /usr/sbin/nologin \
    --comment "op3dsg scene-graph daemon" op3dsg
  echo "created system user op3dsg"
fi
systemctl daemon-reload
echo "installed. Start it now and at every boot:   sudo systemctl enable --now op3dsgd"
echo "logs: journalctl -u op3dsgd -f    map: op3dsg map info    graph: op3dsg watch"
