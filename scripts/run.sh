#!/usr/bin/env bash
# Builds op3dsgd (release) and runs it on the built-in default: the synthetic kitchen with
# realistic detector noise. No camera, model or LLM needed. Extra arguments go to op3dsgd,
# e.g. `./scripts/run.sh --profile profiles/sim-bathroom.toml` or `--max-frames 300`.
# Watch it from another terminal: target/release/op3dsg watch
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release --locked --bin op3dsgd --bin op3dsg
exec target/release/op3dsgd "$@"
