//! Test helpers: scene trees from real model points, file crafting and byte patching.
#![allow(dead_code)]

use std::path::{Path, PathBuf};

use sct_format::geometry::parent_of;
use sct_format::raw::{Cursor, FileHeader, SectionEntry, FILE_HEADER_LEN, SECTION_ENTRY_LEN};
use sct_format::{Generator, GraphNode, Node, Profile, Scene, SceneGraph, SceneTree, WriteOptions};

pub const BUNNY: &str = "/work/shared/models/scans/stanford-bunny-original-ply/bun_zipper_res2.ply";

pub fn bin() -> &'static str {
    env!("CARGO_BIN_EXE_sct-inspect")
}

/// Vertices and triangles of an ASCII PLY (x y z first; faces as vertex lists).
pub fn load_ascii_ply(path: &Path) -> (Vec<[f32; 3]>, Vec<[usize; 3]>) {
    let text = std::fs::read_to_string(path).expect("read PLY");
    let mut lines = text.lines();
    let (mut nv, mut nf) = (0usize, 0usize);
    for l in lines.by_ref() {
        let w: Vec<&str> = l.split_whitespace().collect();
        match w.as_slice() {
            ["element", "vertex", n] => nv = n.parse().unwrap(),
            ["element", "face", n] => nf = n.parse().unwrap(),
            ["end_header"] => break,
            _ => {}
        }
    }
    let mut v = Vec::with_capacity(nv);
    for l in lines.by_ref().take(nv) {
        let f: Vec<f32> = l.split_whitespace().take(3).map(|x| x.parse().unwrap()).collect();
        v.push([f[0], f[1], f[2]]);
    }
    let mut faces = Vec::with_capacity(nf);
    for l in lines.take(nf) {
        let f: Vec<usize> = l.split_whitespace().map(|x| x.parse().unwrap()).collect();
        for k in 2..f[0] {
            faces.push([f[1], f[1 + k - 1], f[1 + k]]);
        }
    }
    (v, faces)
}

/// One leaf per vertex: normal and area (a third of each adjacent triangle) from the faces,
/// radius from the adjacent edges, a height-based colour.
pub fn mesh_leaves(v: &[[f32; 3]], faces: &[[usize; 3]]) -> Vec<Node> {
    let mut acc = vec![([0f64; 3], 0f64, 0f64); v.len()];
    let sub = |a: [f32; 3], b: [f32; 3]| [(a[0] - b[0]) as f64, (a[1] - b[1]) as f64, (a[2] - b[2]) as f64];
    for f in faces {
        let (a, b, c) = (v[f[0]], v[f[1]], v[f[2]]);
        let (e1, e2) = (sub(b, a), sub(c, a));
        let n = [e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2], e1[0] * e2[1] - e1[1] * e2[0]];
        let area = 0.5 * (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        for (k, &i) in f.iter().enumerate() {
            let o = v[f[(k + 1) % 3]];
            let d = sub(o, v[i]);
            let e = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            for (a, nj) in acc[i].0.iter_mut().zip(n) {
                *a += nj;
            }
            acc[i].1 += area / 3.0;
            acc[i].2 = acc[i].2.max(e * 0.5);
        }
    }
    v.iter()
        .zip(&acc)
        .map(|(p, (n, a, r))| {
            let l = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
            let normal = if l > 0.0 { [(n[0] / l) as f32, (n[1] / l) as f32, (n[2] / l) as f32] } else { [0.0, 0.0, 1.0] };
            let h = ((p[1] + 0.1) * 1000.0).clamp(0.0, 255.0) as u8;
            Node { center: *p, radius: (*r as f32).max(1e-4), normal, cone: 0.0, area: *a as f32, color: [h, 255 - h, 128, 255] }
        })
        .collect()
}

/// A consistent tree over `leaves` by median splits along the longest axis, breadth first.
pub fn kd_tree(mut leaves: Vec<Node>) -> SceneTree {
    // Topology from splitting index ranges (sorted in place), attributes bottom-up.
    let mut ranges = vec![(0usize, leaves.len())];
    let mut k = 0;
    while k < ranges.len() {
        let (a, b) = ranges[k];
        if b - a > 1 {
            let s = &mut leaves[a..b];
            let mut lo = [f32::MAX; 3];
            let mut hi = [f32::MIN; 3];
            for n in s.iter() {
                for j in 0..3 {
                    lo[j] = lo[j].min(n.center[j]);
                    hi[j] = hi[j].max(n.center[j]);
                }
            }
            let ax = (0..3).max_by(|&x, &y| (hi[x] - lo[x]).total_cmp(&(hi[y] - lo[y]))).unwrap();
            let m = s.len() / 2;
            s.select_nth_unstable_by(m, |p, q| p.center[ax].total_cmp(&q.center[ax]));
            ranges.push((a, a + m));
            ranges.push((a + m, b));
        }
        k += 1;
    }
    let flags: Vec<bool> = ranges.iter().map(|&(a, b)| b - a > 1).collect();
    let nodes: Vec<Node> = ranges.iter().map(|&(a, b)| if b - a == 1 { leaves[a] } else { Node::default() }).collect();
    let mut t = SceneTree::from_bfs(nodes, flags).unwrap();
    for i in (0..t.len()).rev() {
        if let Some([a, b]) = t.children(i) {
            let p = parent_of(&t.nodes()[a], &t.nodes()[b]);
            t.nodes_mut()[i] = p;
        }
    }
    t
}

