//! Export to PLY point clouds that MeshLab and CloudCompare open: the samples of a samples
//! file, or a level cut of an SCT scene, in world space (instances applied).
//!
//! Layout: binary little-endian, one `vertex` element with `x y z nx ny nz` (float),
//! `red green blue alpha` (uchar) and `radius` (float, MeshLab's per-vertex radius).
//!
//! A *level cut* at level `L` of a scene tree is every node at depth `L` plus every leaf
//! shallower than `L`: the surface at that level of detail, with nothing missing. Each
//! geometry tree reached through the scene graph is cut at its own depth `L` (group trees
//! only bound their children and are not exported). Only the first `L + 1` levels of each
//! tree are read.

use std::collections::HashMap;
use std::io::Write;
use std::path::{Path, PathBuf};

use crate::error::{Error, Result};
use crate::node::Node;
use crate::samples::SamplesFile;
use crate::traverse::{ReachedKind, Traversal, TraversalState, TraverseErrorKind, TraverseOptions};
use crate::SceneTree;

/// Bytes per exported point.
pub const PLY_POINT_BYTES: u64 = 32;

/// Writes the PLY header for `count` points.
fn header<W: Write>(w: &mut W, count: u64, comment: &str) -> std::io::Result<()> {
    let comment: String = comment.chars().map(|c| if c.is_control() { ' ' } else { c }).collect();
    write!(
        w,
        "ply\nformat binary_little_endian 1.0\ncomment {comment}\nelement vertex {count}\n\
         property float x\nproperty float y\nproperty float z\n\
         property float nx\nproperty float ny\nproperty float nz\n\
         property uchar red\nproperty uchar green\nproperty uchar blue\nproperty uchar alpha\n\
         property float radius\nend_header\n"
    )
}

fn point<W: Write>(w: &mut W, n: &Node) -> std::io::Result<()> {
    let mut b = [0u8; PLY_POINT_BYTES as usize];
    let f = [n.center[0], n.center[1], n.center[2], n.normal[0], n.normal[1], n.normal[2]];
    for (i, v) in f.iter().enumerate() {
        b[i * 4..i * 4 + 4].copy_from_slice(&v.to_le_bytes());
    }
    b[24..28].copy_from_slice(&n.color);
    b[28..32].copy_from_slice(&n.radius.to_le_bytes());
    w.write_all(&b)
}

/// What an export wrote.
#[derive(Clone, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct ExportSummary {
    /// Points written.
    pub points: u64,
    /// File size in bytes.
    pub bytes: u64,
    /// Scene trees (or sample-set placements) that contributed points.
    pub placements: u64,
}

/// Points a PLY export of `file` writes: every placement of every mesh, from the tables
/// alone (the samples need not be decoded).
fn placed_points(file: &SamplesFile) -> u64 {
    let count = |m: u32| file.meshes.get(m as usize).map_or(0, |e| e.count);
    file.instances.iter().map(|i| count(i.mesh)).chain(file.affine_instances.iter().map(|i| count(i.mesh))).fold(0u64, u64::saturating_add)
}

/// Writes every sample of `file` in world space (each placement of each mesh, similarity
/// and affine) to `out`, atomically. Refuses more than `max_points` points.
pub fn samples_to_ply(file: &SamplesFile, out: &Path, max_points: u64) -> Result<ExportSummary> {
    let total = placed_points(file);
    if total > max_points {
        return Err(Error::LimitExceeded { what: "PLY export points", value: total, limit: max_points });
    }
    let placements = (file.instances.len() + file.affine_instances.len()) as u64;
    crate::atomic::write_atomic(out, |w| {
        let io = |e| Error::io(out, e);
        header(w, total, &format!("SCT samples exported by sct-format {}", env!("CARGO_PKG_VERSION"))).map_err(io)?;
        for inst in &file.instances {
            let state = TraversalState { transform: inst.transform.into(), ..TraversalState::IDENTITY };
            for n in file.mesh_samples(inst.mesh as usize) {
                point(w, &state.apply(n)).map_err(io)?;
            }
        }
        for inst in &file.affine_instances {
            let stretch = inst.max_stretch();
            for n in file.mesh_samples(inst.mesh as usize) {
                point(w, &inst.transform_node(n, stretch)).map_err(io)?;
            }
        }
        Ok(())
    })?;
    Ok(ExportSummary { points: total, bytes: ply_size(out)?, placements })
}

/// Reads the samples file at `path` and exports it as [`samples_to_ply`] does. The
/// `max_points` check runs on the tables, before any sample is decoded: a file that would
/// export too many points costs no decoding.
pub fn samples_file_to_ply(path: &Path, out: &Path, max_points: u64, limits: &crate::Limits) -> Result<ExportSummary> {
    let file = SamplesFile::read_file_checked(path, limits, |tables, _| {
        let total = placed_points(tables);
        crate::Limits::check("PLY export points", total, max_points)
    })?;
    samples_to_ply(&file, out, max_points)
}

