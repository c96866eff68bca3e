#!/usr/bin/env bash
# The paper anchors of BENCHMARKS.md ("Paper anchors"): every preview method at its default
# knob against the figures its paper reports.
#   a) one model: the densest shared scan (the 100k-triangle dragon) at 640 × 480, front,
#      against its mesh — Wand's Table 2 (Happy Buddha, d = 2: 0.44 s against a 1.18 s
#      z-buffer) as wand d = 1 / 2 over zbuffer, by default and with every leaf sampled
#      (--wand-large inf); parilov's samples/s and wald's splats per ray from the same frames;
#   b) the 600 × 600 grid of the 948-triangle bunny (thesis Table 16: 2.2 s per frame),
#      1280 × 1024, iso, every method (no mesh reference: 341 M triangles);
#   c) wand's output sensitivity: the grid against one instance framed to cover as many
#      pixels (Wand: the city 100 × 100 took about 4× the single city);
# each frame RUNS times, interleaved by method; the median of `seconds.total` (open, refine,
# draw), one Markdown table per part. The error on a grid (a 30 × 30 one, whose mesh
# reference fits in memory) comes from `scripts/compare.sh`-style runs, see BENCHMARKS.md.
# Not part of CI. Usage: scripts/anchors.sh [RUNS] [OUT_DIR]   (default 3 runs, out/anchors)
set -euo pipefail
cd "$(dirname "$0")/.."
runs=${1:-3}
out=${2:-out/anchors}
m=../shared/models/scans
cargo build --release -p render-preview --quiet
target_dir=$(cargo metadata --format-version 1 --no-deps | python3 -c 'import json,sys; print(json.load(sys.stdin)["target_directory"])')
bin="$target_dir/release/sct-render-preview"
mkdir -p "$out"
echo "anchors: $(date -u '+%Y-%m-%d %H:%M UTC'), $(git rev-parse --short HEAD), $(nproc) cores, load $(cut -d' ' -f1 /proc/loadavg)" >&2
dragon="$m/stanford-dragon-100k/dragon.ply"
bunny="$m/stanford-bunny-original-ply/bun_zipper_res4.ply"
"$bin" synth "$dragon" -o "$out/dragon.sct" >&2
"$bin" synth "$bunny" -o "$out/bunny.sct" >&2
"$bin" synth "$bunny" -o "$out/grid600.sct" --grid 600 >&2
python3 - "$bin" "$runs" "$out" "$dragon" <<'PY'
import json, math, statistics, subprocess, sys
bin, runs, out, dragon = sys.argv[1], int(sys.argv[2]), sys.argv[3], sys.argv[4]

def frame(tag, sct, args):
    """One render; its JSON."""
    p = subprocess.run([bin, sct, "-o", f"{out}/{tag}.png", "--json", *args], capture_output=True, text=True)
    if p.returncode != 0:
        return {"failed": p.stderr.strip().splitlines()[-1] if p.stderr.strip() else f"exit {p.returncode}"}
    return json.loads(p.stdout)

def interleaved(cases):
    """cases: tag -> (sct, args). RUNS rounds over every case; per case the median total and the last JSON."""
    secs, last = {t: [] for t in cases}, {}
    for _ in range(runs):
        for t, (sct, args) in cases.items():
            j = frame(t, sct, args)
            last[t] = j
            if "failed" not in j:
                secs[t].append(j["seconds"]["total"])
    return {t: (statistics.median(secs[t]) if secs[t] else None, min(secs[t], default=None), max(secs[t], default=None), last[t]) for t in cases}

def ms(r):
    med, lo, hi, _ = r
    return "failed" if med is None else f"{med * 1e3:,.0f} ({lo * 1e3:,.0f}–{hi * 1e3:,.0f})"

def extra(j):
    """The method's own counters worth a column."""
    if "failed" in j:
        return j["failed"][:90]
    if j.get("wand"):
        s = j["wand"]["stats"]
        return f"{s['samples']:,} samples ({s['samples_per_covered_pixel']:.1f}/covered px), {s['leaf_splats'] + s['other_splats']:,} splats, {s['boxes']:,} boxes"
    if j.get("parilov"):
        s = j["parilov"]["stats"]
        return f"{s['samples']:,} samples, {s['samples_per_second'] / 1e6:.2f} M samples/s, re-sorted {s['resort_fraction'] * 100:.1f} % of {s['cells']:,} cells"
    if j.get("wald"):
        s = j["wald"]["stats"]
        return f"{s['splats_per_ray']:.2f} splats/ray ({s['splats_per_ray'] * s['rays'] / max(s['hits'], 1):.1f} per hit), {s['nodes_per_ray']:.1f} nodes/ray, {s['rays_per_second'] / 1e6:.2f} M rays/s"
    if j.get("canopy"):
        return "t3 default"
    return ""

