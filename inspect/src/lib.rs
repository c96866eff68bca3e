//! `sct-inspect` as a library: statistics ([`summarize`]), validation (re-exported from
//! [`sct_format::validate`]) and dumps ([`dump`]) of SCT files. Every function that prints
//! takes its writer, so the binary only parses flags and picks stdout.
//!
//! The JSON report is described in `spec/inspect-json.md` (schema [`SCHEMA`]).

use std::collections::HashMap;
use std::io::Write;
use std::path::{Path, PathBuf};

use serde::Serialize;

use sct_format::graph::GraphNode;
use sct_format::read::TreeIndex;
use sct_format::traverse::{ReachedKind, Traversal, TraverseError, TraverseErrorKind, TraverseOptions};
pub use sct_format::validate::{validate_file, CheckId, Issue, Report as Validation, ValidateOptions};
use sct_format::{Generator, Limits, Node, Profile, SctReader};

/// Version tag of the JSON report; bumped on any incompatible change.
pub const SCHEMA: &str = "sct-inspect/1";

pub mod export;
pub mod coverage;
pub mod many;

pub use coverage::{coverage_against, AgainstOptions, CoverageReport};

/// Failures that stop an inspection (as opposed to issues, which are results).
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum InspectError {
    /// The file could not be read or parsed.
    #[error(transparent)]
    Sct(#[from] sct_format::Error),
    /// Writing the output failed.
    #[error("writing output: {0}")]
    Output(#[from] std::io::Error),
    /// A `--dump` path that names no node.
    #[error("{0}")]
    Usage(String),
    /// The `--against` mesh could not be loaded.
    #[error("mesh: {0}")]
    Mesh(#[from] voxelize::LoadError),
    /// The `--against` mesh loaded but has no surface to sample.
    #[error("mesh: {0}")]
    BadMesh(String),
}

impl InspectError {
    /// Exit status: 1 when the file's content is at fault, 2 for usage and I/O errors.
    pub fn exit_code(&self) -> i32 {
        match self {
            InspectError::Sct(e) if e.is_invalid_input() => 1,
            InspectError::Mesh(voxelize::LoadError::Io { .. }) => 2,
            InspectError::Mesh(_) | InspectError::BadMesh(_) => 1,
            _ => 2,
        }
    }
}

/// The error that ends an inspection when a traversal stops at its visit limit
/// ([`sct_format::Limits::max_traversal_visits`]): what was reached so far is no answer.
pub(crate) fn traverse_fatal(e: TraverseError) -> InspectError {
    match e.kind {
        TraverseErrorKind::Read(inner) => InspectError::Sct(inner),
        other => InspectError::Sct(sct_format::Error::malformed(0, format!("{}: {other}", e.path))),
    }
}

/// A node's attributes as reported.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct NodeReport {
    /// Sphere centre.
    pub center: [f32; 3],
    /// Sphere radius.
    pub radius: f32,
    /// Cone axis.
    pub normal: [f32; 3],
    /// Cone semi-angle, degrees.
    pub cone_deg: f32,
    /// Surface area.
    pub area: f32,
    /// RGBA colour.
    pub color: [u8; 4],
}

impl From<&Node> for NodeReport {
    fn from(n: &Node) -> Self {
        NodeReport { center: n.center, radius: n.radius, normal: n.normal, cone_deg: n.cone.to_degrees(), area: n.area, color: n.color }
    }
}

/// One section of the file.
#[derive(Clone, Debug, Serialize)]
pub struct SectionReport {
    /// Four-character tag.
    pub tag: String,
    /// Absolute offset.
    pub offset: u64,
    /// Bytes stored in the file.
    pub stored_bytes: u64,
    /// Bytes after decompression.
    pub raw_bytes: u64,
    /// Stored as a zstd frame.
    pub compressed: bool,
}

/// One level of a tree.
#[derive(Clone, Debug, Serialize)]
pub struct LevelReport {
    /// Depth (0 = root).
    pub level: usize,
    /// Nodes.
    pub nodes: u64,
    /// Nodes with children.
    pub internal: u64,
    /// Nodes without children.
    pub leaves: u64,
    /// Blocks ("containers" of sibling pairs).
    pub blocks: u64,
    /// Blocks holding only leaves (the thesis's "leaf containers").
    pub leaf_blocks: u64,
    /// Blocks holding at least one internal node ("branching containers").
    pub branching_blocks: u64,
    /// Stored bytes of the level's blocks.
    pub stored_bytes: u64,
}

/// Bytes of one attribute stream.
#[derive(Clone, Debug, Serialize)]
pub struct StreamReport {
    /// Attribute name.
    pub name: String,
    /// Uncompressed bytes over all non-root nodes (the root is stored raw in the header).
    pub bytes: u64,
}

/// One scene tree.
#[derive(Clone, Debug, Serialize)]
pub struct TreeReport {
    /// Tree index.
    pub index: usize,
    /// Node profile.
    pub profile: String,
    /// Some colour has alpha < 255.
    pub alpha: bool,
    /// Nodes.
    pub nodes: u64,
    /// Leaves.
    pub leaves: u64,
    /// Levels (depth + 1).
    pub levels: usize,
    /// Depth (levels - 1).
    pub depth: usize,
    /// Blocks.
    pub blocks: u64,
    /// Per-level counts.
    pub per_level: Vec<LevelReport>,
    /// Whole TREE section.
    pub section_bytes: u64,
    /// Header, level table and block table.
    pub index_bytes: u64,
    /// Stored bytes of all blocks.
    pub block_bytes: u64,
    /// Uncompressed bytes of the child-flag masks (one bit per non-root node).
    pub flag_bytes: u64,
    /// Per-attribute stream sizes where the profile's layout is fixed (raw, canopy).
    pub streams: Option<Vec<StreamReport>>,
    /// Section bytes per leaf.
    pub bytes_per_leaf: f64,
    /// Root node.
    pub root: Option<NodeReport>,
}

/// Scene-graph counts.
#[derive(Clone, Debug, Serialize, Default)]
pub struct GraphReport {
    /// Graph nodes.
    pub nodes: u64,
    /// Root graph node.
    pub root: u32,
    /// Tree nodes.
    pub trees: u64,
    /// Group nodes.
    pub groups: u64,
    /// Instance nodes (similarity and affine).
    pub instances: u64,
    /// Affine instance nodes among them (format 1.3).
    pub affine_instances: u64,
    /// Inline nodes.
    pub inlines: u64,
}

/// Whole-scene counts.
#[derive(Clone, Debug, Serialize)]
pub struct TotalsReport {
    /// Leaves of all geometry trees in this file (group trees excluded).
    pub leaves: u64,
    /// Nodes of all trees.
    pub nodes: u64,
    /// Leaves reachable from the root, counting every instance and inline (saturating).
    pub leaves_expanded: u64,
    /// False when an inline could not be opened (its leaves are not counted).
    pub leaves_expanded_complete: bool,
    /// Explicit child pointers stored: always 0 (topology is one bit per node).
    pub child_pointers: u64,
    /// `child_pointers / leaves`.
    pub links_per_leaf: f64,
    /// File bytes per leaf of this file.
    pub bytes_per_leaf: f64,
}

/// The full report.
#[derive(Clone, Debug, Serialize)]
pub struct Summary {
    /// [`SCHEMA`].
    pub schema: &'static str,
    /// The file as given.
    pub file: String,
    /// File size.
    pub file_bytes: u64,
    /// Format version.
    pub version: [u16; 2],
    /// Provenance.
    pub generator: Generator,
    /// Sections in table order.
    pub sections: Vec<SectionReport>,
    /// Unknown optional sections skipped.
    pub skipped_sections: Vec<String>,
    /// Graph counts.
    pub graph: GraphReport,
    /// Trees.
    pub trees: Vec<TreeReport>,
    /// Totals.
    pub totals: TotalsReport,
    /// The root's bound (graph root, instances applied).
    pub root: Option<NodeReport>,
    /// Validation result when asked for.
    pub validation: Option<Validation>,
    /// Coverage of a source mesh, only with `--against` (absent otherwise, so reports
    /// without it are unchanged).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub coverage: Option<CoverageReport>,
}

fn tree_report(i: usize, t: &TreeIndex) -> TreeReport {
    let h = &t.header;
    let per_level: Vec<LevelReport> = t
        .levels
        .iter()
        .enumerate()
        .map(|(d, l)| {
            let internal = t.levels.get(d + 1).map_or(0, |n| n.node_count / 2);
            let blocks = t.level_blocks(d);
            let leaf_blocks = blocks.clone().filter(|&b| t.internal_in_block(b) == 0).count() as u64;
            LevelReport {
                level: d,
                nodes: l.node_count,
                internal,
                leaves: l.node_count.saturating_sub(internal),
                blocks: blocks.len() as u64,
                leaf_blocks,
                branching_blocks: blocks.len() as u64 - leaf_blocks,
                stored_bytes: blocks.map(|b| t.blocks[b].stored_len as u64).sum(),
            }
        })
        .collect();
    let block_bytes: u64 = t.blocks.iter().map(|b| b.stored_len as u64).sum();
    let flag_bytes: u64 = t.blocks.iter().map(|b| (b.node_count as u64).div_ceil(8)).sum();
    let n = h.node_count.saturating_sub(1);
    let per_node: Option<Vec<(&str, u64)>> = match t.profile {
        Profile::Raw => Some(vec![("position", 12), ("radius", 4), ("normal", 12), ("cone", 4), ("area", 4), ("color", 4)]),
        Profile::Canopy => {
            let mut v = vec![("position+radius", 2), ("normal", 2), ("cone", 1), ("color", 2)];
            if t.params.alpha {
                v.push(("alpha", 1));
            }
            v.push(("area", 4));
            Some(v)
        }
        Profile::Default => None,
    };
    let streams = per_node.map(|v| {
        let mut s: Vec<StreamReport> = vec![StreamReport { name: "child-flags".into(), bytes: flag_bytes }];
        s.extend(v.into_iter().map(|(name, b)| StreamReport { name: name.into(), bytes: b * n }));
        s
    });
    TreeReport {
        index: i,
        profile: t.profile.name().into(),
        alpha: t.params.alpha,
        nodes: h.node_count,
        leaves: h.leaf_count,
        levels: t.levels.len(),
        depth: t.levels.len().saturating_sub(1),
        blocks: t.blocks.len() as u64,
        per_level,
        section_bytes: t.section.stored_len,
        index_bytes: t.section.stored_len - block_bytes.min(t.section.stored_len),
        block_bytes,
        flag_bytes,
        streams,
        bytes_per_leaf: if h.leaf_count > 0 { t.section.stored_len as f64 / h.leaf_count as f64 } else { 0.0 },
        root: (h.node_count > 0).then(|| NodeReport::from(&h.root)),
    }
}

/// Leaves below each graph node, counting every use of instanced subgraphs and following
/// inlines (memoized per node and per file, so shared subgraphs cost once).
struct LeafCounter {
    limits: Limits,
    /// The directory inline targets must stay in (`None`: anywhere).
    root: Option<PathBuf>,
    files: HashMap<PathBuf, Option<u64>>,
    stack: Vec<PathBuf>,
    complete: bool,
}

impl LeafCounter {
    fn file(&mut self, r: &SctReader, canon: &Path) -> u64 {
        let g = r.graph();
        let mut memo = vec![0u64; g.nodes.len()];
        // References point backwards, so one forward pass sees children first.
        for (i, n) in g.nodes.iter().enumerate() {
            memo[i] = match n {
                GraphNode::Tree { tree } => r.trees().get(*tree as usize).map_or(0, |t| t.header.leaf_count),
                GraphNode::Group { children, .. } => {
                    children.iter().fold(0u64, |s, &c| s.saturating_add(memo.get(c as usize).copied().unwrap_or(0)))
                }
                GraphNode::Instance { child, .. } | GraphNode::Affine { child, .. } => memo.get(*child as usize).copied().unwrap_or(0),
                GraphNode::Inline { path, .. } => self.inline(canon, path).unwrap_or_else(|| {
                    self.complete = false;
                    0
                }),
            };
        }
        memo.get(g.root as usize).copied().unwrap_or(0)
    }

    fn inline(&mut self, from: &Path, rel: &str) -> Option<u64> {
        let canon = sct_format::traverse::resolve_inline(from, rel, self.root.as_deref()).ok()?;
        if let Some(v) = self.files.get(&canon) {
            return *v;
        }
        if self.stack.contains(&canon) || self.stack.len() as u32 > self.limits.max_inline_depth {
            return None;
        }
        let r = SctReader::open(&canon, &self.limits).ok()?;
        self.stack.push(canon.clone());
        let v = self.file(&r, &canon);
        self.stack.pop();
        self.files.insert(canon, Some(v));
        Some(v)
    }
}

/// Builds the report of the file at `path` (headers and indices only: no block is decoded).
/// Inlines are counted only inside the file's directory (see [`summarize_with`]).
pub fn summarize(path: &Path, limits: &Limits) -> Result<Summary, InspectError> {
    summarize_with(path, limits, false)
}

/// [`summarize`], following inlines outside the file's directory too when
/// `allow_outside_inlines`.
pub fn summarize_with(path: &Path, limits: &Limits, allow_outside_inlines: bool) -> Result<Summary, InspectError> {
    let r = SctReader::open(path, limits)?;
    let canon = std::fs::canonicalize(path).map_err(|e| sct_format::Error::io(path, e))?;
    let g = r.graph();
    let mut graph = GraphReport { nodes: g.nodes.len() as u64, root: g.root, ..Default::default() };
    for n in &g.nodes {
        match n {
            GraphNode::Tree { .. } => graph.trees += 1,
            GraphNode::Group { .. } => graph.groups += 1,
            GraphNode::Instance { .. } => graph.instances += 1,
            GraphNode::Affine { .. } => {
                graph.instances += 1;
                graph.affine_instances += 1;
            }
            GraphNode::Inline { .. } => graph.inlines += 1,
        }
    }
    let trees: Vec<TreeReport> = r.trees().iter().enumerate().map(|(i, t)| tree_report(i, t)).collect();
    let group_trees: Vec<usize> =
        g.nodes.iter().filter_map(|n| if let GraphNode::Group { tree, .. } = n { Some(*tree as usize) } else { None }).collect();
    let leaves: u64 = trees.iter().filter(|t| !group_trees.contains(&t.index)).map(|t| t.leaves).sum();
    let nodes: u64 = trees.iter().map(|t| t.nodes).sum();
    let root = (!allow_outside_inlines).then(|| sct_format::traverse::scene_root(&canon));
    let mut lc = LeafCounter { limits: limits.clone(), root, files: HashMap::new(), stack: vec![canon.clone()], complete: true };
    let leaves_expanded = lc.file(&r, &canon);
    let sections = r
        .sections()
        .iter()
        .map(|e| SectionReport { tag: e.tag_str(), offset: e.offset, stored_bytes: e.stored_len, raw_bytes: e.raw_len, compressed: e.compressed() })
        .collect();
    Ok(Summary {
        schema: SCHEMA,
        file: path.display().to_string(),
        file_bytes: r.file_len(),
        version: [r.header().major, r.header().minor],
        generator: r.generator().clone(),
        sections,
        skipped_sections: r.skipped_sections().to_vec(),
        graph,
        trees,
        totals: TotalsReport {
            leaves,
            nodes,
            leaves_expanded,
            leaves_expanded_complete: lc.complete,
            child_pointers: 0,
            links_per_leaf: 0.0,
            bytes_per_leaf: if leaves > 0 { r.file_len() as f64 / leaves as f64 } else { 0.0 },
        },
        root: sct_format::traverse::graph_bound(&r, g.root).as_ref().map(NodeReport::from),
        validation: None,
        coverage: None,
    })
}

fn fmt_node(n: &NodeReport) -> String {
    format!(
        "centre ({:.6}, {:.6}, {:.6}) radius {:.6}; cone axis ({:.4}, {:.4}, {:.4}) ±{:.2}°; area {:.6}; colour {:?}",
        n.center[0], n.center[1], n.center[2], n.radius, n.normal[0], n.normal[1], n.normal[2], n.cone_deg, n.area, n.color
    )
}

/// Writes the readable report.
pub fn write_text(s: &Summary, w: &mut dyn Write) -> std::io::Result<()> {
    writeln!(w, "SCT file {} ({} bytes), format version {}.{}", s.file, s.file_bytes, s.version[0], s.version[1])?;
    let gen = &s.generator;
    writeln!(w, "generator: {} {}", gen.tool, gen.version)?;
    if !gen.parameters.is_null() {
        writeln!(w, "  parameters: {}", gen.parameters)?;
    }
    for src in &gen.sources {
        writeln!(w, "  source: {} (blake3 {})", src.path, src.blake3)?;
    }
    writeln!(w, "sections:")?;
    for sec in &s.sections {
        writeln!(
            w,
            "  {:<4} at {:>10}: {:>12} bytes stored{}",
            sec.tag,
            sec.offset,
            sec.stored_bytes,
            if sec.compressed { format!(", {} raw (zstd)", sec.raw_bytes) } else { String::new() }
        )?;
    }
    if !s.skipped_sections.is_empty() {
        writeln!(w, "  skipped unknown optional sections: {}", s.skipped_sections.join(", "))?;
    }
    let g = &s.graph;
    writeln!(
        w,
        "scene graph: {} nodes (root {}): {} trees, {} groups, {} instances{}, {} inlines",
        g.nodes,
        g.root,
        g.trees,
        g.groups,
        g.instances,
        // Only files that have them (format 1.3) say so: older files print as before.
        if g.affine_instances > 0 { format!(" ({} affine)", g.affine_instances) } else { String::new() },
        g.inlines
    )?;
    for t in &s.trees {
        writeln!(w, "tree {} ({} profile{}):", t.index, t.profile, if t.alpha { ", alpha" } else { "" })?;
        writeln!(w, "  nodes {}, leaves {}, depth {}, blocks {}", t.nodes, t.leaves, t.depth, t.blocks)?;
        writeln!(w, "  level       nodes    internal      leaves  blocks (leaf/branching)        bytes")?;
        for l in &t.per_level {
            writeln!(
                w,
                "  {:>5} {:>11} {:>11} {:>11} {:>7} ({:>6}/{:>6}) {:>12}",
                l.level, l.nodes, l.internal, l.leaves, l.blocks, l.leaf_blocks, l.branching_blocks, l.stored_bytes
            )?;
        }
        writeln!(
            w,
            "  bytes: section {}, index {}, blocks {} (child flags {} uncompressed); {:.2} bytes/leaf",
            t.section_bytes, t.index_bytes, t.block_bytes, t.flag_bytes, t.bytes_per_leaf
        )?;
        match &t.streams {
            Some(st) => {
                let parts: Vec<String> = st.iter().map(|x| format!("{} {}", x.name, x.bytes)).collect();
                writeln!(w, "  streams (uncompressed bytes): {}", parts.join(", "))?;
            }
            None => writeln!(w, "  streams: not separable for the {} profile (entropy-coded together)", t.profile)?,
        }
        if let Some(r) = &t.root {
            writeln!(w, "  root: {}", fmt_node(r))?;
        }
    }
    let tt = &s.totals;
    writeln!(w, "totals: {} leaves, {} nodes; {} leaves expanded through instancing{}", tt.leaves, tt.nodes, tt.leaves_expanded, if tt.leaves_expanded_complete { "" } else { " (incomplete: an inline could not be opened)" })?;
    writeln!(
        w,
        "links: {} explicit child pointers, {:.3} per leaf (blocks of sibling pairs in breadth-first order; one has-children bit per node is the whole topology)",
        tt.child_pointers, tt.links_per_leaf
    )?;
    writeln!(w, "size: {:.2} file bytes per leaf", tt.bytes_per_leaf)?;
    if let Some(r) = &s.root {
        writeln!(w, "scene root: {}", fmt_node(r))?;
    }
    Ok(())
}

/// Writes a validation result.
pub fn write_validation(v: &Validation, w: &mut dyn Write) -> std::io::Result<()> {
    let mode = if v.deep { "deep" } else { "quick" };
    if v.is_valid() {
        writeln!(w, "validation ({mode}): valid ({} files, {} trees, {} blocks, {} nodes checked)", v.files.len(), v.trees, v.blocks, v.nodes)?;
    } else {
        writeln!(w, "validation ({mode}): {} issue(s)", v.issues.len() as u64 + v.issues_omitted)?;
        for i in &v.issues {
            writeln!(w, "{i}")?;
        }
        if v.issues_omitted > 0 {
            writeln!(w, "… and {} more issue(s) not listed (at most {} are kept)", v.issues_omitted, sct_format::validate::MAX_ISSUES)?;
        }
    }
    Ok(())
}

/// Writes a coverage result.
pub fn write_coverage(c: &CoverageReport, w: &mut dyn Write) -> std::io::Result<()> {
    writeln!(
        w,
        "coverage of {}: {:.4}% of {} surface points (seed {}) inside a leaf sphere: {} (threshold {:.4}%)",
        c.mesh,
        c.fraction * 100.0,
        c.points,
        c.seed,
        if c.passed { "pass" } else { "FAIL" },
        c.min_coverage * 100.0
    )?;
    writeln!(
        w,
        "  leaves: {} stored in {} trees, {} uses, {} expanded through instancing",
        c.leaves, c.trees, c.tree_uses, c.leaves_expanded
    )?;
    match &c.worst_uncovered {
        Some(u) => writeln!(
            w,
            "  worst uncovered point ({:.6}, {:.6}, {:.6}): {:.6} from the nearest leaf sphere = {:.3} leaf radii (radius {:.6})",
            u.point[0], u.point[1], u.point[2], u.distance, u.leaf_radii, u.leaf_radius
        )?,
        None => writeln!(w, "  every point is covered")?,
    }
    for e in &c.errors {
        writeln!(w, "  not followed: {e}")?;
    }
    Ok(())
}

/// Writes the JSON report (one object, see `spec/inspect-json.md`).
pub fn write_json(s: &Summary, w: &mut dyn Write) -> std::io::Result<()> {
    serde_json::to_writer_pretty(&mut *w, s)?;
    writeln!(w)
}

/// Parses an abstract path `root/0/1` into its steps.
pub fn parse_path(p: &str) -> Result<Vec<u8>, InspectError> {
    let mut parts = p.trim_end_matches('/').split('/');
    if parts.next() != Some("root") {
        return Err(InspectError::Usage(format!("path {p:?} must start with 'root' (e.g. root/0/1)")));
    }
    parts
        .map(|s| match s {
            "0" => Ok(0),
            "1" => Ok(1),
            _ => Err(InspectError::Usage(format!("path {p:?}: step {s:?} is not 0 or 1"))),
        })
        .collect()
}

/// Prints the scene graph, then the scene tree below `path` (an abstract path, see
/// [`sct_format::traverse`]) down `levels` levels, attributes decoded and in world space.
/// Only the branch towards `path` is traversed. Inlines leave the file's directory only with
/// `allow_outside_inlines`.
pub fn dump(file: &Path, path: &str, levels: usize, limits: &Limits, allow_outside_inlines: bool, w: &mut dyn Write) -> Result<(), InspectError> {
    let steps = parse_path(path)?;
    let r = SctReader::open(file, limits)?;
    writeln!(w, "scene graph of {} (root = node {}):", file.display(), r.graph().root)?;
    for (i, n) in r.graph().nodes.iter().enumerate() {
        let d = match n {
            GraphNode::Tree { tree } => format!("tree {tree}"),
            GraphNode::Group { children, tree } => format!("group over {children:?}, group tree {tree}"),
            GraphNode::Instance { child, transform, attrs } => format!(
                "instance of {child}: translation {:?} rotation {:?} scale {} size {:?} colour {:?} tint {:?}",
                transform.translation, transform.rotation, transform.scale, attrs.size, attrs.color, attrs.tint
            ),
            GraphNode::Affine { child, transform, attrs } => format!(
                "affine instance of {child}: {transform} (determinant {}, condition number {:.4}) size {:?} colour {:?} tint {:?}",
                transform.determinant(),
                transform.condition(),
                attrs.size,
                attrs.color,
                attrs.tint
            ),
            GraphNode::Inline { path, hash, .. } => format!("inline {path:?} blake3 {}", sct_format::traverse::hex(hash)),
        };
        writeln!(w, "  [{i}] {d}")?;
    }
    // The deepest reached tree whose root path is a prefix of the requested path.
    let opts = TraverseOptions { limits: limits.clone(), verify_inline_hashes: false, allow_outside_inlines };
    let mut best: Option<(usize, sct_format::traverse::Reached)> = None;
    let mut traversal = Traversal::open(file, opts)?;
    // Only nodes on the way to the requested path can hold it: every other branch is skipped
    // before it is expanded, so shared subgraphs are not walked path by path.
    let want = steps.clone();
    traversal.set_cull(move |_, p| parse_path(p).is_ok_and(|ps| want.starts_with(&ps)));
    for item in traversal {
        let reached = match item {
            Ok(r) => r,
            Err(e) if e.is_visit_limit() => return Err(traverse_fatal(e)),
            Err(_) => continue,
        };
        let Ok(rs) = parse_path(&reached.path) else { continue };
        if steps.starts_with(&rs) && best.as_ref().is_none_or(|(l, _)| rs.len() >= *l) {
            best = Some((rs.len(), reached));
        }
    }
    let Some((depth, reached)) = best else {
        return Err(InspectError::Usage(format!("no scene tree at or above {path}")));
    };
    let rest = &steps[depth..];
    let tree = reached.file.read_tree_levels(reached.tree, rest.len() + levels)?;
    if tree.is_empty() {
        // An empty tree (node count 0, spec §6.2) has no node to print, not even a root.
        if !rest.is_empty() {
            return Err(InspectError::Usage(format!("{} is an empty tree (tree {}): {path} does not exist", reached.path, reached.tree)));
        }
        writeln!(w, "{path} of {} is empty tree {} (graph node {}): no nodes", file.display(), reached.tree, reached.graph_node)?;
        return Ok(());
    }
    let mut at = 0usize;
    for (k, &s) in rest.iter().enumerate() {
        match tree.children(at) {
            Some(c) => at = c[s as usize],
            None => {
                let here = format!("{}{}", reached.path, rest[..k].iter().map(|s| format!("/{s}")).collect::<String>());
                return Err(InspectError::Usage(format!("{here} is a leaf of tree {}: {path} does not exist", reached.tree)));
            }
        }
    }
    let kind = match &reached.kind {
        ReachedKind::Tree => "tree".to_string(),
        ReachedKind::Group { children } => format!("group tree (leaves are the virtual roots of graph nodes {children:?})"),
    };
    writeln!(
        w,
        "{} of {} is node {at} of {kind} {} (graph node {}, {} inline(s) deep){}:",
        path,
        file.display(),
        reached.tree,
        reached.graph_node,
        reached.inline_depth,
        if reached.state == Default::default() {
            String::new()
        } else {
            let [r, g, b, a] = reached.state.tint;
            format!(", world transform {}, tint ({r}, {g}, {b}, {a})", reached.state.transform)
        }
    )?;
    let mut stack = vec![(at, path.trim_end_matches('/').to_string(), 0usize)];
    while let Some((i, p, d)) = stack.pop() {
        let n = reached.state.apply(&tree.nodes()[i]);
        let tag = if tree.is_internal(i) { "" } else { " leaf" };
        writeln!(w, "{}{p}{tag}: {}", "  ".repeat(d), fmt_node(&NodeReport::from(&n)))?;
        if d + 1 < levels.max(1) {
            if let Some([a, b]) = tree.children(i) {
                stack.push((b, format!("{p}/1"), d + 1));
                stack.push((a, format!("{p}/0"), d + 1));
            }
        }
    }
    Ok(())
}
