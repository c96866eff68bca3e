//! Validation of SCT files: every issue, not only the first (issue 5, thesis §5.11).
//!
//! [`validate_file`] runs in one of two modes:
//!
//! - **quick** (structure): magic and version, header and section table, every section's
//!   CRC and every block's CRC, offsets and lengths inside the file, counts (level table,
//!   block table, full-binary-tree node/leaf counts), generator JSON, scene-graph references,
//!   group child counts, instance transforms (finite, unit quaternion, positive scale;
//!   affine matrices finite, within the f32 range, non-singular, condition number ≤ 10⁶) and
//!   inline targets (present, matching their recorded BLAKE3 hash, no cycles, nesting within
//!   [`Limits::max_inline_depth`]). Inlined files are validated too, once each.
//! - **deep** adds hierarchical consistency (§5.11.1): every block is decoded once, as a
//!   wavefront over all levels that keeps a few blocks' nodes per level (plus one bit per
//!   node, to name the path of a failing node), and every child is checked against its
//!   decoded parent; group leaves are checked against the (transformed, tinted) bounds of
//!   the children they stand for, and inline bounds against the root of the file they name.
//!
//! Each tree is checked once, in its own frame, even when it is instanced many times: the
//! checks are invariant under similarity transforms (up to rounding), so checking every
//! instance would only multiply the work. (An affine map would not keep them: the mapped
//! nodes only bound the mapped geometry, spec §7, so consistency is a property of each tree
//! in its own frame.) The transforms matter where frames meet (a group
//! leaf over an instanced child), and there they are applied.
//!
//! # Tolerances
//!
//! - Containment ([`CheckId::ChildOutsideParent`]): the child sphere must lie inside the
//!   parent sphere grown by [`Profile::containment_slack`] parent radii (raw 1e-5; canopy
//!   0.3657, its worst legal stick-out). Group leaves and inline bounds use the raw slack.
//! - Area ([`CheckId::AreaSum`]): `|parent - (a + b)| <= AREA_REL_TOL * max(parent, a + b)`.
//!   A builder sums in f64 and rounds once (0.5 ulp ≈ 6e-8); the margin leaves room for
//!   codecs that quantize area relative to the parent, while real inconsistencies are ≥ 1e-3.
//!   A group leaf is compared with the child it stands for; in a profile that codes area
//!   relative to the parent, it may also differ by [`area_level_tolerance`] × the decoded
//!   area of each of its ancestors (the profile's documented bound, accumulated with depth).
//! - Cone ([`CheckId::ConeContainment`]): [`cone_tolerance`] radians (raw 1e-6; lossy profiles
//!   0.05 rad ≈ 2.9°: the decoded axis moves ≤ 0.64° and the decoded cone widens by < 1.35°).
//! - Colour ([`CheckId::ColorMean`]): each channel of the parent within [`color_tolerance`]
//!   8-bit steps of the area-weighted mean of its children (raw 1 for rounding; canopy
//!   RGBA 9/5/9/17: the parent's and children's 5:6:5:4 quantization errors plus rounding).
//! - Normal ([`CheckId::Normal`]): the cone axis has unit length within 1e-3 unless the cone
//!   is the whole sphere.

mod nodes;
mod wavefront;
#[cfg(test)]
mod tests;

use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};
use nodes::*;
use wavefront::*;

use rayon::prelude::*;
use serde::Serialize;

use crate::codec::Profile;
use crate::error::Error;
use crate::geometry::{cone_contains, merge_color, sphere_contains};
use crate::graph::{Generator, GraphNode, SceneGraph, Similarity};
use crate::limits::Limits;
use crate::node::Node;
use crate::raw::{tags, SectionEntry};
use crate::read::TreeIndex;
use crate::fsio::Source;
use crate::read::{max_graph_section, section_bytes_in};
use crate::traverse::{hex, GroupLeaves, TraversalState, TraverseErrorKind};
use crate::tree::SceneTree;

/// Issues kept in a [`Report`]; later ones are only counted ([`Report::issues_omitted`]), so
/// a file that is wrong everywhere cannot make validation hold one message per node.
pub const MAX_ISSUES: usize = 100_000;

/// Relative area tolerance (see the module docs).
pub const AREA_REL_TOL: f64 = 1e-4;
/// Unit-length tolerance of quaternions (the reader's).
pub const QUATERNION_TOL: f64 = 1e-6;
/// Unit-length tolerance of cone axes.
pub const NORMAL_TOL: f64 = 1e-3;

/// Most a level of a profile's tree may move a child's area, as a fraction of its decoded
/// parent's area (0 where area is stored exactly).
pub fn area_level_tolerance(p: Profile) -> f64 {
    match p {
        Profile::Raw | Profile::Canopy => 0.0,
        Profile::Default => crate::codec::default::AREA_FRACTION_ERROR,
    }
}

/// Cone containment tolerance of a profile, radians.
pub fn cone_tolerance(p: Profile) -> f32 {
    match p {
        Profile::Raw => 1e-6,
        Profile::Canopy | Profile::Default => 0.05,
    }
}

/// Per-channel RGBA colour tolerance of a profile, 8-bit steps.
pub fn color_tolerance(p: Profile) -> [u8; 4] {
    match p {
        Profile::Raw => [1; 4],
        Profile::Canopy | Profile::Default => [9, 5, 9, 17],
    }
}

