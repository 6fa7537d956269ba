#!/usr/bin/env bash
# Builds op3dsg with the camera and installs it as a system service, into the same paths as the
# Debian package (for distributions without dpkg; on Debian/Ubuntu prefer `cargo deb -p op3dsgd`):
#   /usr/bin/op3dsgd, /usr/bin/op3dsg                   the daemon and the CLI (release, --features robot: the camera and Zenoh)
#   /usr/bin/op3dsg-detectd                             the detection worker for a GPU computer
#   /usr/sbin/op3dsg-service-user                       chooses the user the service runs as
#   /lib/systemd/system/op3dsgd.service                 the unit (systemd/op3dsgd.service)
#   /lib/systemd/system/op3dsg-detectd.service          the worker's unit (not enabled)
#   /usr/share/op3dsg/profiles/                         the profiles and the knowledge base
#   /usr/lib/op3dsg/onnxruntime/, minilm/, clip/        ONNX Runtime and the models (from .models/)
#   /usr/lib/op3dsg/librealsense2.so.2.56               librealsense, when the build used .deps/realsense
#   /usr/share/doc/op3dsg/                              README.md, systemd.md, robot.md
#   /etc/op3dsg/op3dsgd.toml                            the robot's profile (never overwritten)
#   /etc/op3dsg/op3dsg-detectd.toml                     the worker's profile (never overwritten)
#   /etc/op3dsg/credentials/llm-api-key                 empty, root only (kept if present)
#   system user and group `op3dsg`                      (no login, no home; in video and plugdev)
# /var/lib/op3dsg (snapshots) and /var/log/op3dsg (recordings) are made by systemd from the unit.
#
# Usage: systemd/install.sh [--service-user USER] [--bin-dir DIR] [--no-build] [--destdir DIR]
#   As yourself it builds (cargo build --release -p op3dsgd --features robot, after
#   ./scripts/setup-models.sh), then installs through sudo. As root it installs what is built.
#   --service-user USER  run the service as USER (the robot's login user, e.g. hello-robot, so its
#                        planners can attach): op3dsg-service-user USER after the install
#   --bin-dir DIR        take the binaries from DIR (default target/release); implies --no-build
#   --no-build           do not build; the binaries must have the feature realsense
#   --destdir DIR        stage everything under DIR instead of / (no sudo, no systemctl; the user
#                        is created only when DIR/etc/passwd exists and this runs as root)
# Updating: run it again (binaries, unit, libraries and shared files are replaced, /etc and
# /var/lib are kept), then `sudo systemctl restart op3dsgd`. The map snapshot survives.
set -euo pipefail
cd "$(dirname "$0")/.."

bin_dir=target/release
build=1
destdir=""
service_user=""
args=("$@")
while [ $# -gt 0 ]; do
  case "$1" in
    --bin-dir) bin_dir="${2:?--bin-dir needs a folder}"; build=0; shift 2 ;;
    --no-build) build=0; shift ;;
    --destdir) destdir="${2:?--destdir needs a folder}"; shift 2 ;;
    --service-user) service_user="${2:?--service-user needs a user name}"; shift 2 ;;
    -h|--help) sed -n '2,29p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
    *) echo "install.sh: unknown argument '$1' (see --help)" >&2; exit 2 ;;
  esac
done

rs_lib="$PWD/.deps/realsense/lib"
if [ "$(id -u)" = 0 ]; then
  build=0
elif [ "$build" = 1 ]; then
  ./scripts/setup-models.sh
  if [ -d "$rs_lib/pkgconfig" ]; then
    export PKG_CONFIG_PATH="$rs_lib/pkgconfig${PKG_CONFIG_PATH:+:$PKG_CONFIG_PATH}"
  fi
  cargo build --release --locked -p op3dsgd --features robot
fi

for b in op3dsgd op3dsg op3dsg-detectd; do
  if [ ! -x "$bin_dir/$b" ]; then
    echo "install.sh: $bin_dir/$b not built; run systemd/install.sh as yourself (it builds), or:" >&2
    echo "  cargo build --release -p op3dsgd --features robot" >&2
    exit 1
  fi
done
version="$(LD_LIBRARY_PATH="$rs_lib${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}" "$bin_dir/op3dsgd" --version)" || {
  echo "install.sh: $bin_dir/op3dsgd --version failed (librealsense not found?)" >&2
  exit 1
}
case "$version" in
  *realsense*zenoh*) ;;
  *) echo "install.sh: $bin_dir/op3dsgd lacks the camera or Zenoh ($version); build with --features robot" >&2; exit 1 ;;
esac
for f in onnxruntime/libonnxruntime.so.1.31.1 minilm/model.onnx minilm/tokenizer.json clip/tokenizer.json; do
  if [ ! -f ".models/$f" ]; then
    echo "install.sh: .models/$f missing; run ./scripts/setup-models.sh" >&2
    exit 1
  fi
done

if [ -z "$destdir" ] && [ "$(id -u)" != 0 ]; then
  echo "install.sh: installing as root"
  exec sudo "$0" "${args[@]}" --no-build
fi

root="${destdir%/}"
lib="$root/usr/lib/op3dsg"
install -d "$root/usr/bin" "$root/usr/sbin" "$root/lib/systemd/system" "$root/usr/share/op3dsg" \
  "$root/usr/share/doc/op3dsg" "$root/etc/op3dsg" "$lib/onnxruntime" "$lib/minilm" "$lib/clip"
