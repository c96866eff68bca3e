"""Driver of scripts/peers.sh: runs our tools and the installed peers interleaved on the same
inputs and prints the peers table of BENCHMARKS.md. Run it through peers.sh, which installs
the peers and builds our tools first.

Tasks (the peers each do the same job as ours, on the same input, for the same point count):
  mesh -> points   sct-voxelize (default density)   vs open3d sample_points_uniformly,
                                                       trimesh sample_surface (N = our samples)
  points -> LOD    sct-build-tree on those samples  vs copc_converter on a LAS of them;
                   also the dragon voxelized finer (2.1 M and 8.3 M samples), LOD task only;
                   ours also without the centre offsets and leaf refinement that put leaves
                   back on their surface (--no-centre-offsets --leaf-refinement off)
  dense mesh       sct-build-tree, one step         vs open3d and trimesh mesh -> points,
                   the same mesh as binary PLY, OBJ and GLB
  load and prepare sct-voxelize --dry-run --screen-error 60 on the dense mesh: a few hundred
                   samples, so the time and memory are the triangles' (the cost per triangle)
  threads          ours with 1 and 2 threads (RAYON_NUM_THREADS), and the machine's ceiling:
                   a CPU-only loop split over 1 or 2 processes
Every run is a whole process timed by /usr/bin/time (wall, user + system CPU, peak RSS).
Outputs are removed before each run. Medians over the rounds; a round runs every tool once,
the order of ours and the peers alternating between rounds.
"""

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

# The dry run's leaf size in pixels of the default view: about 460 samples of the dense mesh.
COARSE = "60"

PY_SAMPLE = {
    "open3d": """
import sys, open3d as o3d
m = o3d.io.read_triangle_mesh(sys.argv[1])
m.compute_triangle_normals()
p = m.sample_points_uniformly(int(sys.argv[2]))
o3d.io.write_point_cloud(sys.argv[3], p, write_ascii=False)
""",
    "trimesh": """
import sys, trimesh
m = trimesh.load(sys.argv[1], force="mesh", process=False)
pts, face = trimesh.sample.sample_surface(m, int(sys.argv[2]))
trimesh.PointCloud(pts).export(sys.argv[3])
""",
}


# The machine's own 1 -> 2 ceiling: a fixed amount of CPU-only work (no shared data, no
# memory traffic) split over 1 or 2 processes. On a shared VM two busy vCPUs do not each run
# at the speed of one.
CPU_LOOP = """
import sys, multiprocessing as mp
def spin(n):
    x = 0
    for i in range(n):
        x += i * i
    return x
k = int(sys.argv[1])
with mp.get_context("fork").Pool(k) as p:
    p.map(spin, [24_000_000 // k] * k)
"""


def timed(cmd, env=None):
    """(wall s, CPU s, peak RSS MB) of one run of `cmd`; raises on failure."""
    tfile = "/tmp/peers-time.txt"
    full = ["/usr/bin/time", "-f", "%e %U %S %M", "-o", tfile] + [str(c) for c in cmd]
    r = subprocess.run(full, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env)
    if r.returncode != 0:
        raise RuntimeError(f"{' '.join(map(str, cmd))}: exit {r.returncode}: {r.stderr.decode()[-400:]}")
    wall, user, sys_, rss = open(tfile).read().split()[-4:]
    return float(wall), float(user) + float(sys_), int(rss) / 1024.0


def clear(*paths):
    for p in paths:
        Path(p).unlink(missing_ok=True)
    os.sync()


def make_dense(py, src, out):
    """The bunny subdivided three times (each triangle into four), as binary PLY, OBJ and GLB:
    {format: path}."""
    paths = {"PLY": out / "dense-bunny.ply", "OBJ": out / "dense-bunny.obj", "GLB": out / "dense-bunny.glb"}
    if all(p.exists() for p in paths.values()):
        return paths
    code = """
import sys, trimesh
m = trimesh.load(sys.argv[1], force="mesh", process=False)
for _ in range(3):
    m = m.subdivide()
m.export(sys.argv[2], encoding="binary")
m.export(sys.argv[3])
m.export(sys.argv[4])
"""
    subprocess.run([py, "-c", code, str(src), *map(str, paths.values())], check=True)
    return paths


