#!/usr/bin/env bash
# Builds KDL's CLIK tick bench (clik_kdl.cpp) against Debian's orocos-kdl (liborocos-kdl-dev).
#
#   benches/kdl/build.sh [OUTPUT]     # OUTPUT defaults to target/kdl/clik_kdl
#
# Environment: CXX (default g++), EXTRA_CXXFLAGS (appended to the compile flags). Installs
# liborocos-kdl-dev with apt-get when its headers are missing (as root). Rebuilds only when the
# source, this script or the flags change. Nothing is vendored.
set -euo pipefail

HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
ROOT="$(cd "$HERE/../.." && pwd)"
OUT="${1:-target/kdl/clik_kdl}"
case "$OUT" in /*) ;; *) OUT="$ROOT/$OUT" ;; esac
CXX="${CXX:-g++}"
EXTRA_CXXFLAGS="${EXTRA_CXXFLAGS:-}"

command -v "$CXX" >/dev/null 2>&1 || { echo "build.sh: $CXX not found (apt-get install -y g++)" >&2; exit 1; }
if [ ! -f /usr/include/kdl/chainiksolvervel_pinv.hpp ]; then
  # A fresh machine may have no package lists yet: update them once when the first try fails.
  apt-get install -y -qq liborocos-kdl-dev >&2 \
    || { apt-get update -qq >&2 && apt-get install -y -qq liborocos-kdl-dev >&2; } \
    || { echo "build.sh: cannot install liborocos-kdl-dev" >&2; exit 1; }
fi
KDL_VERSION="$(dpkg-query -W -f='${Version}' liborocos-kdl-dev 2>/dev/null | sed 's/-.*//')"

# Baseline x86-64 (as our Rust build and the Pinocchio bench), no -march=native.
CXXFLAGS=(-O3 -DNDEBUG -std=c++17 -march=x86-64 -mtune=generic -DKDL_VERSION_TEXT="\"${KDL_VERSION:-1.5}\"")
# shellcheck disable=SC2206
EXTRA=($EXTRA_CXXFLAGS)
CMD=("$CXX" "${CXXFLAGS[@]}" "${EXTRA[@]}" -isystem /usr/include/eigen3 "$HERE/clik_kdl.cpp" -o "$OUT" -lorocos-kdl)

STAMP="$OUT.cmd"
mkdir -p "$(dirname "$OUT")"
if [ -x "$OUT" ] && [ -f "$STAMP" ] && [ "$(cat "$STAMP")" = "${CMD[*]}" ] \
   && [ "$OUT" -nt "$HERE/clik_kdl.cpp" ] && [ "$OUT" -nt "$HERE/build.sh" ]; then
  echo "build.sh: up to date (kdl $KDL_VERSION)" >&2
else
  echo "build.sh: compiling against kdl $KDL_VERSION" >&2
  "${CMD[@]}"
  printf '%s' "${CMD[*]}" > "$STAMP"
fi
echo "$OUT"
