#!/usr/bin/env bash
# What real files decode to per byte (spec/SCT.md §2.3, decoded size: 40 bytes a sample or
# tree node; the tables, a few KB, are left out here): samples files written by sct-voxelize
# at default settings from the shared models, and the scene files sct-build-tree makes from
# them (default and raw profiles). The reader refuses files above max(64 MiB, 256 × size).
# Usage: scripts/decoded-ratios.sh     (needs ../shared/models beside the repository)
set -euo pipefail
cd "$(dirname "$0")/.."
models=../shared/models
bin=target/release
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
cargo build --release --quiet -p voxelize -p build-tree
printf '%-40s %12s %10s %7s | %12s %10s %7s | %7s\n' model samples-file samples ratio default.sct nodes ratio raw
for m in scans/stanford-bunny/stanford-bunny.obj scans/stanford-dragon-100k/dragon.ply scans/armadillo/armadillo.obj \
    scans/fandisk/fandisk.obj scans/horse/horse.ply textured-obj/spot/spot_triangulated.obj gltf/Box/glTF/Box.gltf \
    gltf/DamagedHelmet/glTF-Binary/DamagedHelmet.glb gltf/SimpleInstancing/glTF/SimpleInstancing.gltf \
    gltf/CesiumMilkTruck/glTF-Binary/CesiumMilkTruck.glb ply/pond-pointcloud-colours/pond.0.ply ply/cycloidal-colours/cycloidal.ply; do
    [ -f "$models/$m" ] || { echo "$m: missing"; continue; }
    s="$tmp/m.samples"
    "$bin/sct-voxelize" "$models/$m" -o "$s" > /dev/null 2>&1 || { echo "$m: voxelize failed"; continue; }
    n=$("$bin/sct-build-tree" "$s" -o "$tmp/d.sct" 2>&1 | grep -o '[0-9]* nodes' | head -1 | cut -d' ' -f1)
    "$bin/sct-build-tree" "$s" -o "$tmp/r.sct" --profile raw > /dev/null 2>&1
    samples=$("$bin/sct-voxelize" "$models/$m" --dry-run --json 2>/dev/null | grep -o '"samples": *[0-9]*' | head -1 | grep -o '[0-9]*$')
    fs=$(stat -c %s "$s"); fd=$(stat -c %s "$tmp/d.sct"); fr=$(stat -c %s "$tmp/r.sct")
    printf '%-40s %12s %10s %7.1f | %12s %10s %7.1f | %7.1f\n' "$m" "$fs" "$samples" "$(awk "BEGIN {print 40 * $samples / $fs}")" \
        "$fd" "$n" "$(awk "BEGIN {print 40 * $n / $fd}")" "$(awk "BEGIN {print 40 * $n / $fr}")"
done
