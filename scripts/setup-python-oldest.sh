#!/usr/bin/env bash
# Creates the venv of the oldest environment the op3dsg Python client (ipc_types/python/)
# supports, ROS 2 Humble's (Ubuntu 22.04: Python 3.10, NumPy 1.21): .venv-oldest/ (gitignored)
# with Python 3.10 and the packages of scripts/python-requirements-oldest.txt, from PyPI. Then it
# installs the client into it (editable) *with* its dependencies, as `pip install` beside ROS
# would, and checks that this left NumPy 1.21 as it was: a requirement that asks for a newer
# NumPy fails here, naming the file to fix. scripts/test.sh runs the client's tests in this venv
# after the project venv's (.venv/, NumPy 2).
#
# Python 3.10: $OLDEST_PYTHON, else python3.10 on PATH, else the newest pyenv 3.10.x
# (${PYENV_ROOT:-~/.pyenv}/versions/3.10.*). Without one it exits 3 after a SKIPPED line, or,
# with CI=true, fails (exit 2) naming what to install.
#
# Idempotent: when the venv already holds exactly these requirements for this interpreter (a
# stamp records their hash) nothing is fetched and the run takes well under a second.
# Usage: ./scripts/setup-python-oldest.sh [--force]
#   OLDEST_VENV_DIR   another folder than .venv-oldest/
#   OLDEST_PYTHON     the Python 3.10 interpreter to use
set -euo pipefail
cd "$(dirname "$0")/.."

me=setup-python-oldest.sh
VENV_DIR="${OLDEST_VENV_DIR:-.venv-oldest}"
REQ=scripts/python-requirements-oldest.txt
PACKAGE=ipc_types/python
WANT=3.10
FORCE=0
[[ "${1:-}" == "--force" ]] && FORCE=1

# "X.Y" of an interpreter that runs, nothing otherwise (a pyenv shim of a version that is not
# selected is on PATH but fails).
minor_of() { "$1" -c 'import sys; print("%d.%d" % sys.version_info[:2])' 2>/dev/null || true; }

find_python() {
  local candidate
  if candidate="$(command -v "python$WANT")" && [[ "$(minor_of "$candidate")" == "$WANT" ]]; then
    echo "$candidate"
    return 0
  fi
  local versions=()
  shopt -s nullglob
  versions=("${PYENV_ROOT:-$HOME/.pyenv}/versions/$WANT".*)
  shopt -u nullglob
  [[ ${#versions[@]} -gt 0 ]] || return 1
  while read -r candidate; do
    if [[ "$(minor_of "$candidate/bin/python$WANT")" == "$WANT" ]]; then
      echo "$candidate/bin/python$WANT"
      return 0
    fi
  done < <(printf '%s\n' "${versions[@]}" | sort -V -r)
  return 1
}

if [[ -n "${OLDEST_PYTHON:-}" ]]; then
  PY="$OLDEST_PYTHON"
  if [[ "$(minor_of "$PY")" != "$WANT" ]]; then
    echo "$me: OLDEST_PYTHON=$PY is not a working Python $WANT" >&2
    exit 2
  fi
elif ! PY="$(find_python)"; then
  what="Python $WANT with its venv module (Ubuntu 22.04: apt-get install python3.10 python3.10-venv; pyenv: pyenv install 3.10; or set OLDEST_PYTHON to one)"
  if [[ "${CI:-}" == "true" ]]; then
    echo "$me: no Python $WANT found (not python$WANT on PATH, not under ${PYENV_ROOT:-$HOME/.pyenv}/versions/): install $what" >&2
    echo "$me: CI runs the op3dsg Python client's tests on ROS 2 Humble's Python $WANT and NumPy 1.21 as well" >&2
    exit 2
  fi
  echo "$me: ******** SKIPPED: no Python $WANT found, so the op3dsg Python client is NOT tested with ROS 2 Humble's Python $WANT and NumPy 1.21; install $what ********" >&2
  exit 3
fi

stamp="$VENV_DIR/.op3dsg-requirements.sha256"
base="$VENV_DIR/.op3dsg-base-python"
want="$({ cat "$REQ" "$PACKAGE/pyproject.toml"; echo "$PY"; } | sha256sum | cut -d' ' -f1)"
if [[ $FORCE -eq 0 && -x "$VENV_DIR/bin/python" && -f "$stamp" && "$(cat "$stamp")" == "$want" ]]; then
  echo "$me: $VENV_DIR is current"
  exit 0
fi

# A venv made by another interpreter (or none that runs) is made anew.
if [[ $FORCE -eq 1 || "$(minor_of "$VENV_DIR/bin/python")" != "$WANT" || "$(cat "$base" 2>/dev/null)" != "$PY" ]]; then
  "$PY" -m venv --clear "$VENV_DIR" || {
    echo "$me: $PY -m venv $VENV_DIR failed (Ubuntu: apt-get install python3.10-venv)" >&2
    exit 2
  }
  echo "$PY" >"$base"
fi
pip=("$VENV_DIR/bin/python" -m pip --disable-pip-version-check)
"${pip[@]}" install --quiet -r "$REQ"
# With dependencies, as beside ROS: the NumPy 1.21 installed above meets the package's numpy
# requirement, so pip must keep it.
"${pip[@]}" install --quiet --no-build-isolation -e "$PACKAGE"
pinned="$(sed -n 's/^numpy==\([0-9.]*\).*/\1/p' "$REQ")"
found="$("$VENV_DIR/bin/python" -c 'import numpy; print(numpy.__version__)')"
if [[ "$found" != "$pinned" ]]; then
  echo "$me: installing $PACKAGE replaced NumPy $pinned by $found: the numpy requirement in $PACKAGE/pyproject.toml must accept NumPy 1.21 (ROS 2 Humble's)" >&2
  exit 1
fi
if ! check="$("${pip[@]}" check 2>&1)"; then
  echo "$me: pip check in $VENV_DIR: $check" >&2
  exit 1
fi
echo "$want" >"$stamp"
echo "$me: $VENV_DIR ready ($("$VENV_DIR/bin/python" --version), NumPy $found)"
