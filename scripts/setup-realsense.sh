#!/usr/bin/env bash
# Makes the librealsense sysroot the `realsense` cargo feature builds and runs against, in
# .deps/realsense/ (gitignored), from PyPI's pyrealsense2 wheel: Debian has no librealsense2.
#
# The wheel ships no librealsense2.so, but its Python module links librealsense statically and
# exports every rs2_* function realsense-rust calls. This script (the recipe in the project's
# dependency notes):
#   1. pip download (nothing installed into any Python) the pinned wheel, checked by sha256,
#      and extracts the module;
#   2. builds lib/libpystub.so defining the module's undefined Python C-API symbols (data
#      symbols as zeroed arrays, functions as abort(): librealsense's C API never calls them);
#   3. copies the module to lib/librealsense2.so.2.56.5 and patches it with three separate
#      patchelf calls (soname, needed libpystub.so, rpath $ORIGIN; one combined call corrupts
#      the string table with Debian 12's patchelf 0.14.3), plus the usual symlinks;
#   4. writes lib/pkgconfig/realsense2.pc (Version 2.56.5) for realsense-sys's build script;
#   5. smoke-tests it with a C program calling rs2_get_api_version and rs2_create_context.
#
# Then: PKG_CONFIG_PATH=.deps/realsense/lib/pkgconfig and, at run time, an rpath or
# LD_LIBRARY_PATH=.deps/realsense/lib (scripts/test.sh sets both).
#
# On the robot, Intel's librealsense2 packages (librealsense2-dev) provide realsense2.pc
# themselves; this sysroot is for machines without them (CI, development).
#
# System packages: patchelf, gcc and binutils (readelf) to build it, libusb-1.0-0 and libudev1
# to load it. When patchelf or libusb-1.0-0 is missing and the script runs as root it installs
# them with apt-get (the only thing it installs system-wide) and says so; otherwise it stops
# naming the packages.
#
# Idempotent: when the sysroot was made from this exact wheel and script, it prints that it is
# current and exits in well under a second.
# Usage: ./scripts/setup-realsense.sh [--force]
#   OP3DSG_REALSENSE_DIR   another folder than .deps/realsense
set -euo pipefail
cd "$(dirname "$0")/.."

VERSION=2.56.5
WHEEL_VERSION=2.56.5.9235
WHEEL=pyrealsense2-${WHEEL_VERSION}-cp311-cp311-manylinux1_x86_64.whl
WHEEL_SHA256=76d384ea99f257b4697a82cb3581b05cc69fadfd0701021ad76da098a3e240f0
MODULE=pyrealsense2/pyrealsense2.cpython-311-x86_64-linux-gnu.so
DIR="${OP3DSG_REALSENSE_DIR:-.deps/realsense}"
FORCE=0
[[ "${1:-}" == "--force" ]] && FORCE=1

say() { echo "setup-realsense.sh: $*"; }
die() { echo "setup-realsense.sh: $*" >&2; exit 2; }

if [[ "$(uname -m)" != "x86_64" ]]; then
  die "PyPI has pyrealsense2 wheels for x86_64 only; on $(uname -m) install Intel's librealsense2-dev ${VERSION%.*}.x (its realsense2.pc is found by pkg-config) and build without this sysroot"
fi

stamp="$DIR/.op3dsg-stamp"
want="$( (echo "$WHEEL_SHA256"; cat "$0") | sha256sum | cut -d' ' -f1)"
if [[ $FORCE -eq 0 && -f "$stamp" && "$(cat "$stamp")" == "$want" && -e "$DIR/lib/librealsense2.so" ]]; then
  say "$DIR is current (librealsense $VERSION from pyrealsense2==$WHEEL_VERSION)"
  exit 0
fi

