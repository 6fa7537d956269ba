#!/usr/bin/env bash
# Creates the project-local Python venv (.venv/, gitignored) with the packages in
# scripts/python-requirements.txt, from PyPI, and installs the op3dsg Python client
# (ipc_types/python/) into it in editable mode when present.
#
# Idempotent: when .venv/ already holds exactly these requirements (a stamp records their hash)
# nothing is fetched and the run takes well under a second.
# Usage: ./scripts/setup-python.sh [--force]
#   VENV_DIR   another folder than .venv/
# Needs python3 >= 3.9 with the venv module (Debian: apt-get install python3-venv).
set -euo pipefail
cd "$(dirname "$0")/.."

VENV_DIR="${VENV_DIR:-.venv}"
REQ=scripts/python-requirements.txt
FORCE=0
[[ "${1:-}" == "--force" ]] && FORCE=1

if ! command -v python3 >/dev/null 2>&1; then
  echo "setup-python.sh: python3 not found (Debian: apt-get install python3 python3-venv)" >&2
  exit 2
fi

stamp="$VENV_DIR/.op3dsg-requirements.sha256"
want_inputs=("$REQ")
[[ -f ipc_types/python/pyproject.toml ]] && want_inputs+=(ipc_types/python/pyproject.toml)
want="$(cat "${want_inputs[@]}" | sha256sum | cut -d' ' -f1)"
if [[ $FORCE -eq 0 && -x "$VENV_DIR/bin/python" && -f "$stamp" && "$(cat "$stamp")" == "$want" ]]; then
  echo "setup-python.sh: $VENV_DIR is current"
  exit 0
fi

if [[ ! -x "$VENV_DIR/bin/python" ]]; then
  python3 -m venv "$VENV_DIR" || {
    echo "setup-python.sh: python3 -m venv $VENV_DIR failed (Debian: apt-get install python3-venv)" >&2
    exit 2
  }
fi
"$VENV_DIR/bin/python" -m pip install --quiet --disable-pip-version-check -r "$REQ"
if [[ -f ipc_types/python/pyproject.toml ]]; then
  "$VENV_DIR/bin/python" -m pip install --quiet --disable-pip-version-check --no-deps --no-build-isolation -e ipc_types/python
fi
echo "$want" >"$stamp"
echo "setup-python.sh: $VENV_DIR ready ($("$VENV_DIR/bin/python" --version))"