def metrics(j):
    if "failed" in j or not j.get("metrics"):
        return "– | – | –"
    mt = j["metrics"]
    f = lambda v, d: "–" if v is None else f"{v:.{d}f}"
    return f"{f(mt['fg_psnr_db'], 2)} | {f(mt['fg_ssim'], 3)} | {mt['silhouette_iou']:.4f}"

# a) one model.
size = ["--width", "640", "--height", "480"]
ref = ["--reference", dragon]
one = {m: (f"{out}/dragon.sct", ["--method", m, *size, *ref]) for m in ["zbuffer", "gauss", "canopy", "parilov", "wald", "wand"]}
one["wand d=1"] = (f"{out}/dragon.sct", ["--method", "wand", "--wand-d", "1", *size, *ref])
one["wand d=1, sampled"] = (f"{out}/dragon.sct", ["--method", "wand", "--wand-d", "1", "--wand-large", "inf", *size, *ref])
one["wand d=2, sampled"] = (f"{out}/dragon.sct", ["--method", "wand", "--wand-d", "2", "--wand-large", "inf", *size, *ref])
ra = interleaved(one)
z = ra["zbuffer"][0]
print(f"\na) dragon (100,000 triangles, `synth` leaves), 640 × 480, front, against the mesh, median of {runs}\n")
print("| method | ms (min–max) | ÷ zbuffer | fg PSNR | fg SSIM | IoU | primitives | own counters |")
print("|---|---|---|---|---|---|---|---|")
for t, r in ra.items():
    j = r[3]
    ratio = "–" if r[0] is None or not z else f"{r[0] / z:.2f}"
    prim = "–" if "failed" in j else f"{j['work']['primitives']:,}"
    print(f"| {t} | {ms(r)} | {ratio} | {metrics(j)} | {prim} | {extra(j)} |")

# b) the 600 × 600 grid.
big = ["--view", "iso", "--width", "1280", "--height", "1024", "--max-nodes", "200000000"]
grid = {m: (f"{out}/grid600.sct", ["--method", m, *big]) for m in ["zbuffer", "gauss", "canopy", "parilov", "wald", "wand"]}
rb = interleaved(grid)
print(f"\nb) 600 × 600 grid (360,000 instances of one 688,757-leaf tree), 1280 × 1024, iso, median of {runs} (thesis Table 16: 2.2 s)\n")
print("| method | ms (min–max) | primitives | nodes visited | covered px | own counters |")
print("|---|---|---|---|---|---|")
for t, r in rb.items():
    j = r[3]
    w = j.get("work", {})
    print(f"| {t} | {ms(r)} | {w.get('primitives', 0):,} | {w.get('nodes_visited', 0):,} | {w.get('covered_pixels', 0):,} | {extra(j)} |")

# c) wand's output sensitivity: one instance from the grid's direction, moved until it
# covers the grid's pixels (coverage goes with 1/distance²; two corrections).
gz = rb["zbuffer"][3]
target_px = gz["work"]["covered_pixels"]
base = frame("one-iso", f"{out}/bunny.sct", ["--method", "zbuffer", *big])
cam = base["camera"]
eye, tgt, cov = cam["eye"], cam["target"], base["work"]["covered_pixels"]
for _ in range(2):
    s = math.sqrt(cov / target_px)
    eye = [t + (e - t) * s for e, t in zip(eye, tgt)]
    cov = frame("one-iso", f"{out}/bunny.sct", ["--method", "zbuffer", *big, "--eye", ",".join(map(str, eye)), "--target", ",".join(map(str, tgt))])["work"]["covered_pixels"]
cam1 = ["--eye", ",".join(map(str, eye)), "--target", ",".join(map(str, tgt))]
sens = {}
for label, args in [("zbuffer", ["--method", "zbuffer"]), ("wand", ["--method", "wand"]), ("wand, sampled", ["--method", "wand", "--wand-large", "inf"])]:
    sens[f"grid {label}"] = (f"{out}/grid600.sct", [*args, *big])
    sens[f"one {label}"] = (f"{out}/bunny.sct", [*args, *big, *cam1])
rc = interleaved(sens)
print(f"\nc) output sensitivity: the 600 × 600 grid against one instance covering {cov:,} px (grid {target_px:,} px by zbuffer), 1280 × 1024, median of {runs}\n")
print("| method | grid ms | one ms | grid ÷ one | grid counters | one counters |")
print("|---|---|---|---|---|---|")
for label in ["zbuffer", "wand", "wand, sampled"]:
    g, o = rc[f"grid {label}"], rc[f"one {label}"]
    ratio = "–" if g[0] is None or o[0] is None else f"{g[0] / o[0]:.2f}"
    print(f"| {label} | {ms(g)} | {ms(o)} | {ratio} | {extra(g[3]) or format(g[3]['work']['primitives'], ',') + ' splats'} | {extra(o[3]) or format(o[3]['work']['primitives'], ',') + ' splats'} |")
PY