fn ply_size(out: &Path) -> Result<u64> {
    std::fs::metadata(out).map(|m| m.len()).map_err(|e| Error::io(out, e))
}

/// The level cut of one tree read to at most `level + 1` levels (module docs).
pub fn level_cut(tree: &SceneTree, level: usize) -> Vec<Node> {
    // An empty tree (node count 0, allowed by spec §6.2) has no level to cut.
    if tree.is_empty() {
        return Vec::new();
    }
    let nodes = tree.nodes();
    let last = tree.level_count().saturating_sub(1).min(level);
    let mut out = Vec::new();
    for d in 0..=last {
        for i in tree.level(d) {
            // Shallower levels contribute their leaves; the cut level contributes everything
            // (its children, if any, were not read).
            if d == last || tree.children(i).is_none() {
                out.push(nodes[i]);
            }
        }
    }
    out
}

/// Writes the level cut at `level` (`None`: the leaves) of the scene in `sct` to `out`, in
/// world space through groups, instances (transform and push-down tint) and inlines.
/// Refuses more than `max_points` points before writing anything. Memory: the cut of each
/// distinct tree is held once (40 bytes per cut node), however often it is instanced.
pub fn scene_to_ply(sct: &Path, level: Option<usize>, out: &Path, opts: TraverseOptions, max_points: u64) -> Result<ExportSummary> {
    scene_to_ply_holding(sct, level, out, opts, max_points, KEPT_PLACEMENTS)
}

/// [`scene_to_ply`] holding at most `kept` placements in memory: past them the scene is
/// traversed a second time to write them. The output is the same.
pub fn scene_to_ply_holding(sct: &Path, level: Option<usize>, out: &Path, opts: TraverseOptions, max_points: u64, kept: usize) -> Result<ExportSummary> {
    let level = level.unwrap_or(usize::MAX - 1);
    // Each distinct tree's cut once; a placement is its cut's index and a state (up to 136
    // bytes under an affine instance), and empty cuts place nothing, so placements are
    // bounded by the points and by the traversal's visit limit. Past `kept` the scene is
    // traversed a second time to write them instead of holding them: 10^7
    // placements of a 60-level DAG held 1.0 GB.
    let mut cut_of: HashMap<(PathBuf, usize), usize> = HashMap::new();
    let mut cuts: Vec<Vec<Node>> = Vec::new();
    let mut placements: Option<Vec<(usize, TraversalState)>> = Some(Vec::new());
    let (mut total, mut placed) = (0u64, 0u64);
    for reached in Traversal::open(sct, opts.clone())? {
        let r = reached.map_err(traversal_error)?;
        if !matches!(r.kind, ReachedKind::Tree) {
            continue;
        }
        let key = (r.file_path.clone(), r.tree);
        let c = match cut_of.get(&key) {
            Some(&c) => c,
            None => {
                let levels = level.saturating_add(1).min(r.file.trees().get(r.tree).map_or(0, |t| t.levels.len()));
                let tree = r.file.read_tree_levels(r.tree, levels)?;
                cuts.push(level_cut(&tree, level));
                cut_of.insert(key, cuts.len() - 1);
                cuts.len() - 1
            }
        };
        let n = cuts.get(c).map_or(0, |v| v.len() as u64);
        if n == 0 {
            continue;
        }
        total = total.saturating_add(n);
        if total > max_points {
            return Err(Error::LimitExceeded { what: "PLY export points (choose a coarser level)", value: total, limit: max_points });
        }
        placed += 1;
        match &mut placements {
            Some(p) if p.len() < kept => p.push((c, r.state)),
            _ => placements = None,
        }
    }
    crate::atomic::write_atomic(out, |w| {
        let io = |e| Error::io(out, e);
        let what = match level {
            l if l >= usize::MAX - 1 => "leaves".to_string(),
            l => format!("level {l} cut"),
        };
        header(w, total, &format!("SCT {what} of {} exported by sct-format {}", sct.display(), env!("CARGO_PKG_VERSION"))).map_err(io)?;
        let mut written = 0u64;
        let mut place = |c: usize, state: &TraversalState| -> Result<()> {
            for n in cuts.get(c).map(Vec::as_slice).unwrap_or_default() {
                written += 1;
                point(w, &state.apply(n)).map_err(io)?;
            }
            Ok(())
        };
        match &placements {
            Some(p) => {
                for (c, state) in p {
                    place(*c, state)?;
                }
            }
            None => {
                for reached in Traversal::open(sct, opts)? {
                    let r = reached.map_err(traversal_error)?;
                    if let (ReachedKind::Tree, Some(&c)) = (&r.kind, cut_of.get(&(r.file_path.clone(), r.tree))) {
                        place(c, &r.state)?;
                    }
                }
            }
        }
        // The second traversal reaches what the first did (the same files, unchanged: an
        // inline's hash is checked on each open); anything else would leave the header wrong.
        if written != total {
            return Err(Error::Malformed { offset: 0, what: format!("{}: the scene changed while it was exported", sct.display()) });
        }
        Ok(())
    })?;
    Ok(ExportSummary { points: total, bytes: ply_size(out)?, placements: placed })
}

