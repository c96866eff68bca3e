#!/usr/bin/env python3
"""Writes mesh inputs of under 1 MB that are as expensive as the format lets them be, for
scripts/hostile-bounds.sh (README, "Resource bounds per tool"). Usage: hostile_meshes.py DIR

- comb.obj: one concave face, a comb of 16,000 teeth (32,002 corners), every tooth 1 unit
  wide and 1,000 units tall;
- comb.ply: the same in binary PLY, 30,000 teeth (one face of 60,002 corners);
- ngon-repeat.obj: one face of 400,000 corners cycling over 3 vertices (a polygon folded
  onto one triangle);
- stacked.ply: 76,000 copies of one triangle (binary; stacked surfaces);
- spread.ply: 20,000 large triangles in random directions through one box (binary);
- points-coincident.ply: 83,000 points at one position (binary, no faces);
- points-1000.ply: 83,000 points on 1,000 positions;
- claims.ply: a header claiming 2^31 vertices and faces over a few bytes of body;
- dag.gltf: 2 x 60 nodes, each level's two nodes both children of both nodes above
  (2^60 paths to the one triangle mesh);
- nodes.gltf: 14,500 nodes of one mesh under distinct non-uniform scales.
"""
import base64
import json
import math
import os
import random
import struct
import sys

out = sys.argv[1]
os.makedirs(out, exist_ok=True)
LIMIT = 1_000_000


def write(name, data):
    path = os.path.join(out, name)
    mode = "wb" if isinstance(data, bytes) else "w"
    with open(path, mode) as f:
        f.write(data)
    size = os.path.getsize(path)
    assert size < LIMIT, (name, size)
    print(f"{name}: {size} bytes")


# comb.obj: bottom edge, then teeth right to left.
teeth = 16_000
pts = [(0.0, 0.0), (float(teeth), 0.0)]
for i in range(teeth, 0, -1):
    pts.append((i - 0.0, 1000.0))
    pts.append((i - 0.5, 1.0))
lines = [f"v {x:g} {y:g} 0" for x, y in pts]
lines.append("f " + " ".join(str(i + 1) for i in range(len(pts))))
write("comb.obj", "\n".join(lines) + "\n")

# comb.ply: the same comb in binary PLY, one face of 60,002 corners (a uint-counted list).
teeth = 30_000
pts = [(0.0, 0.0), (float(teeth), 0.0)]
for i in range(teeth, 0, -1):
    pts.append((float(i), 1000.0))
    pts.append((i - 0.5, 1.0))
head = (f"ply\nformat binary_little_endian 1.0\nelement vertex {len(pts)}\nproperty float x\nproperty float y\n"
        f"property float z\nelement face 1\nproperty list uint int vertex_indices\nend_header\n")
body = b"".join(struct.pack("<3f", x, y, 0.0) for x, y in pts) + struct.pack("<I", len(pts))
body += b"".join(struct.pack("<i", i) for i in range(len(pts)))
write("comb.ply", head.encode() + body)

# ngon-repeat.obj: 400,000 corners over 3 vertices.
corners = 400_000
write("ngon-repeat.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf " + " ".join(str(i % 3 + 1) for i in range(corners)) + "\n")


def ply(vertices, faces, claim=None):
    nv, nf = (len(vertices), len(faces)) if claim is None else claim
    head = f"ply\nformat binary_little_endian 1.0\nelement vertex {nv}\nproperty float x\nproperty float y\nproperty float z\n"
    if faces or claim:
        head += f"element face {nf}\nproperty list uchar int vertex_indices\n"
    head += "end_header\n"
    body = b"".join(struct.pack("<3f", *v) for v in vertices)
    body += b"".join(struct.pack("<B3i", 3, *f) for f in faces)
    return head.encode() + body


write("stacked.ply", ply([(0, 0, 0), (1, 0, 0), (0, 1, 0)], [(0, 1, 2)] * 76_000))
random.seed(24)
n = 20_000
verts = []
for _ in range(3 * n):
    verts.append(tuple(random.uniform(-1, 1) for _ in range(3)))
write("spread.ply", ply(verts, [(3 * i, 3 * i + 1, 3 * i + 2) for i in range(n)]))
write("points-coincident.ply", ply([(0.5, 0.5, 0.5)] * 83_000, []))
pos = [tuple(random.uniform(0, 1) for _ in range(3)) for _ in range(1000)]
write("points-1000.ply", ply([pos[i % 1000] for i in range(83_000)], []))
write("claims.ply", ply([(0, 0, 0)], [], claim=(1 << 31, 1 << 31)))


def gltf(nodes, scenes_nodes, extra_meshes=1):
    tri = struct.pack("<9f", 0, 0, 0, 1, 0, 0, 0, 1, 0)
    return json.dumps({
        "asset": {"version": "2.0"},
        "buffers": [{"byteLength": len(tri), "uri": "data:application/octet-stream;base64," + base64.b64encode(tri).decode()}],
        "bufferViews": [{"buffer": 0, "byteLength": len(tri)}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 0]}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
        "nodes": nodes,
        "scenes": [{"nodes": scenes_nodes}],
        "scene": 0,
    }, separators=(",", ":"))


levels = 60
nodes = [{"mesh": 0}, {"mesh": 0}]
for k in range(1, levels):
    a, b = 2 * (k - 1), 2 * (k - 1) + 1
    nodes.append({"children": [a, b]})
    nodes.append({"children": [a, b]})
write("dag.gltf", gltf(nodes, [len(nodes) - 2, len(nodes) - 1]))

count = 14_500
nodes = [{"mesh": 0, "scale": [1 + i * 1e-3, 1, 2], "translation": [i * 0.01, 0, 0]} for i in range(count)]
write("nodes.gltf", gltf(nodes, list(range(count))))