/// Recomputes every internal node from its children (after deliberate edits below).
pub fn refit(t: &mut SceneTree) {
    for i in (0..t.len()).rev() {
        if let Some([a, b]) = t.children(i) {
            let p = parent_of(&t.nodes()[a], &t.nodes()[b]);
            t.nodes_mut()[i] = p;
        }
    }
}

pub fn bunny_tree() -> SceneTree {
    let (v, f) = load_ascii_ply(Path::new(BUNNY));
    kd_tree(mesh_leaves(&v, &f))
}

pub fn generator() -> Generator {
    Generator {
        tool: "inspect-tests".into(),
        version: "1".into(),
        parameters: serde_json::json!({"model": "bun_zipper_res2.ply", "leaves": "one per vertex"}),
        sources: vec![],
    }
}

pub fn write(path: &Path, graph: SceneGraph, trees: Vec<SceneTree>, profile: Profile) {
    let scene = Scene { generator: generator(), graph, trees };
    sct_format::write_scene_file(path, &scene, &WriteOptions { profile, block_nodes: 256, ..Default::default() }).unwrap();
}

pub fn write_single(path: &Path, tree: SceneTree, profile: Profile) {
    write(path, SceneGraph { nodes: vec![GraphNode::Tree { tree: 0 }], root: 0 }, vec![tree], profile);
}

/// Rewrites a file with section `tag`'s raw (decompressed) bytes replaced by `patch(raw)`;
/// the patched section is stored uncompressed, every offset and CRC is recomputed.
pub fn patch_section(bytes: &[u8], tag: [u8; 4], patch: impl Fn(&mut Vec<u8>)) -> Vec<u8> {
    let mut c = Cursor::new(bytes, 0);
    let h = FileHeader::parse(&mut c).unwrap();
    let mut tc = Cursor::new(&bytes[h.section_table_offset as usize..], h.section_table_offset);
    let entries: Vec<SectionEntry> = (0..h.section_count).map(|_| SectionEntry::parse(&mut tc).unwrap()).collect();
    let mut bodies: Vec<(SectionEntry, Vec<u8>)> = Vec::new();
    for e in entries {
        let stored = bytes[e.offset as usize..(e.offset + e.stored_len) as usize].to_vec();
        if e.tag == tag {
            let mut raw = if e.compressed() { zstd_decode(&stored) } else { stored };
            patch(&mut raw);
            let mut e2 = e.clone();
            e2.flags &= !SectionEntry::ZSTD;
            bodies.push((e2, raw));
        } else {
            bodies.push((e, stored));
        }
    }
    let mut offset = (FILE_HEADER_LEN + bodies.len() * SECTION_ENTRY_LEN) as u64;
    let mut table = Vec::new();
    for (e, b) in &mut bodies {
        e.offset = offset;
        e.stored_len = b.len() as u64;
        if !e.compressed() {
            e.raw_len = b.len() as u64;
        }
        e.crc = crc32(b);
        e.write(&mut table);
        offset += b.len() as u64;
    }
    let mut out = Vec::new();
    FileHeader { file_length: offset, table_crc: crc32(&table), section_table_offset: FILE_HEADER_LEN as u64, ..h }.write(&mut out);
    out.extend_from_slice(&table);
    for (_, b) in &bodies {
        out.extend_from_slice(b);
    }
    out
}

fn zstd_decode(b: &[u8]) -> Vec<u8> {
    zstd::stream::decode_all(b).unwrap()
}

pub fn crc32(data: &[u8]) -> u32 {
    crc32fast::hash(data)
}

pub fn tmp() -> tempfile::TempDir {
    tempfile::tempdir().unwrap()
}

pub fn path_in(d: &tempfile::TempDir, name: &str) -> PathBuf {
    d.path().join(name)
}
