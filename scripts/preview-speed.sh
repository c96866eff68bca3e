#!/usr/bin/env bash
# The preview speed table of BENCHMARKS.md ("Render preview"): `sct-render-preview` at its
# defaults (1280 × 720, zbuffer, 3 × 3 subpixels, --pixel-error 0.75) on a 3.7 M-leaf bunny,
# on 600 × 600 tinted instances of a 689 k-leaf bunny and on one instance of it, RUNS runs
# each, interleaved; medians of the library's `seconds.total` and of the process wall time,
# with the splats, nodes visited and bytes read of the last run, and the load average.
# Usage: scripts/preview-speed.sh [RUNS] [DIR]   (default 7, a temporary directory; needs
#        ../shared/models beside the repository)
set -euo pipefail
cd "$(dirname "$0")/.."
runs=${1:-7}
dir=${2:-$(mktemp -d)}
mkdir -p "$dir"
cargo build --release --quiet -p render-preview
bin=target/release/sct-render-preview
ply=../shared/models/scans/stanford-bunny-original-ply
[ -f "$dir/bunny3m.sct" ] || "$bin" synth "$ply/bun_zipper.ply" -o "$dir/bunny3m.sct" --spacing 0.000265 > /dev/null
[ -f "$dir/grid600.sct" ] || "$bin" synth "$ply/bun_zipper_res4.ply" -o "$dir/grid600.sct" --grid 600 > /dev/null
[ -f "$dir/grid1.sct" ] || "$bin" synth "$ply/bun_zipper_res4.ply" -o "$dir/grid1.sct" --grid 1 > /dev/null

exec python3 - "$bin" "$dir" "$runs" <<'EOF'
import json, statistics, subprocess, sys, time
from datetime import datetime, timezone
bin_, d, runs = sys.argv[1], sys.argv[2], int(sys.argv[3])
cases = [
    ("bunny 3.72 M leaves, front", ["bunny3m.sct"]),
    ("same, `--lod-size sphere` (EQ 46 cut)", ["bunny3m.sct", "--lod-size", "sphere"]),
    ("600 × 600 instances of a 689 k-leaf bunny, iso", ["grid600.sct", "--view", "iso"]),
    ("1 instance of the same bunny, iso", ["grid1.sct", "--view", "iso"]),
]
load0 = open("/proc/loadavg").read().split()[0]
lib, wall, last = {}, {}, {}
for r in range(runs):
    for name, args in (cases if r % 2 == 0 else cases[::-1]):
        cmd = [bin_, f"{d}/{args[0]}", "-o", f"{d}/out.png", "--json", *args[1:]]
        t = time.monotonic()
        out = subprocess.run(cmd, check=True, capture_output=True).stdout
        wall.setdefault(name, []).append(time.monotonic() - t)
        j = json.loads(out)
        lib.setdefault(name, []).append(j["seconds"]["total"])
        last[name] = j
load1 = open("/proc/loadavg").read().split()[0]
when = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
print(f"preview-speed: {when}, {runs} runs each, load average {load0} at the start, {load1} at the end\n")
print("| run (1280 × 720, default options) | splats | nodes visited | bytes read / file | library total (median) | raster (last run) | process wall (median) |")
print("|---|---:|---:|---|---:|---:|---:|")
for name, _ in cases:
    j = last[name]
    mb = lambda b: f"{b / 1e6:.1f}"
    print(f"| {name} | {j['splats']:,} | {j['nodes_visited']:,} | {mb(j['bytes_read'])} / {mb(j['file_size'])} MB | "
          f"{statistics.median(lib[name]):.2f} s | {j['seconds']['raster']:.2f} s | {statistics.median(wall[name]):.2f} s |")
EOF