def write_las(py, ply, las):
    """A LAS 1.4 file (point format 7: xyz, rgb) of an exported leaf PLY, 0.01 mm steps."""
    code = """
import sys, numpy as np, laspy
f = open(sys.argv[1], "rb")
n = 0
while True:
    l = f.readline()
    if l.startswith(b"element vertex"):
        n = int(l.split()[2])
    if l.strip() == b"end_header":
        break
dt = np.dtype([("p", "<f4", 3), ("n", "<f4", 3), ("c", "u1", 4), ("r", "<f4")])
a = np.frombuffer(f.read(n * dt.itemsize), dt)
h = laspy.LasHeader(point_format=7, version="1.4")
h.offsets = a["p"].min(0).astype(float)
h.scales = [1e-5] * 3
las = laspy.LasData(h)
las.x, las.y, las.z = (a["p"][:, k].astype(float) for k in range(3))
las.red, las.green, las.blue = (a["c"][:, k].astype(np.uint16) * 257 for k in range(3))
las.write(sys.argv[2])
"""
    subprocess.run([py, "-c", code, str(ply), str(las)], check=True)


# Repetitions of the 1- and 2-thread runs in every round.
THREAD_REPS = 3

CEILING = "CPU-only loop, 1 or 2 processes (the machine's ceiling)"

