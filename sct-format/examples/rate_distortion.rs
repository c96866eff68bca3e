//! Rate–distortion of the node codecs on real scans.
//!
//! `cargo run -p sct-format --release --example rate_distortion [-- file.ply ...]`
//!
//! Leaves are the PLY vertices (own tiny ASCII / binary-little-endian vertex+face reader):
//! normal = the file's normal, else the area-weighted face normal; area = a third of the
//! adjacent triangles' area; one radius for all leaves, `√(2·mean area/π)` (like voxelized
//! samples: identical radii, cone 0); colour = a synthetic smooth field of position (the
//! scans have none). The tree is a median k-d split on the longest axis with parents from
//! `sct_format::geometry::parent_of` (EQ 9–14). Every level is encoded top-down against the
//! decoded parents; the default payload is zstd-compressed per level (one block a level).

use sct_format::codec::{decode_children, encode_children, CodecParams, Profile};
use sct_format::geometry::parent_of;
use sct_format::Node;
use std::time::Instant;

struct Mesh {
    pos: Vec<[f32; 3]>,
    nrm: Option<Vec<[f32; 3]>>,
    faces: Vec<[u32; 3]>,
}

fn read_ply(path: &str) -> Result<Mesh, String> {
    let data = std::fs::read(path).map_err(|e| format!("{path}: {e}"))?;
    let end = data.windows(11).position(|w| w == b"end_header\n").ok_or("no end_header")? + 11;
    let header = std::str::from_utf8(&data[..end]).map_err(|e| e.to_string())?;
    let mut binary = false;
    let (mut nv, mut nf) = (0usize, 0usize);
    let mut vprops: Vec<(String, String)> = Vec::new();
    let mut cur = "";
    for line in header.lines() {
        let w: Vec<&str> = line.split_whitespace().collect();
        match w.as_slice() {
            ["format", f, ..] => binary = *f == "binary_little_endian",
            ["element", "vertex", n] => {
                nv = n.parse().map_err(|_| "bad count")?;
                cur = "vertex";
            }
            ["element", "face", n] => {
                nf = n.parse().map_err(|_| "bad count")?;
                cur = "face";
            }
            ["element", ..] => cur = "other",
            ["property", "list", ..] => {}
            ["property", t, name] if cur == "vertex" => vprops.push((t.to_string(), name.to_string())),
            _ => {}
        }
    }
    let idx = |n: &str| vprops.iter().position(|p| p.1 == n);
    let (ix, iy, iz) = (idx("x").ok_or("no x")?, idx("y").ok_or("no y")?, idx("z").ok_or("no z")?);
    let inn = (idx("nx"), idx("ny"), idx("nz"));
    let size = |t: &str| match t {
        "char" | "uchar" | "int8" | "uint8" => 1,
        "short" | "ushort" | "int16" | "uint16" => 2,
        "double" | "float64" => 8,
        _ => 4,
    };
    let mut vals = vec![0f32; vprops.len()];
    let mut pos = Vec::with_capacity(nv);
    let mut nrm = Vec::with_capacity(nv);
    let mut faces = Vec::with_capacity(nf);
    let mut push = |vals: &[f32]| {
        pos.push([vals[ix], vals[iy], vals[iz]]);
        if let (Some(a), Some(b), Some(c)) = inn {
            nrm.push([vals[a], vals[b], vals[c]]);
        }
    };
    if binary {
        let mut o = end;
        let rd = |o: usize, t: &str| -> Result<f32, String> {
            let b = data.get(o..o + size(t)).ok_or("truncated")?;
            Ok(match t {
                "float" | "float32" => f32::from_le_bytes([b[0], b[1], b[2], b[3]]),
                "double" | "float64" => f64::from_le_bytes(b.try_into().map_err(|_| "x")?) as f32,
                "uchar" | "uint8" => b[0] as f32,
                "int" | "int32" => i32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f32,
                _ => 0.0,
            })
        };
        for _ in 0..nv {
            for (k, (t, _)) in vprops.iter().enumerate() {
                vals[k] = rd(o, t)?;
                o += size(t);
            }
            push(&vals);
        }
        for _ in 0..nf {
            let n = *data.get(o).ok_or("truncated")? as usize;
            o += 1;
            let mut f = Vec::with_capacity(n);
            for _ in 0..n {
                let b = data.get(o..o + 4).ok_or("truncated")?;
                f.push(u32::from_le_bytes([b[0], b[1], b[2], b[3]]));
                o += 4;
            }
            for t in 1..n.saturating_sub(1) {
                faces.push([f[0], f[t], f[t + 1]]);
            }
        }
    } else {
        let body = std::str::from_utf8(&data[end..]).map_err(|e| e.to_string())?;
        let mut lines = body.lines();
        for _ in 0..nv {
            let l = lines.next().ok_or("truncated")?;
            for (k, w) in l.split_whitespace().take(vals.len()).enumerate() {
                vals[k] = w.parse().map_err(|_| "bad float")?;
            }
            push(&vals);
        }
        for _ in 0..nf {
            let l = lines.next().ok_or("truncated")?;
            let f: Vec<u32> = l.split_whitespace().skip(1).map(|w| w.parse().unwrap_or(0)).collect();
            for t in 1..f.len().saturating_sub(1) {
                faces.push([f[0], f[t], f[t + 1]]);
            }
        }
    }
    let nrm = if nrm.len() == pos.len() { Some(nrm) } else { None };
    Ok(Mesh { pos, nrm, faces })
}

