#!/usr/bin/env bash
# The peers table of BENCHMARKS.md ("Against the peers"): our tools and the peers that the
# package registries serve, on the same inputs with matched point counts, run interleaved
# (ROUNDS rounds, medians), as one Markdown table: wall, CPU, peak RSS, output bytes per
# point, ours/peer ratios, and the load average.
#
# Peers, installed here on first use (never in CI):
#   - open3d `sample_points_uniformly` and trimesh `sample_surface` (PyPI, a virtual
#     environment under OUT_DIR/venv): mesh -> points, whole process (load, sample, write);
#   - copc_converter (crates.io, `cargo install` into OUT_DIR/cargo): points -> LOD file
#     (COPC: an octree of LAZ chunks), fed a LAS file of our own samples (laspy).
# Inputs: the Stanford bunny and dragon scans, the textured spot, and a dense mesh made by
# subdividing the bunny three times (4.4 M triangles, as binary PLY, OBJ and GLB) for the
# cost per triangle, and the dragon voxelized finer (2.1 M and 8.3 M samples) for the LOD task.
#
# Usage: scripts/peers.sh [ROUNDS] [OUT_DIR]   (default 3, out/peers; needs ../shared/models)
set -euo pipefail
cd "$(dirname "$0")/.."
rounds=${1:-3}
out=${2:-out/peers}
mkdir -p "$out"
out=$(cd "$out" && pwd)

cargo build --release --quiet -p voxelize -p build-tree -p inspect
target_dir=$(cargo metadata --format-version 1 --no-deps | python3 -c 'import json,sys; print(json.load(sys.stdin)["target_directory"])')

if [ ! -x "$out/venv/bin/python" ]; then
    python3 -m venv "$out/venv"
fi
# Installed? (found, not imported: importing open3d needs the library below)
"$out/venv/bin/python" -c 'import importlib.util as u, sys; sys.exit(any(u.find_spec(m) is None for m in ("open3d", "trimesh", "laspy", "numpy", "PIL")))' ||
    "$out/venv/bin/pip" install --quiet --disable-pip-version-check 'open3d>=0.18' 'trimesh>=4' 'laspy>=2.5' 'numpy>=1.26' 'pillow>=10'
# open3d's wheel links libusb (Debian: libusb-1.0-0), which a bare machine lacks.
if ! "$out/venv/bin/python" -c 'import open3d' 2>/dev/null; then
    if [ "$(id -u)" = 0 ] && command -v apt-get > /dev/null; then
        apt-get install -y -q libusb-1.0-0 > /dev/null || { apt-get update -q > /dev/null && apt-get install -y -q libusb-1.0-0 > /dev/null; }
    else
        echo "peers.sh: open3d cannot load (missing libusb-1.0?); install libusb-1.0-0 and run again" >&2
        exit 2
    fi
fi
if [ ! -x "$out/cargo/bin/copc_converter" ]; then
    cargo install --quiet --locked --root "$out/cargo" copc_converter
fi

exec "$out/venv/bin/python" scripts/peers.py --rounds "$rounds" --out "$out" \
    --bin "$target_dir/release" --copc "$out/cargo/bin/copc_converter" --models ../shared/models
