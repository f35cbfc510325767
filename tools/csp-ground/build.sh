#!/usr/bin/env bash
# Build csp-ground: libcsp (MIT, from ../shared/vendor/libcsp) with cmake into
# OUT_DIR/libcsp (once), then OUT_DIR/csp-ground linked against it.
#
#   tools/csp-ground/build.sh OUT_DIR
#
# Env: LIBCSP_SRC (libcsp source tree), CC (C compiler, default cc).
# Exit 3 if cmake or the C compiler is missing.
set -euo pipefail

if [ $# -ne 1 ]; then
    echo "usage: $0 OUT_DIR" >&2
    exit 2
fi

HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
REPO="$(cd "$HERE/../.." && pwd)"
LIBCSP_SRC="${LIBCSP_SRC:-$REPO/../shared/vendor/libcsp}"
CC="${CC:-cc}"

for tool in cmake "$CC"; do
    if ! command -v "$tool" >/dev/null 2>&1; then
        echo "build.sh: '$tool' not found; install it (e.g. apt-get install -y cmake gcc)" >&2
        exit 3
    fi
done
if [ ! -f "$LIBCSP_SRC/CMakeLists.txt" ]; then
    echo "build.sh: no libcsp source at $LIBCSP_SRC (set LIBCSP_SRC)" >&2
    exit 2
fi
LIBCSP_SRC="$(cd "$LIBCSP_SRC" && pwd)"

mkdir -p "$1"
OUT="$(cd "$1" && pwd)"
CSP_BUILD="$OUT/libcsp"

# libcsp's CMakeLists forces BUILD_SHARED_LIBS=ON on Linux, so we get
# libcsp.so and link it with an $ORIGIN-relative rpath. pkg-config is disabled
# so the optional libyaml/libzmq/libsocketcan extras are never pulled in;
# KISS + the Linux usart driver are always compiled. RTABLE stays off
# (csp-ground routes via the interface's is_default flag).
if [ ! -f "$CSP_BUILD/libcsp.so" ]; then
    echo "build.sh: building libcsp from $LIBCSP_SRC into $CSP_BUILD"
    cmake -S "$LIBCSP_SRC" -B "$CSP_BUILD" \
        -DCMAKE_BUILD_TYPE=Release \
        -DCMAKE_DISABLE_FIND_PACKAGE_PkgConfig=TRUE \
        -DCSP_USE_RTABLE=OFF >/dev/null
    cmake --build "$CSP_BUILD" --target csp -j2 >/dev/null
fi

"$CC" -std=c11 -O2 -Wall -Wextra \
    -I"$LIBCSP_SRC/include" -I"$CSP_BUILD/include" \
    "$HERE/csp_ground.c" -o "$OUT/csp-ground" \
    -L"$CSP_BUILD" -lcsp -Wl,-rpath,'$ORIGIN/libcsp' -pthread

echo "build.sh: built $OUT/csp-ground"