macro_rules! checks {
    ($($(#[doc = $d:literal])* $v:ident = $s:literal,)*) => {
        /// Stable identifier of a check (kebab-case in reports; never renamed).
        #[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
        pub enum CheckId { $($(#[doc = $d])* $v,)* }
        impl CheckId {
            /// Every check, in report order.
            pub const ALL: &'static [CheckId] = &[$(CheckId::$v,)*];
            /// The kebab-case id.
            pub fn as_str(self) -> &'static str { match self { $(CheckId::$v => $s,)* } }
        }
    };
}

checks! {
    /// Not an SCT file (magic bytes).
    Magic = "magic",
    /// Unsupported major version.
    Version = "version",
    /// The file is shorter or longer than its header says, or a section or block lies past
    /// the end of the file or its section.
    Truncated = "truncated",
    /// A CRC-32 (header, section table, section or block) does not match.
    Checksum = "checksum",
    /// Malformed header or section table (flags, unknown required section, GENR not first, …).
    SectionTable = "section-table",
    /// The generator (GENR) is not valid JSON of the expected shape.
    Generator = "generator",
    /// The scene graph is malformed: references, kinds, root, group child counts, inline paths.
    Graph = "graph",
    /// A tree's header, level table or block table is inconsistent.
    TreeIndex = "tree-index",
    /// A block cannot be decoded (corrupt payload, wrong flags, counts disagreeing with the index).
    BlockDecode = "block-decode",
    /// A count or size exceeds a configured limit.
    Limit = "limit",
    /// A node attribute or transform component is NaN or infinite, or a radius, area or cone
    /// angle is out of range.
    NonFinite = "non-finite",
    /// A cone axis is not unit length.
    Normal = "normal",
    /// An instance rotation is not a unit quaternion.
    Quaternion = "quaternion",
    /// An instance scale is not positive.
    Scale = "scale",
    /// An affine instance's matrix is singular, has an entry beyond the f32 range, or a
    /// condition number above [`crate::affine::MAX_CONDITION`] (spec §7).
    Affine = "affine",
    /// An inline target does not exist or cannot be opened.
    InlineMissing = "inline-missing",
    /// An inline target's BLAKE3 hash differs from the recorded one.
    InlineHash = "inline-hash",
    /// Inlines form a cycle.
    InlineCycle = "inline-cycle",
    /// Inlines nest deeper than the limit.
    InlineDepth = "inline-depth",
    /// An inline's recorded bound does not match the root of its target.
    InlineBound = "inline-bound",
    /// An inline target (symlinks resolved) lies outside the validated file's directory; it is
    /// not opened unless outside inlines are allowed.
    InlineOutside = "inline-outside",
    /// A child sphere is not inside its parent sphere (with the profile's slack).
    ChildOutsideParent = "child-outside-parent",
    /// A parent's area is not the sum of its children's.
    AreaSum = "area-sum",
    /// A parent's normal cone does not contain a child's.
    ConeContainment = "cone-containment",
    /// A parent's colour is not the area-weighted mean of its children's.
    ColorMean = "color-mean",
}

impl std::fmt::Display for CheckId {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

impl Serialize for CheckId {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(self.as_str())
    }
}

/// One problem: where, which check, what.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct Issue {
    /// Abstract node path (`root/1/0`, see [`crate::traverse`]), or `file`, `graph/N`,
    /// `tree/N` for things without a node.
    pub path: String,
    /// The check that failed.
    pub check: CheckId,
    /// Human-readable details (values found and expected).
    pub message: String,
}

impl std::fmt::Display for Issue {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} {}: {}", self.path, self.check, self.message)
    }
}

/// How to validate.
#[derive(Clone, Debug, Default)]
pub struct ValidateOptions {
    /// Decode every block and check hierarchical consistency.
    pub deep: bool,
    /// Limits for every file opened.
    pub limits: Limits,
    /// Follow inlines whose target (symlinks resolved) lies outside the directory of the
    /// validated file (else [`CheckId::InlineOutside`], and the target is not opened).
    pub allow_outside_inlines: bool,
}

/// The outcome of a validation.
#[derive(Clone, Debug, Default, Serialize)]
pub struct Report {
    /// Whether the deep checks ran.
    pub deep: bool,
    /// Every issue found, in discovery order.
    pub issues: Vec<Issue>,
    /// Files validated (the file itself and its inlines), canonical paths.
    pub files: Vec<PathBuf>,
    /// Trees whose index was checked.
    pub trees: u64,
    /// Blocks whose CRC was checked (quick) or that were decoded (deep).
    pub blocks: u64,
    /// Nodes checked against their parent (deep).
    pub nodes: u64,
    /// Issues found beyond [`MAX_ISSUES`] and not listed (absent from JSON when 0).
    #[serde(skip_serializing_if = "is_zero")]
    pub issues_omitted: u64,
}

fn is_zero(v: &u64) -> bool {
    *v == 0
}

impl Report {
    /// True when no issue was found.
    pub fn is_valid(&self) -> bool {
        self.issues.is_empty() && self.issues_omitted == 0
    }
    /// The distinct check ids found, sorted.
    pub fn check_ids(&self) -> Vec<CheckId> {
        let mut v: Vec<CheckId> = self.issues.iter().map(|i| i.check).collect();
        v.sort();
        v.dedup();
        v
    }
}

/// Validates the file at `path` (and the files it inlines). Only an I/O failure on `path`
/// itself is an error; everything wrong with the content is an [`Issue`].
pub fn validate_file(path: &Path, opts: &ValidateOptions) -> Result<Report, Error> {
    let canon = std::fs::canonicalize(path).map_err(|e| Error::io(path, e))?;
    let src = Source::open(&canon)?;
    let mut v = Validator::new(opts);
    v.root = Some(crate::traverse::scene_root(&canon));
    v.stack.push(canon.clone());
    v.report.files.push(canon.clone());
    v.file(&src, Some(&canon), "root", "");
    Ok(v.finish())
}

/// Validates a file held in memory (inlines cannot be resolved and are reported missing).
pub fn validate_bytes(bytes: &[u8], opts: &ValidateOptions) -> Report {
    let mut v = Validator::new(opts);
    v.file(&Source::Bytes(std::borrow::Cow::Borrowed(bytes)), None, "root", "");
    v.finish()
}

/// Which check a reader error belongs to (`default` for malformed data of the part being read).
fn classify(e: &Error, default: CheckId) -> CheckId {
    match e {
        Error::BadMagic { .. } => CheckId::Magic,
        Error::UnsupportedVersion { .. } => CheckId::Version,
        Error::Checksum { .. } => CheckId::Checksum,
        Error::LimitExceeded { .. } => CheckId::Limit,
        Error::UnknownRequiredSection { .. } => CheckId::SectionTable,
        Error::Malformed { what, .. }
            if what.contains("truncated") || what.contains("past the end") || what.contains("outside") || what.contains("unexpected end") =>
        {
            CheckId::Truncated
        }
        _ => default,
    }
}

type Problem = (CheckId, String);

/// Parses a tree's index with the reader's parser, naming the failed check.
fn parse_tree_index(src: &Source<'_>, e: &SectionEntry, limits: &Limits) -> Result<TreeIndex, Problem> {
    crate::read::parse_tree_index(src, e, limits)
        .map_err(|er| (classify(&er, CheckId::TreeIndex), format!("{er} (tree section at byte {})", e.offset)))
}

/// A graph parsed leniently, with per-node transform problems.
struct Graph {
    graph: SceneGraph,
    node_problems: HashMap<u32, Vec<Problem>>,
}

fn transform_problems(t: &Similarity) -> Vec<Problem> {
    let finite = t.translation.iter().chain(t.rotation.iter()).all(|v| v.is_finite()) && t.scale.is_finite();
    if !finite {
        return vec![(CheckId::NonFinite, format!("instance transform has a non-finite component: {t}"))];
    }
    let mut out = Vec::new();
    let len = t.rotation.iter().map(|v| v * v).sum::<f64>().sqrt();
    if (len - 1.0).abs() > QUATERNION_TOL {
        out.push((CheckId::Quaternion, format!("rotation {:?} has length {len:.9}, expected 1 ± {QUATERNION_TOL:e}", t.rotation)));
    }
    if t.scale <= 0.0 {
        out.push((CheckId::Scale, format!("scale {} is not positive", t.scale)));
    }
    out
}

fn affine_problems(a: &crate::affine::Affine) -> Vec<Problem> {
    match a.problem() {
        None => Vec::new(),
        Some(m) if !a.matrix.iter().flatten().all(|v| v.is_finite()) => vec![(CheckId::NonFinite, m)],
        Some(m) => vec![(CheckId::Affine, m)],
    }
}

/// Parses the graph with the reader's parser, keeping per-node problems (bad references,
/// flags, inline paths, transforms, inline bounds) to report at each node's path. At most
/// `room` problems are kept (each is reported once, reachable or not, so no more can be
/// listed); the rest are added to `omitted`, so a hostile graph cannot make validation
/// hold one message per node before [`MAX_ISSUES`] applies.
fn parse_graph(bytes: &[u8], offset: u64, limits: &Limits, room: usize, issues: &mut Vec<Problem>, omitted: &mut u64) -> Option<Graph> {
    let (graph, problems) = match crate::read::parse_graph(bytes, offset, limits, crate::read::OnProblem::Keep(room), None) {
        Ok(g) => g,
        Err(e) => {
            issues.push((classify(&e, CheckId::Graph), e.to_string()));
            return None;
        }
    };
    *omitted = omitted.saturating_add(problems.omitted);
    let mut kept = problems.list.len();
    let mut node_problems: HashMap<u32, Vec<Problem>> = HashMap::new();
    for p in problems.list {
        match p.node {
            Some(i) => node_problems.entry(i).or_default().push((CheckId::Graph, p.message)),
            None => issues.push((CheckId::Graph, p.message)),
        }
    }
    for (i, n) in graph.nodes.iter().enumerate() {
        let probs = match n {
            GraphNode::Instance { transform, .. } => transform_problems(transform),
            GraphNode::Affine { transform, .. } => affine_problems(transform),
            GraphNode::Inline { bound, .. } if !bound.is_finite() => {
                vec![(CheckId::NonFinite, format!("inline bound has non-finite attributes: {bound}"))]
            }
            _ => continue,
        };
        for p in probs {
            if kept < room {
                kept += 1;
                node_problems.entry(i as u32).or_default().push(p);
            } else {
                *omitted = omitted.saturating_add(1);
            }
        }
    }
    Some(Graph { graph, node_problems })
}

/// The bound of every graph node in its file's frame (instances applied, push-down tints
/// included; `None` for empty or unusable trees and bad references), in one forward pass:
/// references point backwards, so a node's child is done before the node. (Asking per node
/// would walk instance chains again for every group child that uses them: quadratic.) Each
/// instance maps its child's bound, as the tree builder does when it makes group leaves.
fn graph_bounds(g: &SceneGraph, trees: &[Option<TreeIndex>]) -> Vec<Option<Node>> {
    let mut out: Vec<Option<Node>> = Vec::with_capacity(g.nodes.len());
    for n in &g.nodes {
        let b = match n {
            GraphNode::Tree { tree } | GraphNode::Group { tree, .. } => {
                trees.get(*tree as usize).and_then(|t| t.as_ref()).filter(|t| t.header.node_count > 0).map(|t| t.header.root)
            }
            GraphNode::Inline { bound, .. } => Some(*bound),
            n @ (GraphNode::Instance { .. } | GraphNode::Affine { .. }) => n.instance().and_then(|(child, transform, attrs)| {
                out.get(child as usize).copied().flatten().map(|c| TraversalState::IDENTITY.push(&transform, &attrs).apply(&c))
            }),
        };
        out.push(b);
    }
    out
}

/// One bit per node of one level, with a rank directory to map "k-th internal node" to its
/// index (for naming paths of failing nodes).
#[derive(Default)]
struct LevelBits {
    words: Vec<u64>,
    len: u64,
    /// Set bits before each word.
    before: Vec<u64>,
}

impl LevelBits {
    fn push(&mut self, f: bool) {
        if self.len % 64 == 0 {
            self.words.push(0);
        }
        if f {
            *self.words.last_mut().unwrap_or(&mut 0) |= 1 << (self.len % 64);
        }
        self.len += 1;
    }
    fn finish(&mut self) {
        let mut s = 0;
        self.before = self.words.iter().map(|w| { let b = s; s += w.count_ones() as u64; b }).collect();
    }
    /// Index of the `rank`-th set bit.
    fn select(&self, rank: u64) -> Option<u64> {
        let w = self.before.partition_point(|&b| b <= rank).checked_sub(1)?;
        let mut word = self.words[w];
        for _ in 0..(rank - self.before[w]) {
            word &= word.wrapping_sub(1);
        }
        (word != 0).then(|| w as u64 * 64 + word.trailing_zeros() as u64)
    }
}

/// Path of node `i` of level `d` below `prefix`.
fn node_path(levels: &[LevelBits], d: usize, mut i: u64, prefix: &str) -> String {
    let mut steps = Vec::with_capacity(d);
    for lvl in (1..=d).rev() {
        steps.push(i % 2);
        match levels.get(lvl - 1).and_then(|l| l.select(i / 2)) {
            Some(p) => i = p,
            None => return format!("{prefix}/?level{d}[{i}]"),
        }
    }
    let mut s = prefix.to_string();
    for st in steps.iter().rev() {
        s.push_str(if *st == 0 { "/0" } else { "/1" });
    }
    s
}

/// What an inline target turned out to be, remembered per canonical path so that each
/// distinct target is read, hashed and validated once however many inlines name it: its
/// hash and root bound, or why it could not be read.
type Target = Result<([u8; 32], Option<Node>), String>;

struct Validator<'o> {
    opts: &'o ValidateOptions,
    report: Report,
    /// Canonical paths of the files on the current inline branch.
    stack: Vec<PathBuf>,
    /// Inline targets met so far (see [`Target`]).
    targets: HashMap<PathBuf, Target>,
    /// The directory inline targets must stay in (`None` for a file held in memory).
    root: Option<PathBuf>,
    /// [`MAX_ISSUES`] (smaller in tests).
    max_issues: usize,
}

impl<'o> Validator<'o> {
    fn new(opts: &'o ValidateOptions) -> Self {
        Validator {
            opts,
            report: Report { deep: opts.deep, ..Default::default() },
            stack: Vec::new(),
            targets: HashMap::new(),
            root: None,
            max_issues: MAX_ISSUES,
        }
    }

    fn finish(self) -> Report {
        self.report
    }

    fn issue(&mut self, path: impl Into<String>, check: CheckId, label: &str, message: impl std::fmt::Display) {
        if self.report.issues.len() >= self.max_issues {
            self.report.issues_omitted += 1;
            return;
        }
        let message = if label.is_empty() { message.to_string() } else { format!("{label}: {message}") };
        self.report.issues.push(Issue { path: path.into(), check, message });
    }

    /// Validates one file whose graph root sits at abstract path `prefix`; `label` names the
    /// file in messages (empty for the top file). Returns the root bound.
    fn file(&mut self, src: &Source<'_>, path: Option<&Path>, prefix: &str, label: &str) -> Option<Node> {
        let limits = self.opts.limits.clone();
        let (header, sections) = match crate::read::parse_container(src, &limits) {
            Ok((h, s, _)) => (h, s),
            Err(e) => {
                self.issue("file", classify(&e, CheckId::SectionTable), label, &e);
                return None;
            }
        };
        let single = |tag| crate::container::single_in(&sections, tag, header.section_table_offset);
        let mut bad_crc = HashSet::new();
        for (i, e) in sections.iter().enumerate() {
            match src.crc32(e.offset, e.stored_len, "section data") {
                Ok(crc) if crc == e.crc => {}
                Ok(computed) => {
                    let er = Error::Checksum { what: format!("section {}", e.tag_str()), offset: e.offset, stored: e.crc, computed };
                    self.issue("file", CheckId::Checksum, label, format!("section {i}: {er}"));
                    bad_crc.insert(i);
                }
                Err(er) => {
                    self.issue("file", classify(&er, CheckId::Truncated), label, format!("section {i}: {er}"));
                    bad_crc.insert(i);
                }
            }
        }
        if sections.first().map(|e| e.tag) != Some(tags::GENR) {
            self.issue("file", CheckId::SectionTable, label, "the first section must be the generator (GENR)");
        }
        let sec_index = |tag: [u8; 4]| sections.iter().position(|e| e.tag == tag);
        // Generator.
        match single(tags::GENR) {
            Err(e) => self.issue("file", CheckId::SectionTable, label, e),
            Ok(e) if !bad_crc.contains(&sec_index(tags::GENR).unwrap_or(usize::MAX)) => {
                let bytes = section_bytes_in(src, e, limits.max_string_bytes as u64, "generator size", &limits);
                match bytes.map_err(|er| (classify(&er, CheckId::Generator), er.to_string())).and_then(|b| {
                    serde_json::from_slice::<Generator>(&b).map_err(|er| (CheckId::Generator, format!("generator JSON: {er}")))
                }) {
                    Ok(_) => {}
                    Err((k, m)) => self.issue("file", k, label, m),
                }
            }
            Ok(_) => {}
        }
        // Trees.
        let tree_secs: Vec<(usize, &SectionEntry)> = sections.iter().enumerate().filter(|(_, e)| e.tag == tags::TREE).collect();
        let mut trees: Vec<Option<TreeIndex>> = Vec::with_capacity(tree_secs.len());
        for (t, (si, e)) in tree_secs.iter().enumerate() {
            self.report.trees += 1;
            if bad_crc.contains(si) {
                trees.push(None);
                continue;
            }
            let parsed = parse_tree_index(src, e, &limits);
            match parsed {
                Ok(idx) => {
                    if idx.header.node_count > 0 && !idx.header.root.is_finite() {
                        self.issue(format!("tree/{t}"), CheckId::NonFinite, label, format!("root: {}", non_finite_what(&idx.header.root)));
                    }
                    trees.push(Some(idx));
                }
                Err((k, m)) => {
                    self.issue(format!("tree/{t}"), k, label, m);
                    trees.push(None);
                }
            }
        }
        // What the file stands for must be in proportion to its size before the graph is
        // inflated or any block decoded (spec §2.4); past that, nothing more is checked, as
        // the reader would refuse the file there too.
        let decoded = crate::read::scene_decoded_size(&sections, trees.iter().flatten().map(|t| t.header.node_count));
        if let Err(e) = limits.check_decoded(decoded, src.len()) {
            self.issue("file", CheckId::Limit, label, e);
            return None;
        }
        // Block CRCs (quick mode; deep mode checks them while decoding).
        if !self.opts.deep {
            for (t, idx) in trees.iter().enumerate() {
                let Some(idx) = idx else { continue };
                let bad: Vec<Problem> = (0..idx.blocks.len())
                    .into_par_iter()
                    .filter_map(|b| {
                        let e = &idx.blocks[b];
                        // Streamed: a block can be gigabytes, and every thread reads one.
                        match src.crc32(idx.section.offset + e.offset, e.stored_len as u64, "block") {
                            Err(er) => Some((classify(&er, CheckId::Truncated), format!("block {b}: {er}"))),
                            Ok(crc) if crc != e.crc => Some((
                                CheckId::Checksum,
                                format!("block {b} (level {}) CRC stored {:#010x}, computed {crc:#010x}", e.level, e.crc),
                            )),
                            _ => None,
                        }
                    })
                    .collect();
                self.report.blocks += idx.blocks.len() as u64;
                for (k, m) in bad {
                    self.issue(format!("tree/{t}"), k, label, m);
                }
            }
        }
        // Graph.
        let grph = match single(tags::GRPH) {
            Err(e) => {
                self.issue("file", CheckId::SectionTable, label, e);
                None
            }
            Ok(_) if bad_crc.contains(&sec_index(tags::GRPH).unwrap_or(usize::MAX)) => None,
            Ok(e) => match section_bytes_in(src, e, max_graph_section(&limits), "scene graph section bytes", &limits) {
                Err(er) => {
                    self.issue("graph", classify(&er, CheckId::Graph), label, er);
                    None
                }
                Ok(b) => {
                    let mut probs = Vec::new();
                    let room = self.max_issues.saturating_sub(self.report.issues.len());
                    let mut omitted = 0;
                    let g = parse_graph(&b, e.offset, &limits, room, &mut probs, &mut omitted);
                    self.report.issues_omitted = self.report.issues_omitted.saturating_add(omitted);
                    for (k, m) in probs {
                        self.issue("graph", k, label, m);
                    }
                    g
                }
            },
        };
        let mut tree_paths: Vec<Option<String>> = vec![None; trees.len()];
        let root_bound = match &grph {
            Some(g) => {
                self.walk(src, path, g, &trees, &mut tree_paths, prefix, label);
                crate::traverse::bound_in_graph(&g.graph, g.graph.root, |t| {
                    let t = trees.get(t as usize)?.as_ref()?;
                    (t.header.node_count > 0).then_some(t.header.root)
                })
            }
            None => None,
        };
        if self.opts.deep {
            for (t, idx) in trees.iter().enumerate() {
                let Some(idx) = idx else { continue };
                let p = tree_paths[t].clone().unwrap_or_else(|| format!("tree/{t}"));
                self.check_tree(src, idx, &p, label);
            }
        }
        root_bound
    }

    /// Walks the graph from the root, naming each node by its abstract path, checking group
    /// leaves against their children and following inlines. Every graph node is visited once
    /// (by the first path that reaches it, depth first), so shared subgraphs cost nothing
    /// more; a group's children are handed out one at a time by its stack frame, so a group
    /// of 2^30 children costs one frame, and a child's path is built only when it is visited.
    #[allow(clippy::too_many_arguments)]
    fn walk(&mut self, src: &Source<'_>, path: Option<&Path>, g: &Graph, trees: &[Option<TreeIndex>], tree_paths: &mut [Option<String>], prefix: &str, label: &str) {
        enum Item {
            Node(u32, String),
            Children { node: u32, base: String, leaves: Option<GroupLeaves>, next: usize },
        }
        let nodes = &g.graph.nodes;
        let mut visited = vec![false; nodes.len()];
        // Bounds of graph nodes for the deep group checks, computed once per file on demand.
        let mut bounds: Option<Vec<Option<Node>>> = None;
        let mut stack = vec![Item::Node(g.graph.root, prefix.to_string())];
        while let Some(top) = stack.last_mut() {
            let (n, p) = match top {
                Item::Children { node, base, leaves, next } => {
                    let Some(GraphNode::Group { children, .. }) = nodes.get(*node as usize) else {
                        stack.pop();
                        continue;
                    };
                    let mut found = None;
                    while *next < children.len() {
                        let j = *next;
                        *next += 1;
                        let c = children[j];
                        // Bad references (kept as u32::MAX) and nodes already visited are skipped
                        // here rather than after being stacked.
                        if visited.get(c as usize).is_none_or(|&v| v) {
                            continue;
                        }
                        let path = leaves.as_ref().and_then(|l| l.path(j, base)).unwrap_or_else(|| format!("{base}/child{j}"));
                        found = Some((c, path));
                        break;
                    }
                    match found {
                        Some(x) => x,
                        None => {
                            stack.pop();
                            continue;
                        }
                    }
                }
                Item::Node(..) => match stack.pop() {
                    Some(Item::Node(n, p)) => (n, p),
                    _ => continue,
                },
            };
            let Some(slot) = visited.get_mut(n as usize) else { continue };
            if std::mem::replace(slot, true) {
                continue;
            }
            if let Some(probs) = g.node_problems.get(&n) {
                for (k, m) in probs.clone() {
                    self.issue(p.clone(), k, label, format!("graph node {n}: {m}"));
                }
            }
            let tree_ok = |t: u32, me: &mut Self| -> Option<usize> {
                if (t as usize) < trees.len() {
                    Some(t as usize)
                } else {
                    me.issue(p.clone(), CheckId::Graph, label, format!("graph node {n} refers to tree {t}, the file has {}", trees.len()));
                    None
                }
            };
            match &nodes[n as usize] {
                GraphNode::Tree { tree } => {
                    if let Some(t) = tree_ok(*tree, self) {
                        tree_paths[t].get_or_insert_with(|| p.clone());
                    }
                }
                GraphNode::Group { children, tree } => {
                    let Some(t) = tree_ok(*tree, self) else { continue };
                    tree_paths[t].get_or_insert_with(|| p.clone());
                    let mut leaves = None;
                    if let Some(idx) = &trees[t] {
                        // The leaf count first: nothing is decoded or named for a group whose
                        // tree cannot stand for its children.
                        if idx.header.leaf_count != children.len() as u64 {
                            self.issue(
                                p.clone(),
                                CheckId::Graph,
                                label,
                                format!("group (graph node {n}) has {} children, its tree {t} has {} leaves", children.len(), idx.header.leaf_count),
                            );
                        } else if let Ok(gt) = self.decode_small_tree(src, idx) {
                            let gl = GroupLeaves::new(gt);
                            if self.opts.deep {
                                let b = bounds.get_or_insert_with(|| graph_bounds(&g.graph, trees));
                                self.check_group(b, &gl, children, &p, idx.profile, label);
                            }
                            leaves = Some(gl);
                        }
                    }
                    stack.push(Item::Children { node: n, base: p, leaves, next: 0 });
                }
                GraphNode::Instance { child, .. } | GraphNode::Affine { child, .. } => {
                    if *child != u32::MAX {
                        stack.push(Item::Node(*child, p));
                    }
                }
                GraphNode::Inline { path: rel, hash, bound } => {
                    self.inline(path, rel, hash, bound, &p, n, label);
                }
            }
        }
        for (i, v) in visited.iter().enumerate() {
            if !v {
                if let Some(probs) = g.node_problems.get(&(i as u32)) {
                    for (k, m) in probs.clone() {
                        self.issue(format!("graph/{i}"), k, label, format!("unreachable graph node {i}: {m}"));
                    }
                }
                // Tree references are checked for every node, as the reader does: an
                // unreachable node naming a tree the file lacks (or a group whose tree does not
                // have one leaf per child) makes the file unreadable, reachable or not.
                let what = match &nodes[i] {
                    GraphNode::Tree { tree } | GraphNode::Group { tree, .. } if *tree as usize >= trees.len() => {
                        Some(format!("refers to tree {tree}, the file has {}", trees.len()))
                    }
                    GraphNode::Group { children, tree } => trees[*tree as usize]
                        .as_ref()
                        .filter(|idx| idx.header.leaf_count != children.len() as u64)
                        .map(|idx| format!("is a group of {} children, its tree {tree} has {} leaves", children.len(), idx.header.leaf_count)),
                    _ => None,
                };
                if let Some(m) = what {
                    self.issue(format!("graph/{i}"), CheckId::Graph, label, format!("unreachable graph node {i} {m}"));
                }
            }
        }
    }

    /// Decodes a (group) tree completely; group trees have one leaf per child, so their size
    /// is bounded by the graph's ([`Limits::max_graph_bytes`]).
    fn decode_small_tree(&self, src: &Source<'_>, idx: &TreeIndex) -> Result<SceneTree, Problem> {
        let limits = &self.opts.limits;
        crate::read::read_levels(idx, usize::MAX, |b, ps| crate::read::decode_block_in(src, idx, b, ps, limits))
            .map_err(|er| (classify(&er, CheckId::BlockDecode), er.to_string()))
    }

    /// Group leaf `j` must stand for child `j`: contain its bound and carry its area, cone
    /// and colour (§5.10.5 virtual roots; instance transforms and push-down tints applied).
    /// `bounds` are the graph's node bounds ([`graph_bounds`]); paths are named only for
    /// leaves that fail.
    fn check_group(&mut self, bounds: &[Option<Node>], gl: &GroupLeaves, children: &[u32], base: &str, profile: Profile, label: &str) {
        let gt = gl.tree();
        let slack = Profile::Raw.containment_slack().max(profile.containment_slack());
        // Area error each node may carry from its ancestors' coding (breadth first: parents
        // come before their children).
        let per_level = area_level_tolerance(profile);
        let mut area_slack = vec![0f64; gt.len()];
        for i in 0..gt.len() {
            if let Some(kids) = gt.children(i) {
                let s = area_slack[i] + per_level * f64::from(gt.nodes()[i].area).abs();
                kids.iter().for_each(|&k| area_slack[k] = s);
            }
        }
        for (j, &c) in children.iter().enumerate() {
            let (Some(li), Some(cb)) = (gl.leaf_index(j), bounds.get(c as usize).copied().flatten()) else { continue };
            let leaf = gt.nodes()[li];
            if !leaf.is_finite() || !cb.is_finite() {
                continue; // reported by the node checks
            }
            let mut out = Vec::new();
            check_contained(&leaf, &cb, slack, cone_tolerance(profile), 0, &mut out);
            if !area_ok_within(leaf.area, cb.area as f64, area_slack[li]) {
                out.push((0, CheckId::AreaSum, format!("group leaf area {:.6}, child {:.6} (instance scale² applied)", leaf.area, cb.area)));
            }
            if !color_ok(leaf.color, cb.color, color_tolerance(profile)) {
                out.push((0, CheckId::ColorMean, format!("group leaf colour {:?}, child {:?} (push-down tint applied)", leaf.color, cb.color)));
            }
            for (_, k, m) in out {
                let path = gl.path(j, base).unwrap_or_else(|| format!("{base}/child{j}"));
                self.issue(path, k, label, format!("group leaf {j} vs graph node {c}: {m}"));
            }
        }
    }

    #[allow(clippy::too_many_arguments)]
    fn inline(&mut self, from: Option<&Path>, rel: &str, hash: &[u8; 32], bound: &Node, p: &str, n: u32, label: &str) {
        let Some(from) = from else {
            self.issue(p, CheckId::InlineMissing, label, format!("graph node {n}: inline {rel:?} cannot be resolved for a file held in memory"));
            return;
        };
        let root = if self.opts.allow_outside_inlines { None } else { self.root.clone() };
        let canon = match crate::traverse::resolve_inline(from, rel, root.as_deref()) {
            Ok(c) => c,
            Err(TraverseErrorKind::InlineOutside { target, root }) => {
                // Not opened: a scene must not make the validator read (or print the hash of)
                // files outside its directory.
                let m = format!("graph node {n}: inline target {} lies outside the scene directory {}", target.display(), root.display());
                self.issue(p, CheckId::InlineOutside, label, m);
                return;
            }
            Err(TraverseErrorKind::InlineMissing { target, source }) => {
                self.issue(p, CheckId::InlineMissing, label, format!("graph node {n}: inline target {} is missing: {source}", target.display()));
                return;
            }
            Err(e) => {
                self.issue(p, CheckId::InlineMissing, label, format!("graph node {n}: {e}"));
                return;
            }
        };
        if self.stack.contains(&canon) {
            let chain: Vec<String> = self.stack.iter().chain(std::iter::once(&canon)).map(|p| p.display().to_string()).collect();
            self.issue(p, CheckId::InlineCycle, label, format!("graph node {n}: inline cycle {}", chain.join(" -> ")));
            return;
        }
        let depth = self.stack.len() as u32; // inlines followed to reach the target
        if depth > self.opts.limits.max_inline_depth {
            self.issue(p, CheckId::InlineDepth, label, format!("graph node {n}: inlines nest deeper than {}", self.opts.limits.max_inline_depth));
            return;
        }
        let (found, root, first) = match self.targets.get(&canon) {
            Some(Ok((h, r))) => (*h, *r, false),
            Some(Err(m)) => {
                let m = m.clone();
                self.issue(p, CheckId::InlineMissing, label, format!("graph node {n}: {m}"));
                return;
            }
            None => {
                // First inline naming this target: read it (regular files only, in pieces),
                // hash it and validate it, once.
                let opened = Source::open(&canon).and_then(|s| s.blake3().map(|h| (s, h)));
                let (src, found) = match opened {
                    Ok(x) => x,
                    Err(e) => {
                        let m = format!("inline target cannot be read: {e}");
                        self.targets.insert(canon.clone(), Err(m.clone()));
                        self.issue(p, CheckId::InlineMissing, label, format!("graph node {n}: {m}"));
                        return;
                    }
                };
                self.check_hash(&canon, &found, hash, p, n, label);
                self.report.files.push(canon.clone());
                self.stack.push(canon.clone());
                let sub = if label.is_empty() { rel.to_string() } else { format!("{label} > {rel}") };
                let r = self.file(&src, Some(&canon), p, &sub);
                self.stack.pop();
                self.targets.insert(canon.clone(), Ok((found, r)));
                (found, r, true)
            }
        };
        if !first {
            self.check_hash(&canon, &found, hash, p, n, label);
        }
        if let (true, Some(r)) = (self.opts.deep, root) {
            let ok = sphere_contains(bound, &r, Profile::Raw.containment_slack())
                && area_ok(bound.area, r.area as f64)
                && cone_contains(bound.normal, bound.cone, r.normal, r.cone, cone_tolerance(Profile::Raw))
                && color_ok(bound.color, r.color, color_tolerance(Profile::Raw));
            if !ok {
                self.issue(p, CheckId::InlineBound, label, format!("graph node {n}: recorded bound ({bound}) does not match the root of {rel} ({r})"));
            }
        }
    }

    fn check_hash(&mut self, canon: &Path, found: &[u8; 32], recorded: &[u8; 32], p: &str, n: u32, label: &str) {
        if found != recorded {
            self.issue(
                p,
                CheckId::InlineHash,
                label,
                format!("graph node {n}: inline target {} has BLAKE3 {}, recorded {}", canon.display(), hex(found), hex(recorded)),
            );
        }
    }

    /// Deep check of one tree: every block decoded once, every child checked against its
    /// decoded parent. Blocks are decoded as a wavefront over all levels (see [`Wavefront`]),
    /// so besides one bit per node (to name failing paths) memory stays bounded by a few
    /// blocks per level, whatever the tree's width.
    fn check_tree(&mut self, src: &Source<'_>, idx: &TreeIndex, prefix: &str, label: &str) {
        if idx.header.node_count == 0 {
            return;
        }
        let root = idx.header.root;
        let mut w = Wavefront::new(idx, &self.opts.limits, self.max_issues.saturating_sub(self.report.issues.len()));
        w.bits[0].push(idx.header.root_internal == 1);
        let mut root_issues = Vec::new();
        check_node(&root, 0, &mut root_issues);
        w.keep(0, root_issues);
        if idx.header.root_internal == 1 {
            w.fronts[0].queue.push_back(root);
        }
        w.nodes += 1;
        // Deepest level first: it pulls its ancestors' blocks as it needs their nodes; what
        // is left above afterwards are blocks of leaves only.
        let mut failed = None;
        'levels: for d in (1..idx.levels.len()).rev() {
            while w.fronts[d].next_block < w.fronts[d].end_block {
                if let Err(f) = w.advance(src, d) {
                    failed = Some(f);
                    break 'levels;
                }
            }
        }
        self.report.nodes += w.nodes;
        self.report.issues_omitted += w.omitted;
        self.report.blocks += w.blocks;
        if let Some((d, (k, m))) = failed {
            // Deeper nodes need the failed block's nodes as parents: stop this tree.
            self.issue(prefix, k, label, format!("level {d}: {m}; the rest of the tree is not checked"));
        }
        let mut levels = w.bits;
        levels.iter_mut().for_each(LevelBits::finish);
        for (d, i, k, m) in w.pending {
            let path = if i & PARENT_BIT != 0 {
                let child = i & !PARENT_BIT;
                match d.checked_sub(1).and_then(|pd| levels.get(pd).and_then(|l| l.select(child / 2)).map(|pi| (pd, pi))) {
                    Some((pd, pi)) => node_path(&levels, pd, pi, prefix),
                    None => format!("{prefix}/?"),
                }
            } else {
                node_path(&levels, d, i, prefix)
            };
            self.issue(path, k, label, m);
        }
    }
}