# System tools and libraries.
missing=()
command -v patchelf >/dev/null 2>&1 || missing+=(patchelf)
ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0' || missing+=(libusb-1.0-0)
ldconfig -p 2>/dev/null | grep -q 'libudev.so.1' || missing+=(libudev1)
command -v gcc >/dev/null 2>&1 || missing+=(gcc)
command -v readelf >/dev/null 2>&1 || missing+=(binutils)
if ((${#missing[@]})); then
  if [[ $(id -u) -eq 0 ]] && command -v apt-get >/dev/null 2>&1; then
    say "installing system packages with apt-get: ${missing[*]}"
    apt-get install -y --no-install-recommends "${missing[@]}" >/dev/null ||
      { apt-get update >/dev/null && apt-get install -y --no-install-recommends "${missing[@]}" >/dev/null; } ||
      die "apt-get install ${missing[*]} failed"
  else
    die "missing system packages: ${missing[*]} (Debian: sudo apt-get install ${missing[*]})"
  fi
fi
command -v python3 >/dev/null 2>&1 || die "python3 (with pip) is needed to download the wheel"

work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT

# 1. The wheel, from PyPI, checked.
python3 -m pip download --quiet --disable-pip-version-check --no-deps --only-binary=:all: \
  --python-version 3.11 --implementation cp --abi cp311 --platform manylinux1_x86_64 \
  "pyrealsense2==$WHEEL_VERSION" -d "$work" ||
  die "pip download pyrealsense2==$WHEEL_VERSION failed (PyPI unreachable?)"
[[ -f "$work/$WHEEL" ]] || die "pip download did not produce $WHEEL (got: $(ls "$work"))"
got="$(sha256sum "$work/$WHEEL" | cut -d' ' -f1)"
[[ "$got" == "$WHEEL_SHA256" ]] || die "$WHEEL: sha256 $got, expected $WHEEL_SHA256"
python3 - "$work/$WHEEL" "$MODULE" "$work/module.so" <<'EOF'
import sys, zipfile
with zipfile.ZipFile(sys.argv[1]) as z, open(sys.argv[3], "wb") as out:
    out.write(z.read(sys.argv[2]))
EOF

rm -rf "$DIR.new"
mkdir -p "$DIR.new/lib/pkgconfig" "$DIR.new/include"
lib="$DIR.new/lib"

# 2. The Python C-API stub: relocation type tells data (GLOB_DAT) from functions.
readelf -rW "$work/module.so" | awk '
  $3 ~ /R_X86_64_(GLOB_DAT|JUMP_SLO|64)/ && $5 ~ /^_?Py/ {
    sym = $5; sub(/@.*/, "", sym);
    kind = ($3 == "R_X86_64_GLOB_DAT") ? "data" : "func";
    if (!(sym in seen)) { seen[sym] = kind; print kind, sym }
  }' | sort -u >"$work/symbols"
n="$(wc -l <"$work/symbols")"
((n > 100)) || die "found only $n Python symbols in $MODULE (expected ~155): wheel layout changed?"
{
  echo '/* Python C-API symbols of the pyrealsense2 module; librealsense C API never uses them. */'
  echo '#include <stdlib.h>'
  awk '$1 == "data" { printf "__attribute__((aligned(64))) unsigned char %s[1024];\n", $2 }
       $1 == "func" { printf "void %s(void) { abort(); }\n", $2 }' "$work/symbols"
} >"$work/pystub.c"
gcc -shared -fPIC -O1 -Wl,-soname,libpystub.so -o "$lib/libpystub.so" "$work/pystub.c"

# 3. The library, patched in three calls.
cp "$work/module.so" "$lib/librealsense2.so.$VERSION"
patchelf --set-soname "librealsense2.so.${VERSION%.*}" "$lib/librealsense2.so.$VERSION"
patchelf --add-needed libpystub.so "$lib/librealsense2.so.$VERSION"
patchelf --set-rpath '$ORIGIN' "$lib/librealsense2.so.$VERSION"
ln -s "librealsense2.so.$VERSION" "$lib/librealsense2.so.${VERSION%.*}"
ln -s "librealsense2.so.${VERSION%.*}" "$lib/librealsense2.so"

# 4. pkg-config (prefix relative to the .pc file, so the folder can move).
cat >"$lib/pkgconfig/realsense2.pc" <<EOF
prefix=\${pcfiledir}/../..
libdir=\${prefix}/lib
includedir=\${prefix}/include

Name: realsense2
Description: librealsense $VERSION from PyPI pyrealsense2==$WHEEL_VERSION (op3dsg scripts/setup-realsense.sh)
Version: $VERSION
Libs: -L\${libdir} -lrealsense2
Cflags: -I\${includedir}
EOF

# 5. Every symbol resolves and a context can be made.
cat >"$work/smoke.c" <<'EOF'
#include <stdio.h>
typedef struct rs2_error rs2_error;
typedef struct rs2_context rs2_context;
int rs2_get_api_version(rs2_error **error);
rs2_context *rs2_create_context(int api_version, rs2_error **error);
void rs2_delete_context(rs2_context *context);
int main(void) {
  rs2_error *e = 0;
  int v = rs2_get_api_version(&e);
  rs2_context *c = rs2_create_context(v, &e);
  if (e || !c) { fprintf(stderr, "rs2_create_context failed\n"); return 1; }
  rs2_delete_context(c);
  printf("%d\n", v);
  return 0;
}
EOF
gcc -o "$work/smoke" "$work/smoke.c" -L"$lib" -lrealsense2 -Wl,-rpath,"$(cd "$lib" && pwd)"
api="$(LIBRS_LOG_LEVEL=NONE "$work/smoke")" || die "smoke test of $lib/librealsense2.so failed"

rm -rf "$DIR"
mv "$DIR.new" "$DIR"
echo "$want" >"$stamp"
say "$DIR ready: librealsense $VERSION (API $api) from pyrealsense2==$WHEEL_VERSION, $n Python symbols stubbed"
