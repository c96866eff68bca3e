#!/usr/bin/env bash
# Measures where the time of the two speed goals goes (BENCHMARKS.md, "What blocks the 5 M
# leaves/s goal" under "Build tree" and "What blocks the 30 M samples/s goal" under "Voxelize"):
#   - sct-build-tree on the Table-8 bunny samples, default and raw profiles, per phase, with
#     2 threads (RUNS runs, medians) and 1 thread (one run: the phases' CPU cost);
#   - sct-voxelize dense runs (bunny, textured spot; voxel and scan-line methods), dry and
#     writing (RUNS runs, medians): the writer's cost is the CPU difference of the two.
# Every output is removed and synced before each run: replacing a file makes the next run
# pay the release of its page cache.
# Usage: scripts/speed-floor.sh [RUNS]     (needs ../shared/models beside the repository)
set -euo pipefail
cd "$(dirname "$0")/.."
runs=${1:-5}
models=../shared/models
bin=target/release
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
cargo build --release --quiet -p voxelize -p build-tree
bunny=$models/scans/stanford-bunny/stanford-bunny.obj
spot=$models/textured-obj/spot
"$bin/sct-voxelize" "$bunny" -o "$tmp/t8.samples" --density eq16 --k 3 --gamma 2 > /dev/null

# arithmetic on the arguments, e.g. calc "$a + $b"
calc() { awk "BEGIN {print $*}"; }
# median of the numbers on stdin
median() { sort -g | awk '{v[NR] = $1} END {print (NR % 2) ? v[(NR + 1) / 2] : (v[NR / 2] + v[NR / 2 + 1]) / 2}'; }
# value of a numeric JSON field (the outputs are flat enough for this)
field() { grep -o "\"$1\": *[0-9.e+-]*" "$2" | head -1 | sed 's/.*: *//'; }

echo "## sct-build-tree, Table-8 bunny samples (k = 3, gamma = 2)"
for threads in 2 1; do
  n=$runs; [ "$threads" = 1 ] && n=1
  for profile in default raw; do
    : > "$tmp/rows"
    for _ in $(seq "$n"); do
      rm -f "$tmp/b.sct"; sync
      RAYON_NUM_THREADS=$threads /usr/bin/time -f "%e %U %S %M" -o "$tmp/time" \
        "$bin/sct-build-tree" "$tmp/t8.samples" -o "$tmp/b.sct" --json --profile "$profile" > "$tmp/j.json"
      read -r wall user sys kib < "$tmp/time"
      leaves=$(field leaves "$tmp/j.json")
      echo "$(for p in read partition layout attributes write; do field "$p" "$tmp/j.json"; done | tr '\n' ' ')$wall $(calc "$user + $sys") $kib $leaves" >> "$tmp/rows"
    done
    printf '%s threads, %-7s (median of %s):' "$threads" "$profile" "$n"
    i=1
    for name in read partition layout attributes write wall cpu; do
      printf ' %s %.3f' "$name" "$(cut -d' ' -f$i "$tmp/rows" | median)"; i=$((i + 1))
    done
    leaves=$(cut -d' ' -f9 "$tmp/rows" | head -1)
    cpu=$(cut -d' ' -f7 "$tmp/rows" | median)
    printf ' s, peak %s KiB, %s leaves, %.0f CPU-ns per leaf (5 M leaves/s on 2 cores allows 400)\n' \
      "$(cut -d' ' -f8 "$tmp/rows" | median)" "$leaves" "$(calc "$cpu * 1e9 / $leaves")"
  done
done
rm -f "$tmp/b.sct" "$tmp/t8.samples"

echo "## sct-voxelize, dense runs"
vox() {
  local label=$1; shift
  for mode in dry write; do
    : > "$tmp/rows"
    for _ in $(seq "$runs"); do
      local out=(); [ "$mode" = dry ] && out=(--dry-run)
      rm -f "$tmp/x.samples"; sync
      /usr/bin/time -f "%e %U %S %M" -o "$tmp/time" "$bin/sct-voxelize" "$@" -o "$tmp/x.samples" "${out[@]}" --json > "$tmp/v.json"
      read -r wall user sys kib < "$tmp/time"
      echo "$wall $(calc "$user + $sys") $kib $(field samples "$tmp/v.json") $(field samples_per_second "$tmp/v.json")" >> "$tmp/rows"
    done
    local samples wall cpu
    samples=$(cut -d' ' -f4 "$tmp/rows" | head -1)
    wall=$(cut -d' ' -f1 "$tmp/rows" | median)
    cpu=$(cut -d' ' -f2 "$tmp/rows" | median)
    printf '%-12s %-5s %s samples: sampling %.2f M/s, whole command %.2f s = %.2f M/s, CPU %s s = %.0f ns per sample (30 M/s on 2 cores allows 67), peak %s KiB\n' \
      "$label" "$mode" "$samples" "$(cut -d' ' -f5 "$tmp/rows" | median | awk '{print $1 / 1e6}')" "$wall" \
      "$(calc "$samples / $wall / 1e6")" "$cpu" "$(calc "$cpu * 1e9 / $samples")" "$(cut -d' ' -f3 "$tmp/rows" | median)"
  done
  rm -f "$tmp/x.samples"
}
vox bunny-voxel "$bunny" --voxel-size 6e-5
vox bunny-scan "$bunny" --voxel-size 4e-5 --method scanline
vox spot-voxel "$spot/spot_triangulated.obj" --texture "$spot/spot_texture.png" --voxel-size 6e-4
vox spot-scan "$spot/spot_triangulated.obj" --texture "$spot/spot_texture.png" --voxel-size 4.5e-4 --method scanline
