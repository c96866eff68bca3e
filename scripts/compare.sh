#!/usr/bin/env bash
# The method comparison of BENCHMARKS.md ("Preview methods: speed against accuracy"): builds
# the comparison scenes from ../shared/models and runs `sct-render-preview compare` over them
# (chart, JSON and table in OUT_DIR). Not part of CI; about 25 minutes on 2 loaded cores with
# every method and REPEAT=3 ORBIT=4 (wald at radius scale 4 and wand on the grid and block
# dominate).
# Usage: [REPEAT=5] [ORBIT=16] scripts/compare.sh [OUT_DIR] [extra compare options]
# (default OUT_DIR out/compare)
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-out/compare}
shift || true
m=../shared/models
cargo build --release -p render-preview --quiet
target_dir=$(cargo metadata --format-version 1 --no-deps | python3 -c 'import json,sys; print(json.load(sys.stdin)["target_directory"])')
mkdir -p "$out"
echo "compare: $(date -u '+%Y-%m-%d %H:%M UTC'), $(git rev-parse --short HEAD), $(nproc) cores" >&2
# One model (textured and not), a model in front of another (thesis Table 14 with models we
# have: bunny in front of the dragon), a jittered 30 × 30 grid (§6.6) and a dense 8 × 8 × 8
# block (§6.8) of low-resolution bunnies. `--pixel-error 1` is the cut of `wald` and `wand`
# (their knobs are the radius scale and d; `zbuffer`, `gauss` and `parilov` take theirs from
# --knobs): at the default 0.75 `wald` examines more than 10^7 nodes on the block.
"$target_dir/release/sct-render-preview" compare \
  --scene "one:$m/gltf/Duck/glTF-Binary/Duck.glb" \
  --scene "one:$m/textured-obj/fuze/fuze.obj" \
  --scene "pair:$m/scans/stanford-bunny-original-ply/bun_zipper.ply,$m/scans/stanford-dragon-100k/dragon.ply" \
  --scene "grid:$m/scans/stanford-bunny-original-ply/bun_zipper_res4.ply:30" \
  --scene "block:$m/scans/stanford-bunny-original-ply/bun_zipper_res4.ply:8" \
  --knobs 0.5,1,2,4 --repeat "${REPEAT:-5}" --orbit "${ORBIT:-16}" --width 640 --height 480 \
  --pixel-error 1 \
  -o "$out/compare" "$@" | tee "$out/compare.txt"