/// Placements [`scene_to_ply`] holds before it traverses the scene a second time instead
/// (2^20: about 130 MB).
const KEPT_PLACEMENTS: usize = 1 << 20;

/// A traversal error as [`scene_to_ply`] reports it.
fn traversal_error(e: crate::traverse::TraverseError) -> Error {
    match e.kind {
        TraverseErrorKind::Read(inner) => inner,
        // A missing, changed or cyclic inline is a defect of the scene (exit 1), as in
        // validation and rendering.
        other => Error::Malformed { offset: 0, what: format!("{}: {other}", e.path) },
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::graph::{Generator, Similarity};
    use crate::samples::{MeshEntry, SampleInstance};

    fn node(i: usize) -> Node {
        Node { center: [i as f32, 0.5, -1.0], radius: 0.25, normal: [0.0, 0.0, 1.0], cone: 0.0, area: 0.1, color: [10, 20, 30, 255] }
    }

    /// Reads back our own layout (header lines and fixed-size records).
    fn read_back(path: &Path) -> (String, Vec<[f32; 7]>, Vec<[u8; 4]>) {
        let data = std::fs::read(path).expect("read");
        let end = data.windows(11).position(|w| w == b"end_header\n").expect("end_header") + 11;
        let head = String::from_utf8(data[..end].to_vec()).expect("utf8");
        let mut pts = Vec::new();
        let mut cols = Vec::new();
        for rec in data[end..].chunks_exact(32) {
            let f = |i: usize| f32::from_le_bytes([rec[i], rec[i + 1], rec[i + 2], rec[i + 3]]);
            pts.push([f(0), f(4), f(8), f(12), f(16), f(20), f(28)]);
            cols.push([rec[24], rec[25], rec[26], rec[27]]);
        }
        assert_eq!((data.len() - end) % 32, 0);
        (head, pts, cols)
    }

    #[test]
    fn samples_export_applies_every_placement() {
        let dir = tempfile::tempdir().expect("tempdir");
        let f = SamplesFile {
            generator: Generator::default(),
            meshes: vec![MeshEntry { name: "m".into(), first: 0, count: 3, two_sided: false }],
            instances: vec![
                SampleInstance { mesh: 0, transform: Similarity::IDENTITY },
                SampleInstance { mesh: 0, transform: Similarity { translation: [10.0, 0.0, 0.0], rotation: [0.0, 0.0, 0.0, 1.0], scale: 2.0 } },
            ],
            affine_instances: Vec::new(),
            samples: (0..3).map(node).collect(),
        };
        let out = dir.path().join("s.ply");
        let s = samples_to_ply(&f, &out, 1000).expect("export");
        assert_eq!((s.points, s.placements), (6, 2));
        let (head, pts, cols) = read_back(&out);
        assert!(head.contains("element vertex 6\n") && head.contains("property float radius\n"), "{head}");
        assert_eq!(pts.len(), 6);
        assert_eq!(pts[1][..3], [1.0, 0.5, -1.0]);
        assert_eq!(pts[4][..3], [12.0, 1.0, -2.0], "translation + scale 2");
        assert_eq!(pts[4][6], 0.5, "radius scaled");
        assert!(cols.iter().all(|c| *c == [10, 20, 30, 255]));
        // The limit is checked before anything is written.
        let out2 = dir.path().join("t.ply");
        assert!(matches!(samples_to_ply(&f, &out2, 5), Err(Error::LimitExceeded { .. })));
        assert!(!out2.exists());
    }

    #[test]
    fn level_cut_covers_every_leaf_exactly_once() {
        // Levels: root; 2 nodes; node 0 has children, node 1 is a leaf; 2 leaves.
        let nodes: Vec<Node> = (0..5).map(node).collect();
        let tree = SceneTree::from_bfs(nodes, vec![true, true, false, false, false]).expect("tree");
        let x = |v: Vec<Node>| v.iter().map(|n| n.center[0] as usize).collect::<Vec<_>>();
        assert_eq!(x(level_cut(&tree, 0)), [0]);
        assert_eq!(x(level_cut(&tree, 1)), [1, 2]);
        assert_eq!(x(level_cut(&tree, 2)), [2, 3, 4], "the shallow leaf and the deep level");
        assert_eq!(x(level_cut(&tree, 99)), [2, 3, 4]);
    }
}
