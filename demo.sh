#!/usr/bin/env bash
# The main job on the embedded demo model (assets/fuze, MIT):
#   voxelize -> build-tree -> inspect --validate --deep -> render-preview
# Outputs land in ${OUT:-out/demo}: fuze.samples, fuze.sct, report.txt, preview.png.
set -euo pipefail
cd "$(dirname "$0")"
out=${OUT:-out/demo}
mkdir -p "$out"
cargo build --release --quiet -p voxelize -p build-tree -p inspect -p render-preview
bin=target/release
model=assets/fuze/fuze.obj

echo "1/4 voxelize  $model" >&2
"$bin/sct-voxelize" "$model" -o "$out/fuze.samples"
echo "2/4 build     $out/fuze.sct" >&2
"$bin/sct-build-tree" "$out/fuze.samples" -o "$out/fuze.sct"
echo "3/4 inspect   $out/report.txt" >&2
"$bin/sct-inspect" "$out/fuze.sct" --validate --deep > "$out/report.txt"
echo "4/4 render    $out/preview.png" >&2
"$bin/sct-render-preview" "$out/fuze.sct" -o "$out/preview.png" --view left

echo "done: SCT file $out/fuze.sct, report $out/report.txt, preview $out/preview.png"
