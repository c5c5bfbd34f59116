#!/usr/bin/env bash
# Builds the Pinocchio DLS CLIK benchmark (clik_dls.cpp) against Pinocchio from PyPI (cmeel wheels).
#
#   benches/pinocchio/build.sh [OUTPUT]     # OUTPUT defaults to target/pinocchio/clik_dls
#
# Environment: PIN_VENV (venv to create/use, default /tmp/pinvenv), CXX (default g++),
# EXTRA_CXXFLAGS (appended to the compile flags). Idempotent: the venv is reused when the pinned
# packages are there, and the binary is rebuilt only when the source, this script or the flags change.
# Nothing is vendored: Pinocchio (BSD-2-Clause) and its dependencies come from PyPI.
set -euo pipefail

HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
ROOT="$(cd "$HERE/../.." && pwd)"
OUT="${1:-target/pinocchio/clik_dls}"
case "$OUT" in /*) ;; *) OUT="$ROOT/$OUT" ;; esac
VENV="${PIN_VENV:-/tmp/pinvenv}"
CXX="${CXX:-g++}"
EXTRA_CXXFLAGS="${EXTRA_CXXFLAGS:-}"

# pin ships the headers and libraries of Pinocchio, Boost, urdfdom, coal; Eigen and the urdfdom
# headers are only build-time dependencies of the wheels, so they are pinned here to the versions
# the wheels were built against (Eigen 3.4.1, urdfdom-headers 3.0.0).
PACKAGES=(pin==4.1.0 cmeel-eigen==3.4.1 cmeel-urdfdom-headers==3.0.0)

command -v "$CXX" >/dev/null 2>&1 || { echo "build.sh: $CXX not found (apt-get install -y g++)" >&2; exit 1; }

if [ ! -x "$VENV/bin/python" ]; then
  python3 -m venv "$VENV"
fi
if ! "$VENV/bin/python" - "${PACKAGES[@]}" <<'EOF'
import sys
from importlib.metadata import version, PackageNotFoundError
for spec in sys.argv[1:]:
    name, want = spec.split("==")
    try:
        if version(name) != want:
            sys.exit(1)
    except PackageNotFoundError:
        sys.exit(1)
EOF
then
  "$VENV/bin/python" -m pip install --disable-pip-version-check --progress-bar off -q "${PACKAGES[@]}"
fi

PREFIX="$("$VENV/bin/python" -c 'import cmeel.consts as c; print(c.CMEEL_PREFIX)' 2>/dev/null || true)"
if [ -z "$PREFIX" ] || [ ! -d "$PREFIX" ]; then
  PREFIX="$(ls -d "$VENV"/lib/python3*/site-packages/cmeel.prefix 2>/dev/null | head -n1)"
fi
[ -f "$PREFIX/include/pinocchio/config.hpp" ] || { echo "build.sh: no Pinocchio headers under '$PREFIX'" >&2; exit 1; }
PIN_VERSION="$(sed -n 's/^# *define PINOCCHIO_VERSION "\(.*\)"/\1/p' "$PREFIX/include/pinocchio/config.hpp")"

# Baseline x86-64 (as our Rust build), no -march=native.
CXXFLAGS=(-O3 -DNDEBUG -std=c++17 -march=x86-64 -mtune=generic)
# What lib/cmake/pinocchio/pinocchioTargets.cmake (pinocchio_parsers, _default, _headers) and
# lib/cmake/coal/coalTargets.cmake put on their consumers.
DEFINES=(
  -DPINOCCHIO_ENABLE_TEMPLATE_INSTANTIATION
  -DPINOCCHIO_WITH_COLLISION
  -DPINOCCHIO_WITH_URDFDOM
  -DPINOCCHIO_URDFDOM_HEADERS_MAJOR_VERSION=3
  -DPINOCCHIO_URDFDOM_HEADERS_MINOR_VERSION=0
  -DPINOCCHIO_URDFDOM_HEADERS_PATCH_VERSION=0
  -DBOOST_MPL_LIMIT_LIST_SIZE=30
  -DBOOST_MPL_LIMIT_VECTOR_SIZE=30
  -DBOOST_MPL_CFG_NO_PREPROCESSED_HEADERS
  -DBOOST_FUSION_INVOKE_MAX_ARITY=12
  -DCOAL_BACKWARD_COMPATIBILITY_WITH_HPP_FCL
  -DCOAL_HAS_OCTOMAP -DCOAL_HAVE_OCTOMAP
  -DOCTOMAP_MAJOR_VERSION=1 -DOCTOMAP_MINOR_VERSION=10 -DOCTOMAP_PATCH_VERSION=0
)
INCLUDES=(
  -isystem "$PREFIX/include"
  -isystem "$PREFIX/include/eigen3"
  -isystem "$PREFIX/include/urdfdom_headers"
  -isystem "$PREFIX/include/urdfdom"
)
# RPATH (not RUNPATH) so the indirect dependencies resolve from the cmeel prefix too.
LDFLAGS=(
  -L"$PREFIX/lib"
  -Wl,--disable-new-dtags -Wl,-rpath,"$PREFIX/lib" -Wl,-rpath,"$PREFIX/lib64"
  -lpinocchio_parsers -lpinocchio_collision -lpinocchio_default
  -lurdfdom_model -lboost_filesystem -lboost_serialization
)
# shellcheck disable=SC2206
EXTRA=($EXTRA_CXXFLAGS)

CMD=("$CXX" "${CXXFLAGS[@]}" "${EXTRA[@]}" "${DEFINES[@]}" "${INCLUDES[@]}"
     "$HERE/clik_dls.cpp" -o "$OUT" "${LDFLAGS[@]}")

STAMP="$OUT.cmd"
mkdir -p "$(dirname "$OUT")"
if [ -x "$OUT" ] && [ -f "$STAMP" ] && [ "$(cat "$STAMP")" = "${CMD[*]}" ] \
   && [ "$OUT" -nt "$HERE/clik_dls.cpp" ] && [ "$OUT" -nt "$HERE/build.sh" ]; then
  echo "build.sh: up to date (pinocchio $PIN_VERSION)" >&2
else
  echo "build.sh: compiling against pinocchio $PIN_VERSION from $PREFIX" >&2
  "${CMD[@]}"
  printf '%s' "${CMD[*]}" > "$STAMP"
fi
echo "$OUT"
