#!/usr/bin/env bash
# Writes the stand-in models of the detector families into .models/standins/ (gitignored) with
# scripts/reference/model_standins.py, run by the project venv (PyPI onnx). Needs
# ./scripts/setup-models.sh (CLIP's BPE files) and ./scripts/setup-python.sh first; test.sh
# runs all three. Also writes the real-size YOLO-World-S stand-in of
# `cargo bench -p op3dsg-runtime --bench model_families`. Idempotent: a stamp of the script's hash skips a second run.
# Usage: ./scripts/setup-standins.sh [--force]
#   VENV_DIR     another venv than .venv/
#   MODELS_DIR   another folder than .models/
set -euo pipefail
cd "$(dirname "$0")/.."

VENV_DIR="${VENV_DIR:-.venv}"
MODELS_DIR="${MODELS_DIR:-.models}"
OUT="$MODELS_DIR/standins"
SCRIPT=scripts/reference/model_standins.py
# The real-size YOLO-World-S stand-in of the CPU-cost benchmark (45 MB, a few seconds).
SIZED=scripts/reference/yolo_world_s_like.py
stamp="$OUT/.script.sha256"
want="$(cat "$SCRIPT" "$SIZED" scripts/reference/stand_in_graph.py "$MODELS_DIR/clip/tokenizer.json" 2>/dev/null | sha256sum | cut -d' ' -f1)"
if [[ "${1:-}" != "--force" && -f "$stamp" && "$(cat "$stamp")" == "$want" && -f "$OUT/expected.json" ]]; then
  echo "setup-standins.sh: $OUT/ is current"
  exit 0
fi
if [[ ! -x "$VENV_DIR/bin/python" ]]; then
  echo "setup-standins.sh: no $VENV_DIR/bin/python; run ./scripts/setup-python.sh first" >&2
  exit 2
fi
"$VENV_DIR/bin/python" "$SCRIPT" --out "$OUT"
"$VENV_DIR/bin/python" "$SIZED" --out "$OUT/yolo_world_s_like.onnx"
echo "$want" >"$stamp"
