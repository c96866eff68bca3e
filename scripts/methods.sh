#!/usr/bin/env bash
# "Every method at its defaults" of BENCHMARKS.md (Preview methods): each shared model made
# into an SCT file by `sct-render-preview synth` (leaves at 1/400 of the bounding diameter),
# then every --method at its defaults, RUNS frames each (interleaved by method), 512 × 512,
# against the mesh: the median of `seconds.total` (open, refine, draw) and the last frame's
# foreground PSNR, SSIM, IoU and primitives, one Markdown row per model and method.
# Not part of CI. Usage: [METHODS="zbuffer gauss"] scripts/methods.sh [RUNS] [OUT_DIR]
# (default every method, 3 runs, out/methods)
set -euo pipefail
cd "$(dirname "$0")/.."
runs=${1:-3}
out=${2:-out/methods}
m=../shared/models
cargo build --release -p render-preview --quiet
target_dir=$(cargo metadata --format-version 1 --no-deps | python3 -c 'import json,sys; print(json.load(sys.stdin)["target_directory"])')
bin="$target_dir/release/sct-render-preview"
mkdir -p "$out"
methods=${METHODS:-zbuffer gauss canopy parilov wald wand}
echo "methods: $(date -u '+%Y-%m-%d %H:%M UTC'), $(git rev-parse --short HEAD), $(nproc) cores, load $(cut -d' ' -f1 /proc/loadavg)" >&2
echo "| model (leaves) | method | ms | fg PSNR | fg SSIM | IoU | primitives |"
echo "|---|---|---|---|---|---|---|"
for mesh in "$m/gltf/Duck/glTF-Binary/Duck.glb" "$m/textured-obj/fuze/fuze.obj" "$m/scans/stanford-bunny-original-ply/bun_zipper.ply"; do
    name=$(basename "$mesh"); name=${name%.*}
    leaves=$("$bin" synth "$mesh" -o "$out/$name.sct" | sed -n 's/.*: \([0-9]*\) leaves.*/\1/p')
    declare -A secs=()
    for r in $(seq "$runs"); do
        for meth in $methods; do
            if "$bin" "$out/$name.sct" -o "$out/$name.$meth.png" --method "$meth" --width 512 --height 512 --reference "$mesh" --json > "$out/$name.$meth.json" 2> "$out/$name.$meth.err"; then
                secs[$meth]="${secs[$meth]:-} $(python3 -c 'import json,sys; print(json.load(open(sys.argv[1]))["seconds"]["total"])' "$out/$name.$meth.json")"
            else
                secs[$meth]="failed"
            fi
        done
    done
    first=1
    for meth in $methods; do
        label=$([ $first = 1 ] && python3 -c 'import sys; print(f"{sys.argv[1]} ({int(sys.argv[2]):,})")' "$name" "$leaves" || true)
        first=0
        if [ "${secs[$meth]}" = failed ]; then
            echo "| $label | $meth | failed: $(tail -c 120 "$out/$name.$meth.err" | tr '\n' ' ') | | | | |"
            continue
        fi
        python3 - "$label" "$meth" "$out/$name.$meth.json" ${secs[$meth]} <<'PY'
import json, statistics, sys
label, meth, path, *secs = sys.argv[1:]
j = json.load(open(path))
m = j["metrics"]
f = lambda v, d: "-" if v is None else f"{v:.{d}f}"
print(f"| {label} | {meth} | {statistics.median(map(float, secs)) * 1e3:.0f} | {f(m['fg_psnr_db'], 2)} | {f(m['fg_ssim'], 3)} | {m['silhouette_iou']:.3f} | {j['work']['primitives']:,} |")
PY
    done
    unset secs
done