fn sub(a: [f32; 3], b: [f32; 3]) -> [f64; 3] {
    [a[0] as f64 - b[0] as f64, a[1] as f64 - b[1] as f64, a[2] as f64 - b[2] as f64]
}
fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}
fn len(a: [f64; 3]) -> f64 {
    (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt()
}
fn angle(a: [f32; 3], b: [f32; 3]) -> f64 {
    let a = [a[0] as f64, a[1] as f64, a[2] as f64];
    let b = [b[0] as f64, b[1] as f64, b[2] as f64];
    len(cross(a, b)).atan2(a[0] * b[0] + a[1] * b[1] + a[2] * b[2])
}

fn leaves(m: &Mesh) -> Vec<Node> {
    let n = m.pos.len();
    let mut area = vec![0f64; n];
    let mut fn_ = vec![[0f64; 3]; n];
    for f in &m.faces {
        if f.iter().any(|&i| i as usize >= n) {
            continue;
        }
        let [a, b, c] = f.map(|i| m.pos[i as usize]);
        let x = cross(sub(b, a), sub(c, a));
        for &i in f {
            area[i as usize] += len(x) / 6.0;
            for k in 0..3 {
                fn_[i as usize][k] += x[k];
            }
        }
    }
    let used: Vec<usize> = (0..n).filter(|&i| area[i] > 0.0).collect();
    let mean = used.iter().map(|&i| area[i]).sum::<f64>() / used.len() as f64;
    let r = (2.0 * mean / std::f64::consts::PI).sqrt() as f32;
    let (lo, hi) = bbox(&m.pos);
    used.iter()
        .map(|&i| {
            let p = m.pos[i];
            let nv = match &m.nrm {
                Some(v) => [v[i][0] as f64, v[i][1] as f64, v[i][2] as f64],
                None => fn_[i],
            };
            let l = len(nv).max(1e-30);
            let t = |k: usize| ((p[k] - lo[k]) / (hi[k] - lo[k]).max(1e-9)) as f64;
            let ch = |x: f64| (127.5 + 127.5 * x.sin()) as u8;
            Node {
                center: p,
                radius: r,
                normal: [(nv[0] / l) as f32, (nv[1] / l) as f32, (nv[2] / l) as f32],
                cone: 0.0,
                area: area[i] as f32,
                color: [ch(6.0 * t(0) + 1.0), ch(9.0 * t(1)), ch(4.0 * t(2) + 3.0 * t(0)), 255],
            }
        })
        .collect()
}

fn bbox(p: &[[f32; 3]]) -> ([f32; 3], [f32; 3]) {
    let mut lo = [f32::MAX; 3];
    let mut hi = [f32::MIN; 3];
    for v in p {
        for k in 0..3 {
            lo[k] = lo[k].min(v[k]);
            hi[k] = hi[k].max(v[k]);
        }
    }
    (lo, hi)
}

/// Arena tree: node, children.
struct Tree {
    nodes: Vec<Node>,
    kids: Vec<Option<[usize; 2]>>,
}

fn build(t: &mut Tree, items: &mut [Node]) -> usize {
    if items.len() == 1 {
        t.nodes.push(items[0]);
        t.kids.push(None);
        return t.nodes.len() - 1;
    }
    let c: Vec<[f32; 3]> = items.iter().map(|n| n.center).collect();
    let (lo, hi) = bbox(&c);
    let ax = (0..3).max_by(|&a, &b| (hi[a] - lo[a]).total_cmp(&(hi[b] - lo[b]))).unwrap_or(0);
    let mid = items.len() / 2;
    items.select_nth_unstable_by(mid, |a, b| a.center[ax].total_cmp(&b.center[ax]));
    let (l, r) = items.split_at_mut(mid);
    let a = build(t, l);
    let b = build(t, r);
    t.nodes.push(parent_of(&t.nodes[a], &t.nodes[b]));
    t.kids.push(Some([a, b]));
    t.nodes.len() - 1
}

/// Levels in BFS order: per level, (true nodes, is-internal flags).
fn bfs(t: &Tree, root: usize) -> Vec<Vec<usize>> {
    let mut levels = vec![vec![root]];
    loop {
        let next: Vec<usize> = levels.last().into_iter().flatten().filter_map(|&i| t.kids[i]).flatten().collect();
        if next.is_empty() {
            return levels;
        }
        levels.push(next);
    }
}

struct Row {
    name: String,
    bytes: usize,
    enc_s: f64,
    dec_s: f64,
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let files = if args.is_empty() {
        vec![
            "../shared/models/scans/stanford-bunny-original-ply/bun_zipper.ply".to_string(),
            "../shared/models/scans/stanford-dragon-100k/dragon.ply".to_string(),
        ]
    } else {
        args
    };
    for f in files {
        let path = if std::path::Path::new(&f).exists() { f.clone() } else { format!("../{f}") };
        let mesh = match read_ply(&path) {
            Ok(m) => m,
            Err(e) => {
                eprintln!("skipping {f}: {e}");
                continue;
            }
        };
        let mut ls = leaves(&mesh);
        let n_leaves = ls.len();
        let mut t = Tree { nodes: Vec::new(), kids: Vec::new() };
        let root = build(&mut t, &mut ls);
        let levels = bfs(&t, root);
        let n_nodes = t.nodes.len();
        println!(
            "\n### {} — {} leaves, {} nodes, {} levels, leaf radius {:.3e}, normals: {}",
            f.rsplit('/').next().unwrap_or(&f),
            n_leaves,
            n_nodes,
            levels.len(),
            ls[0].radius,
            if mesh.nrm.is_some() { "from file" } else { "from faces" }
        );
        println!("\n| profile | bytes/leaf | bytes/node | pos err max / mean (leaf radii) | radius growth max / mean (leaf radii) | normal err max / mean (°) | colour err max / mean (steps) | area rel. err max | encode Mnodes/s | decode Mnodes/s |");
        println!("|---|---|---|---|---|---|---|---|---|---|");
        let params = CodecParams::default();
        for profile in [Profile::Raw, Profile::Canopy, Profile::Default] {
            // Encode top-down.
            let t0 = Instant::now();
            let mut decoded: Vec<Vec<Node>> = vec![vec![t.nodes[root]]];
            let mut payloads: Vec<Vec<u8>> = Vec::new();
            let mut ok = true;
            for d in 1..levels.len() {
                let parents: Vec<Node> = levels[d - 1]
                    .iter()
                    .zip(&decoded[d - 1])
                    .filter(|(&i, _)| t.kids[i].is_some())
                    .map(|(_, n)| *n)
                    .collect();
                let children: Vec<Node> = levels[d].iter().map(|&i| t.nodes[i]).collect();
                let mut out = Vec::new();
                match encode_children(profile, params, &parents, &children, &mut out) {
                    Ok(dec) => decoded.push(dec),
                    Err(e) => {
                        eprintln!("{}: level {d}: {e}", profile.name());
                        ok = false;
                        break;
                    }
                }
                payloads.push(out);
            }
            let enc_s = t0.elapsed().as_secs_f64();
            if !ok {
                continue;
            }
            // Decode (timed) and check it matches.
            let t1 = Instant::now();
            let mut redec: Vec<Vec<Node>> = vec![vec![t.nodes[root]]];
            for d in 1..levels.len() {
                let parents: Vec<Node> = levels[d - 1]
                    .iter()
                    .zip(&redec[d - 1])
                    .filter(|(&i, _)| t.kids[i].is_some())
                    .map(|(_, n)| *n)
                    .collect();
                let mut out = Vec::new();
                if let Err(e) = decode_children(profile, params, &parents, &payloads[d - 1], 0, &mut out) {
                    eprintln!("decode failed: {e}");
                }
                redec.push(out);
            }
            let dec_s = t1.elapsed().as_secs_f64();
            assert!(redec == decoded, "decode(encode) differs from the returned nodes");
            // Distortion over the leaves.
            let r = t.nodes[levels[levels.len() - 1][0]].radius as f64;
            let (mut pe, mut pm, mut re, mut rm, mut ne, mut nm, mut ce, mut cm, mut ae) = (0f64, 0f64, 0f64, 0f64, 0f64, 0f64, 0u8, 0f64, 0f64);
            let mut cnt = 0f64;
            for (d, lv) in levels.iter().enumerate() {
                for (k, &i) in lv.iter().enumerate() {
                    if t.kids[i].is_some() {
                        continue;
                    }
                    let (a, b) = (&t.nodes[i], &decoded[d][k]);
                    let p = len(sub(a.center, b.center)) / r;
                    let g = (b.radius as f64 - a.radius as f64) / r;
                    let n = angle(a.normal, b.normal).to_degrees();
                    let c = (0..4).map(|j| (a.color[j] as i32 - b.color[j] as i32).unsigned_abs() as u8).max().unwrap_or(0);
                    let ar = ((b.area as f64 - a.area as f64) / (a.area as f64).max(1e-30)).abs();
                    pe = pe.max(p);
                    pm += p;
                    re = re.max(g);
                    rm += g;
                    ne = ne.max(n);
                    nm += n;
                    ce = ce.max(c);
                    cm += c as f64;
                    ae = ae.max(ar);
                    cnt += 1.0;
                }
            }
            let dist = format!(
                "{pe:.3} / {:.3} | {re:.3} / {:.3} | {ne:.3} / {:.3} | {ce} / {:.2} | {ae:.1e}",
                pm / cnt,
                rm / cnt,
                nm / cnt,
                cm / cnt
            );
            if profile == Profile::Default {
                // Where the bytes go: each stream gathered over all levels, zstd 19 alone.
                let names = ["state lo", "state hi", "normal u", "normal v", "cone", "red", "green", "blue", "area lo", "area hi"];
                let mut streams = vec![Vec::new(); names.len()];
                for p in &payloads {
                    let m = p.len() / 9;
                    let mut o = 0;
                    for (k, s) in streams.iter_mut().enumerate() {
                        let l = if k >= 8 { m / 2 } else { m };
                        s.extend_from_slice(&p[o..o + l]);
                        o += l;
                    }
                }
                let parts: Vec<String> = names
                    .iter()
                    .zip(&streams)
                    .map(|(n, s)| format!("{n} {:.2}", zstd::bulk::compress(s, 19).map(|v| v.len()).unwrap_or(0) as f64 * 8.0 / n_nodes as f64))
                    .collect();
                println!("<!-- default streams, bits/node after zstd 19: {} -->", parts.join(", "));
            }
            let mut rows = vec![Row { name: profile.name().into(), bytes: payloads.iter().map(|p| p.len()).sum(), enc_s, dec_s }];
            if profile != Profile::Raw {
                for lvl in [3, 19] {
                    let t2 = Instant::now();
                    let z: usize = payloads.iter().map(|p| zstd::bulk::compress(p, lvl).map(|v| v.len()).unwrap_or(p.len())).sum();
                    let zs = t2.elapsed().as_secs_f64();
                    let comp: Vec<Vec<u8>> = payloads.iter().map(|p| zstd::bulk::compress(p, lvl).unwrap_or_default()).collect();
                    let t3 = Instant::now();
                    for (c, p) in comp.iter().zip(&payloads) {
                        let _ = zstd::bulk::decompress(c, p.len());
                    }
                    let zd = t3.elapsed().as_secs_f64();
                    rows.push(Row { name: format!("{} + zstd {lvl}", profile.name()), bytes: z, enc_s: enc_s + zs, dec_s: dec_s + zd });
                }
            }
            for row in rows {
                println!(
                    "| {} | {:.2} | {:.2} | {dist} | {:.2} | {:.2} |",
                    row.name,
                    row.bytes as f64 / n_leaves as f64,
                    row.bytes as f64 / n_nodes as f64,
                    n_nodes as f64 / row.enc_s / 1e6,
                    n_nodes as f64 / row.dec_s / 1e6
                );
            }
        }
    }
}
