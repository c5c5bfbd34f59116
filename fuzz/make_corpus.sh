#!/usr/bin/env bash
# Writes the seed corpus fuzz/corpus/<target>/ for both targets: the first 100 lines of every
# program in tests/data/gcode, a 100-line window from the middle of the long ones (past the slicer's
# start code, where the moves are), and the hand-written programs in fuzz/seeds/. The result is
# committed; run this again when tests/data/gcode changes.
set -euo pipefail
cd "$(dirname "$0")"
data=../tests/data/gcode
for target in gcode_parser gcode_to_path; do
  out=corpus/$target
  rm -rf "$out"
  mkdir -p "$out"
  find "$data" -type f \( -name '*.gcode' -o -name '*.ngc' \) | sort | while read -r file; do
    name=$(basename "$(dirname "$file")")_$(basename "$file")
    head -n 100 "$file" > "$out/head_$name"
    lines=$(wc -l < "$file")
    if [ "$lines" -gt 300 ]; then
      start=$((lines * 2 / 5))
      sed -n "${start},$((start + 99))p" "$file" > "$out/mid_$name"
    fi
  done
  cp seeds/* "$out/"
done
du -sh corpus/*
