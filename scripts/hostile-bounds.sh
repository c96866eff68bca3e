#!/usr/bin/env bash
# Measures every tool, with default flags, on the worst inputs of under 1 MB we know how to
# make (README, "Resource bounds per tool"): peak RSS and wall time from /usr/bin/time -v,
# and the exit status (a refusal is a fine answer; a crash, more than 1 GB or more than 10 s
# is not). The inputs are generated, never committed:
#   - scene and samples files: cargo run --release -p sct-format --example hostile_inputs
#   - meshes: scripts/hostile_meshes.py
#   - scene.json files: below
# Usage: scripts/hostile-bounds.sh [DIR]    (DIR keeps the inputs; default a temporary one)
set -uo pipefail
cd "$(dirname "$0")/.."
bin=target/release
dir=${1:-$(mktemp -d)}
mkdir -p "$dir"
cargo build --release --quiet -p voxelize -p build-tree -p inspect -p render-preview
cargo run --release --quiet -p sct-format --example hostile_inputs -- "$dir" > /dev/null
python3 scripts/hostile_meshes.py "$dir" > /dev/null
echo '{"root": {"grid": {"child": {"mesh": 0}, "nx": 16384, "nz": 16384}}}' > "$dir/grid.json"
echo '{"root": {"grid": {"child": {"mesh": 0}, "nx": 2048, "nz": 1024}}}' > "$dir/grid-max.json"
# 60 groups, each over the previous one twice (2^60 paths), built by sct-build-tree itself.
python3 -c '
import json
defs = {"g0": {"mesh": 0}}
for k in range(1, 61):
    defs["g%d" % k] = {"group": [{"ref": "g%d" % (k - 1)}, {"ref": "g%d" % (k - 1)}]}
print(json.dumps({"defs": defs, "root": {"ref": "g60"}}))' > "$dir/dag.json"
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT

# run LABEL CMD...: one line "LABEL  exit  wall s  peak MB  end of stderr"
run() {
    local label=$1
    shift
    /usr/bin/time -v -o "$out/time" timeout 120 "$@" > "$out/stdout" 2> "$out/stderr"
    local rc=$?
    local wall rss
    wall=$(awk -F': ' '/Elapsed \(wall clock\)/ {n = split($2, t, ":"); s = 0; for (i = 1; i <= n; i++) s = s * 60 + t[i]; print s}' "$out/time")
    rss=$(awk -F': ' '/Maximum resident set size/ {printf "%.0f", $2 / 1024}' "$out/time")
    printf '%-50s exit %3s %6.2f s %5s MB  %s\n' "$label" "$rc" "$wall" "$rss" "$(tail -c 100 "$out/stderr" | tr '\n' ' ')"
}

echo "## sct-voxelize (default flags)"
for m in comb.obj comb.ply ngon-repeat.obj stacked.ply spread.ply points-coincident.ply points-1000.ply claims.ply dag.gltf nodes.gltf; do
    run "sct-voxelize $m" "$bin/sct-voxelize" "$dir/$m" -o "$out/m.samples"
done

echo "## sct-build-tree (default flags)"
for s in samples-coincident samples-line samples-inst samples-affine; do
    run "sct-build-tree $s.samples" "$bin/sct-build-tree" "$dir/$s.samples" -o "$out/s.sct"
done
"$bin/sct-voxelize" "$dir/stacked.ply" -o "$dir/small.samples" > /dev/null 2>&1
run "sct-build-tree --scene grid.json (2^28 cells)" "$bin/sct-build-tree" "$dir/small.samples" --scene "$dir/grid.json" -o "$out/g.sct"
run "sct-build-tree --scene grid-max.json (2^21 cells)" "$bin/sct-build-tree" "$dir/small.samples" --scene "$dir/grid-max.json" -o "$out/g.sct"
run "sct-build-tree --scene dag.json (60 levels)" "$bin/sct-build-tree" "$dir/small.samples" --scene "$dir/dag.json" -o "$dir/dag-built.sct"

echo "## sct-inspect and sct-render-preview (default flags)"
for f in tree-identical dag dag-built inlines; do
    run "sct-inspect $f.sct" "$bin/sct-inspect" "$dir/$f.sct"
    run "sct-inspect --validate $f.sct" "$bin/sct-inspect" "$dir/$f.sct" --validate
    run "sct-inspect --deep $f.sct" "$bin/sct-inspect" "$dir/$f.sct" --deep
    run "sct-inspect --export-ply $f.sct" "$bin/sct-inspect" "$dir/$f.sct" --export-ply "$out/e.ply"
    run "sct-inspect --dump $f.sct" "$bin/sct-inspect" "$dir/$f.sct" --dump
    run "sct-render-preview $f.sct" "$bin/sct-render-preview" "$dir/$f.sct" -o "$out/r.png"
    for m in gauss canopy parilov wald wand; do
        run "sct-render-preview --method $m $f.sct" "$bin/sct-render-preview" "$dir/$f.sct" -o "$out/r.png" --method "$m"
    done
done
for s in samples-coincident samples-line samples-inst samples-affine; do
    run "sct-inspect --export-ply $s.samples" "$bin/sct-inspect" "$dir/$s.samples" --export-ply "$out/e.ply"
done