install -m 0755 "$bin_dir/op3dsgd" "$bin_dir/op3dsg" "$bin_dir/op3dsg-detectd" "$root/usr/bin/"
install -m 0755 systemd/op3dsg-service-user "$root/usr/sbin/"
install -m 0644 systemd/op3dsgd.service "$root/lib/systemd/system/op3dsgd.service"
install -m 0644 systemd/op3dsg-detectd.service "$root/lib/systemd/system/op3dsg-detectd.service"
rm -rf "$root/usr/share/op3dsg/profiles"
install -d "$root/usr/share/op3dsg/profiles/knowledge"
install -m 0644 profiles/*.toml "$root/usr/share/op3dsg/profiles/"
install -m 0644 profiles/knowledge/*.toml "$root/usr/share/op3dsg/profiles/knowledge/"
install -m 0644 .models/onnxruntime/libonnxruntime.so.1.31.1 "$lib/onnxruntime/"
install -m 0644 .models/minilm/model.onnx .models/minilm/tokenizer.json "$lib/minilm/"
install -m 0644 .models/clip/tokenizer.json "$lib/clip/"
# librealsense: the binaries look in /usr/lib/op3dsg first (RUNPATH $ORIGIN/../lib/op3dsg). A
# build against .deps/realsense (./scripts/setup-realsense.sh) needs its library there; one
# against the system's (Intel's librealsense2) uses that.
linked="$(LD_LIBRARY_PATH="$rs_lib${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}" ldd "$bin_dir/op3dsgd" | awk '/librealsense2/ { print $3 }')"
case "$linked" in
  "$rs_lib"/*)
    install -m 0644 "$rs_lib/librealsense2.so.2.56.5" "$lib/librealsense2.so.2.56"
    install -m 0644 "$rs_lib/libpystub.so" "$lib/"
    echo "installed librealsense from .deps/realsense into $lib" ;;
  "") echo "install.sh: $bin_dir/op3dsgd does not link librealsense" >&2; exit 1 ;;
  *) echo "librealsense: the system's ($linked)" ;;
esac
install -m 0644 README.md "$root/usr/share/doc/op3dsg/README.md"
install -m 0644 systemd/README.md "$root/usr/share/doc/op3dsg/systemd.md"
install -m 0644 docs/robot.md "$root/usr/share/doc/op3dsg/robot.md"

profile="$root/etc/op3dsg/op3dsgd.toml"
if [ ! -e "$profile" ]; then
  install -m 0644 systemd/op3dsgd.toml "$profile"
  echo "installed $profile (the Stretch 3 profile; place the detector model it names)"
else
  echo "kept $profile"
fi
worker_profile="$root/etc/op3dsg/op3dsg-detectd.toml"
if [ ! -e "$worker_profile" ]; then
  install -m 0644 systemd/op3dsg-detectd.toml "$worker_profile"
else
  echo "kept $worker_profile"
fi
install -d -m 0700 "$root/etc/op3dsg/credentials"
key="$root/etc/op3dsg/credentials/llm-api-key"
if [ ! -e "$key" ]; then
  install -m 0600 /dev/null "$key"
fi

if [ -z "$destdir" ] || [ -f "$root/etc/passwd" ]; then
  prefix=()
  [ -n "$destdir" ] && prefix=(--prefix "$root")
  for group in video plugdev; do
    grep -q "^$group:" "$root/etc/group" || groupadd "${prefix[@]}" --system "$group"
  done
  if ! grep -q "^op3dsg:" "$root/etc/passwd" && { [ -n "$destdir" ] || ! getent passwd op3dsg >/dev/null; }; then
    useradd "${prefix[@]}" --system --user-group --no-create-home --home-dir /nonexistent \
      --shell /usr/sbin/nologin --comment "op3dsg scene-graph daemon" op3dsg
    echo "created system user op3dsg"
  fi
  usermod "${prefix[@]}" -a -G video,plugdev op3dsg
fi
if [ -n "$service_user" ]; then
  if [ -n "$destdir" ]; then
    systemd/op3dsg-service-user --root "$root" "$service_user"
  else
    systemd/op3dsg-service-user "$service_user"
  fi
fi
if [ -f "$root/etc/op3dsg/op3dsgd.toml" ] && grep -q '^model_path = "models/yolox_nano.onnx"' "$profile" \
  && [ ! -f "$root/etc/op3dsg/models/yolox_nano.onnx" ]; then
  echo "place the detector model (no registry distributes it): sudo install -D -m 0644 yolox_nano.onnx /etc/op3dsg/models/yolox_nano.onnx"
fi
if [ -n "$destdir" ]; then
  echo "staged under $destdir (systemd not told)"
  exit 0
fi
systemctl daemon-reload
echo "installed. Start it now and at every boot:   sudo systemctl enable --now op3dsgd"
echo "on a GPU computer serving a robot instead: edit /etc/op3dsg/op3dsg-detectd.toml, then sudo systemctl enable --now op3dsg-detectd"
echo "logs: journalctl -u op3dsgd -f    map: op3dsg map info    graph: op3dsg watch"
