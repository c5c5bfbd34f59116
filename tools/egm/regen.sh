#!/usr/bin/env bash
# Regenerates tools/driver/src/egm/proto.rs from tools/egm/proto/egm.proto with protox (a pure-Rust
# protobuf compiler: no protoc) and prost-build, then checks the result builds. The generator is its
# own crate outside the workspace, so the driver's build never compiles protox.
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
out=$(mktemp -d)
cargo run --release -q --manifest-path "$here/codegen/Cargo.toml" -- "$here/proto" "$out"
target="$here/../driver/src/egm/proto.rs"
{
  echo '//! prost'"'"'s code for `tools/egm/proto/egm.proto` (package `abb.egm`, from ros-industrial/abb_libegm,'
  echo '//! BSD-3-Clause: see `tools/egm/proto/LICENSE-abb_libegm`). Generated, not written: protox 0.10.0 and'
  echo '//! prost-build 0.14.6 (`tools/egm/regen.sh` makes it again).'
  echo '#![allow(missing_docs, clippy::all)]'
  echo
  cat "$out/abb.egm.rs"
} > "$target"
rm -rf "$out"
echo "wrote $target"
