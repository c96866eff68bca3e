#!/usr/bin/env bash
# The main job on the embedded demo model (assets/fuze, MIT):
#   voxelize -> build-tree -> inspect --validate --deep -> render-preview (+ mesh reference)
# Outputs land in ${OUT:-out/demo}: fuze.samples, fuze.sct, report.txt, preview.png and the
# accuracy check against the mesh (preview.metrics.json, preview.reference.png, preview.diff.png).
# SCT_BIN_DIR: use already-built binaries from there instead of building (the tests do).
# Otherwise the binaries are built and taken from cargo's target directory: CARGO_TARGET_DIR
# when set, else the one cargo reports (build.target-dir of a .cargo/config.toml), else target/.
set -euo pipefail
cd "$(dirname "$0")"
out=${OUT:-out/demo}
mkdir -p "$out"
if [ -n "${SCT_BIN_DIR:-}" ]; then
  bin=$SCT_BIN_DIR
else
  cargo build --release --quiet -p voxelize -p build-tree -p inspect -p render-preview
  target=${CARGO_TARGET_DIR:-}
  if [ -z "$target" ]; then
    target=$(cargo metadata --no-deps --format-version 1 2>/dev/null | sed -n 's/.*"target_directory":"\([^"]*\)".*/\1/p') || true
  fi
  bin=${target:-target}/release
fi
for tool in sct-voxelize sct-build-tree sct-inspect sct-render-preview; do
  if [ ! -x "$bin/$tool" ]; then
    echo "demo.sh: $bin/$tool not found (set SCT_BIN_DIR to the directory holding the built tools)" >&2
    exit 2
  fi
done
model=assets/fuze/fuze.obj

echo "1/4 voxelize  $model" >&2
"$bin/sct-voxelize" "$model" -o "$out/fuze.samples"
echo "2/4 build     $out/fuze.sct" >&2
"$bin/sct-build-tree" "$out/fuze.samples" -o "$out/fuze.sct"
echo "3/4 inspect   $out/report.txt" >&2
"$bin/sct-inspect" "$out/fuze.sct" --validate --deep > "$out/report.txt"
echo "4/4 render    $out/preview.png (and the mesh reference)" >&2
# The fuze bottle is modelled Z-up and its OBJ does not say so.
"$bin/sct-render-preview" "$out/fuze.sct" -o "$out/preview.png" --up z --reference "$model"

echo "done: SCT file $out/fuze.sct, report $out/report.txt, preview $out/preview.png, accuracy $out/preview.metrics.json"