# Ours without the on-surface features (centre offsets, leaf refinement): the tree of the
# thesis's quantizers alone, still with normal, cone, radius and area per node.
OFF_SURFACE = "ours, offsets and refinement off"
OFF_FLAGS = ["--no-centre-offsets", "--leaf-refinement", "off"]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--bin", type=Path, required=True)
    ap.add_argument("--copc", type=Path, required=True)
    ap.add_argument("--models", type=Path, required=True)
    a = ap.parse_args()
    out, bin_, py = a.out, a.bin, sys.executable
    vox, build, inspect = bin_ / "sct-voxelize", bin_ / "sct-build-tree", bin_ / "sct-inspect"
    m = a.models
    meshes = {
        "bunny": m / "scans/stanford-bunny-original-ply/bun_zipper.ply",
        "dragon": m / "scans/stanford-dragon-100k/dragon.ply",
        "spot (textured)": m / "textured-obj/spot/spot_triangulated.obj",
    }
    dense = make_dense(py, meshes["bunny"], out)
    dense_tris = 69451 * 64

    # Preparation (untimed): our sample counts, the LAS inputs of the LOD task.
    def prepare(mesh, key, flags=()):
        """Our samples of `mesh` and a LAS of the leaves built from them: (samples, count, LAS)."""
        smp = out / f"{key}.samples"
        r = subprocess.run([vox, mesh, "-o", smp, "--json", *flags], check=True, capture_output=True)
        n = json.loads(r.stdout)["samples"]
        sct = out / f"{key}.sct"
        subprocess.run([build, smp, "-o", sct], check=True, capture_output=True)
        ply = out / f"{key}.leaves.ply"
        subprocess.run([inspect, sct, "--export-ply", ply], check=True, capture_output=True)
        las = out / f"{key}.las"
        write_las(py, ply, las)
        ply.unlink()
        return smp, n, las

    prep = {}
    for name, mesh in meshes.items():
        prep[name] = (mesh, *prepare(mesh, name.split()[0]))
    # Larger point sets for the LOD task: the dragon voxelized finer.
    large = {
        "dragon, finer": ["--screen-error", "0.7"],
        "dragon, finest": ["--screen-error", "0.35", "--sample-budget", "20000000"],
    }
    for name, flags in large.items():
        key = name.replace(", ", "-")
        large[name] = (key, *prepare(meshes["dragon"], key, flags))
    dense_n = {}
    for fmt, path in dense.items():
        r = subprocess.run([build, path, "-o", out / "dense.sct", "--json"], check=True, capture_output=True)
        dense_n[fmt] = json.loads(r.stdout)["build"]["leaves"]
    dense_input = {fmt: f"bunny x64 (4.4 M tris), {fmt}" for fmt in dense}

    runs = {}  # (task, input, tool) -> list of (wall, cpu, rss)
    size = {}  # (task, input, tool) -> (bytes, points)

    def run(key, cmd, output, points, env=None):
        clear(output)
        runs.setdefault(key, []).append(timed(cmd, env))
        size[key] = (Path(output).stat().st_size, points)

    for rnd in range(a.rounds):
        flip = rnd % 2 == 1
        for name, (mesh, smp, n, las) in prep.items():
            key = name.split()[0]
            jobs = [
                (("mesh -> points", name, "ours"), [vox, mesh, "-o", out / f"{key}.t.samples"], out / f"{key}.t.samples"),
                (("mesh -> points", name, "open3d"), [py, "-c", PY_SAMPLE["open3d"], mesh, n, out / f"{key}.o3d.ply"], out / f"{key}.o3d.ply"),
                (("mesh -> points", name, "trimesh"), [py, "-c", PY_SAMPLE["trimesh"], mesh, n, out / f"{key}.tm.ply"], out / f"{key}.tm.ply"),
                (("points -> LOD", name, "ours"), [build, smp, "-o", out / f"{key}.t.sct"], out / f"{key}.t.sct"),
                (("points -> LOD", name, OFF_SURFACE), [build, smp, "-o", out / f"{key}.n.sct", *OFF_FLAGS], out / f"{key}.n.sct"),
                (("points -> LOD", name, "copc_converter"), [a.copc, las, out / f"{key}.copc.laz"], out / f"{key}.copc.laz"),
            ]
            for key_, cmd, output in (reversed(jobs) if flip else jobs):
                run(key_, cmd, output, n)
        for name, (key, smp, n, las) in large.items():
            jobs = [
                (("points -> LOD", name, "ours"), [build, smp, "-o", out / f"{key}.t.sct"], out / f"{key}.t.sct"),
                (("points -> LOD", name, OFF_SURFACE), [build, smp, "-o", out / f"{key}.n.sct", *OFF_FLAGS], out / f"{key}.n.sct"),
                (("points -> LOD", name, "copc_converter"), [a.copc, las, out / f"{key}.copc.laz"], out / f"{key}.copc.laz"),
            ]
            for key_, cmd, output in (reversed(jobs) if flip else jobs):
                run(key_, cmd, output, n)
        for fmt, path in dense.items():
            inp, n = dense_input[fmt], dense_n[fmt]
            dense_jobs = [
                (("dense mesh -> LOD / points", inp, "ours"), [build, path, "-o", out / "dense.t.sct"], out / "dense.t.sct"),
                (("dense mesh -> LOD / points", inp, "open3d"), [py, "-c", PY_SAMPLE["open3d"], path, n, out / "dense.o3d.ply"], out / "dense.o3d.ply"),
                (("dense mesh -> LOD / points", inp, "trimesh"), [py, "-c", PY_SAMPLE["trimesh"], path, n, out / "dense.tm.ply"], out / "dense.tm.ply"),
            ]
            for key_, cmd, output in (reversed(dense_jobs) if flip else dense_jobs):
                run(key_, cmd, output, n)
            # Loading and preparing alone, as the issue measured it: a dry run making a few
            # hundred samples, whose cost is the triangles', not the samples'.
            runs.setdefault(("load and prepare", inp, "ours"), []).append(timed([vox, path, "--dry-run", "--screen-error", COARSE]))
        # The thread runs are short (0.2-1.8 s), so each is repeated THREAD_REPS times a
        # round, 1 and 2 threads alternating: one slow moment of a shared machine then
        # moves one of several samples, not a median of three.
        for _ in range(THREAD_REPS):
            for threads in ("1", "2"):
                env = dict(os.environ, RAYON_NUM_THREADS=threads)
                mesh, smp, n, _ = prep["dragon"]
                run(("threads", "dragon, sct-voxelize", threads), [vox, mesh, "-o", out / "thr.samples"], out / "thr.samples", n, env)
                run(("threads", "dragon, sct-build-tree", threads), [build, smp, "-o", out / "thr.sct"], out / "thr.sct", n, env)
                runs.setdefault(("threads", CEILING, threads), []).append(timed([sys.executable, "-c", CPU_LOOP, threads]))
        print(f"round {rnd + 1}/{a.rounds} done", file=sys.stderr)

    def med(key, i):
        return statistics.median(r[i] for r in runs[key])

    print(f"peers: {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, {os.cpu_count()} cores, "
          f"{a.rounds} rounds, load average {os.getloadavg()[0]:.2f} at the end")
    print()
    print("| task | input | points | tool | wall s | CPU s | peak MB | B/point | ours faster |")
    print("|---|---|---:|---|---:|---:|---:|---:|---:|")
    for key in runs:
        task, inp, tool = key
        if task in ("threads", "load and prepare") or tool == OFF_SURFACE:
            continue
        b, pts = size[key]
        ours = med((task, inp, "ours"), 0)
        ratio = "—" if tool == "ours" else f"{med(key, 0) / ours:.2f}×"
        print(f"| {task} | {inp} | {pts:,} | {tool} | {med(key, 0):.2f} | {med(key, 1):.2f} | {med(key, 2):.0f} | {b / pts:.2f} | {ratio} |")
    print()
    print(f"| points -> LOD, {OFF_SURFACE} ({' '.join(OFF_FLAGS)}) | wall s | CPU s | B/point "
          "| copc_converter wall s | B/point | ours faster | ours ÷ copc_converter bytes |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    for key in runs:
        task, inp, tool = key
        if tool != OFF_SURFACE:
            continue
        peer = (task, inp, "copc_converter")
        (b, pts), (pb, _) = size[key], size[peer]
        print(f"| {inp} | {med(key, 0):.2f} | {med(key, 1):.2f} | {b / pts:.2f} | {med(peer, 0):.2f} | {pb / pts:.2f} "
              f"| {med(peer, 0) / med(key, 0):.2f}× | {b / pb:.2f} |")
    print()
    print(f"| dense mesh, ours | one step: µs wall per triangle | B peak per triangle | leaves "
          f"| load and prepare (dry run, --screen-error {COARSE}): µs wall per triangle | B peak per triangle |")
    print("|---|---:|---:|---:|---:|---:|")
    for fmt in dense:
        w, _, rss = (med(("dense mesh -> LOD / points", dense_input[fmt], "ours"), i) for i in range(3))
        lw, _, lrss = (med(("load and prepare", dense_input[fmt], "ours"), i) for i in range(3))
        print(f"| {dense_input[fmt]} | {w / dense_tris * 1e6:.2f} | {rss * 1048576 / dense_tris:.0f} | {dense_n[fmt]:,} "
              f"| {lw / dense_tris * 1e6:.2f} | {lrss * 1048576 / dense_tris:.0f} |")
    print()
    print(f"| threads ({a.rounds} × {THREAD_REPS} runs each, medians) | tool | 1 thread s | 2 threads s | speed-up |")
    print("|---|---|---:|---:|---:|")
    for inp in ("dragon, sct-voxelize", "dragon, sct-build-tree", CEILING):
        one, two = med(("threads", inp, "1"), 0), med(("threads", inp, "2"), 0)
        print(f"| 1 -> 2 | {inp} | {one:.2f} | {two:.2f} | {one / two:.2f}× |")


if __name__ == "__main__":
    main()
