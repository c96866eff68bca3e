#!/usr/bin/env python3
"""The 1 -> 2 thread speed-up of sct-voxelize (BENCHMARKS.md, "Voxelize", "Threads"): each
binary on each mesh with RAYON_NUM_THREADS=1 and 2, interleaved (the order of binaries and
thread counts alternating between rounds), the output removed and synced before every run;
medians of wall and CPU (user + system) over the rounds, and the load average.

Give two binaries (--bin OLD --bin NEW) to compare builds in one run; the outputs of every
binary and thread count are compared byte for byte with the first one's (a difference is an
error).

On a shared machine, --quiet S waits (at most S seconds) before every run for 0.3 s in
which the CPUs were at least 90 % idle, and says how many runs started without one.

Usage: scripts/voxelize-threads.py [--rounds N] [--quiet S] [--bin PATH]... MESH...
       (default: 7 rounds, no waiting, target/release/sct-voxelize; build it first)
"""

import argparse
import filecmp
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def timed(cmd, env):
    """(wall s, CPU s) of one run of `cmd`, a child process; raises on failure."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    r = subprocess.run(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if r.returncode != 0:
        raise RuntimeError(f"{' '.join(map(str, cmd))}: exit {r.returncode}: {r.stderr.decode()[-400:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu


def idle_fraction(seconds=0.3):
    """Share of CPU time spent idle over the next `seconds` (/proc/stat)."""
    def snap():
        with open("/proc/stat") as f:
            v = [int(x) for x in f.readline().split()[1:]]
        return v[3] + v[4], sum(v)
    a = snap()
    time.sleep(seconds)
    b = snap()
    return (b[0] - a[0]) / max(1, b[1] - a[1])


def wait_quiet(limit):
    """Waits up to `limit` seconds for a quiet moment; whether one came."""
    end = time.time() + limit
    while time.time() < end:
        if idle_fraction() >= 0.9:
            return True
    return False


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--rounds", type=int, default=7)
    ap.add_argument("--bin", type=Path, action="append")
    ap.add_argument("--quiet", type=float, default=0.0)
    ap.add_argument("meshes", type=Path, nargs="+")
    a = ap.parse_args()
    bins = a.bin or [Path("target/release/sct-voxelize")]
    runs = {}  # (mesh, bin, threads) -> [(wall, cpu)]
    loads = []
    noisy = 0
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        for rnd in range(a.rounds):
            flip = rnd % 2 == 1
            for mesh in a.meshes:
                jobs = [(b, t) for b in range(len(bins)) for t in ("1", "2")]
                for b, t in reversed(jobs) if flip else jobs:
                    dst = out / f"{mesh.stem}.{b}.{t}.samples"
                    dst.unlink(missing_ok=True)
                    os.sync()
                    env = dict(os.environ, RAYON_NUM_THREADS=t)
                    if a.quiet > 0 and not wait_quiet(a.quiet):
                        noisy += 1
                    runs.setdefault((mesh, b, t), []).append(timed([bins[b], mesh, "-o", dst], env))
                    first = out / f"{mesh.stem}.0.1.samples"
                    if first.exists() and not filecmp.cmp(first, dst, shallow=False):
                        sys.exit(f"{mesh}: {bins[b]} on {t} threads wrote other bytes than {bins[0]} on 1 thread")
            loads.append(os.getloadavg()[0])
            print(f"round {rnd + 1}/{a.rounds} done", file=sys.stderr)

    def med(key, i):
        return statistics.median(r[i] for r in runs[key])

    print(f"voxelize threads: {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, {os.cpu_count()} cores, "
          f"{a.rounds} rounds, load average (1 min, after each round) {min(loads):.2f}-{max(loads):.2f}"
          + (f", {noisy} runs started without a quiet 0.3 s" if a.quiet > 0 else ""))
    print()
    print("| mesh | binary | 1 thread s | 2 threads s | speed-up | CPU s, 1 / 2 threads |")
    print("|---|---|---:|---:|---:|---:|")
    for mesh in a.meshes:
        for b, path in enumerate(bins):
            one, two = med((mesh, b, "1"), 0), med((mesh, b, "2"), 0)
            c1, c2 = med((mesh, b, "1"), 1), med((mesh, b, "2"), 1)
            print(f"| {mesh.name} | {path} | {one:.3f} | {two:.3f} | {one / two:.2f}× | {c1:.3f} / {c2:.3f} |")


if __name__ == "__main__":
    main()
