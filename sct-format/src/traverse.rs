//! Abstract scene-graph traversal (thesis §5.10.2, §5.11.2).
//!
//! The thesis hides groups, instances and inlines behind "scene node specifiers" so that a
//! client sees one binary scene tree. [`Traversal`] does the graph half of that: it walks the
//! scene graph from the root, composes instance transforms and push-down tints, follows
//! inlines into other files (hash-checked, cycle- and depth-bounded), and yields one
//! [`Reached`] per scene tree it arrives at, with the world transform to apply to that
//! tree's nodes. The client then reads the tree's levels itself (progressively, if it
//! likes) and maps every node through [`TraversalState::apply`].
//!
//! The iterator is lazy: nothing below a group is expanded until the iterator is advanced
//! past the group, so a renderer can [`Traversal::skip_children`] of a group it culled, or
//! install a [`Traversal::set_cull`] predicate that sees each pending child's world bound
//! (a group leaf, or an inline's recorded bound) *before* it is expanded or its file opened.
//!
//! # Paths
//!
//! Every node is named by its path in the *abstract* binary tree: `root`, then `/0` or `/1`
//! per step to the first or second child. Instances and inlines add no step (they are the
//! same abstract node as their child); leaf `j` of a group's tree *is* the virtual root of
//! the group's child `j` (§5.10.5), so the child's root has the leaf's path. A scene tree
//! reached at path `P` has its node `root/…` at `P/…`; this is the path the validator reports.
//!
//! # Attribute propagation (§5.11.2)
//!
//! Position, radius (× s), cone axis (rotated) and area (× s²) always follow the instance
//! transform: our files store the fitting transform explicitly, so "push-down size" (fit the
//! child into the instance root) and "pull-up size" (keep the child's own size) differ only in
//! how the writer chose the transform, not in how it is applied. Colour is pull-up by default
//! (colours are used unchanged); an instance with push-down colour and a tint multiplies the
//! tint (`t / 255` per channel, RGBA) into every colour below it, composing multiplicatively
//! with outer tints, clipped to [0, 255]. A tint on a pull-up instance is ignored.
//!
//! An affine instance (format 1.3) composes like a similarity; below it the world transform
//! is a general affine map ([`Transform::Affine`]) and nodes map as [`crate::affine`]
//! describes: radius × σ_max, axis by the inverse transpose, cone × condition number (≤ π),
//! area by Nanson's factor of the axis.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use crate::affine::Transform;
use crate::error::Error;
use crate::graph::{GraphNode, InstanceAttrs, Propagation, SceneGraph, Similarity};
use crate::limits::Limits;
use crate::node::Node;
use crate::read::SctReader;

/// The push-down state accumulated from the root to a graph node.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TraversalState {
    /// Local-to-world transform: a similarity until an affine instance is on the path.
    pub transform: Transform,
    /// Per-channel RGBA colour multiplier from push-down tints (1.0 = unchanged).
    pub tint: [f32; 4],
}

impl Default for TraversalState {
    fn default() -> Self {
        TraversalState::IDENTITY
    }
}

impl TraversalState {
    /// No transform, no tint.
    pub const IDENTITY: TraversalState = TraversalState { transform: Transform::IDENTITY, tint: [1.0; 4] };

    /// The state below a similarity instance with `transform` and `attrs`.
    pub fn push_instance(&self, transform: &Similarity, attrs: &InstanceAttrs) -> TraversalState {
        self.push(&Transform::Similarity(*transform), attrs)
    }

    /// The state below an instance of either kind (a similarity or an affine map).
    pub fn push(&self, transform: &Transform, attrs: &InstanceAttrs) -> TraversalState {
        let mut tint = self.tint;
        if let (Propagation::PushDown, Some(t)) = (attrs.color, attrs.tint) {
            for (m, &c) in tint.iter_mut().zip(&t) {
                *m *= c as f32 / 255.0;
            }
        }
        TraversalState { transform: self.transform.compose(transform), tint }
    }

    /// True when some tint changes colours.
    pub fn is_tinted(&self) -> bool {
        self.tint != [1.0; 4]
    }

    /// Maps a node from the tree's frame to the world: transform, then tint.
    pub fn apply(&self, n: &Node) -> Node {
        let mut out = if self.transform == Transform::IDENTITY { *n } else { self.transform.apply_node(n) };
        out.color = tint_color(out.color, self.tint);
        out
    }
}

/// Multiplies a colour by a per-channel tint, rounding to nearest and clipping.
pub fn tint_color(c: [u8; 4], tint: [f32; 4]) -> [u8; 4] {
    if tint == [1.0; 4] {
        return c;
    }
    let mut out = [0u8; 4];
    for i in 0..4 {
        out[i] = (c[i] as f32 * tint[i]).round().clamp(0.0, 255.0) as u8;
    }
    out
}

/// Appends one abstract-tree step (`0` or `1`) to `path`.
pub fn child_path(path: &str, step: usize) -> String {
    format!("{path}/{step}")
}

/// The leaves of a group's tree, so that its children can be named and bounded one at a
/// time: leaf `j` (breadth-first leaf order) stands for the group's child `j` (§5.10.5).
/// Holds the tree and 8 bytes per node; no path is built until one is asked for.
#[derive(Clone, Debug)]
pub struct GroupLeaves {
    tree: crate::SceneTree,
    parents: Vec<u32>,
    leaves: Vec<u32>,
}

impl GroupLeaves {
    /// The leaves of `tree`.
    pub fn new(tree: crate::SceneTree) -> Self {
        let parents = tree.parents();
        // Node indices fit in u32: a SceneTree holds fewer than u32::MAX nodes.
        let leaves = tree.leaves().map(|i| i as u32).collect();
        GroupLeaves { tree, parents, leaves }
    }

    /// Number of leaves.
    pub fn len(&self) -> usize {
        self.leaves.len()
    }

    /// True for a tree without leaves.
    pub fn is_empty(&self) -> bool {
        self.leaves.is_empty()
    }

    /// The tree.
    pub fn tree(&self) -> &crate::SceneTree {
        &self.tree
    }

    /// Node index (breadth first) of leaf `j`.
    pub fn leaf_index(&self, j: usize) -> Option<usize> {
        self.leaves.get(j).map(|&i| i as usize)
    }

    /// Leaf `j`, if there is one.
    pub fn leaf(&self, j: usize) -> Option<&Node> {
        self.tree.nodes().get(*self.leaves.get(j)? as usize)
    }

    /// The abstract path of leaf `j` below `base`.
    pub fn path(&self, j: usize, base: &str) -> Option<String> {
        Some(path_of(&self.tree, &self.parents, *self.leaves.get(j)? as usize, base))
    }
}

/// The abstract path of node `leaf` of `tree` below `base` (`parents` from
/// [`crate::SceneTree::parents`]).
fn path_of(tree: &crate::SceneTree, parents: &[u32], leaf: usize, base: &str) -> String {
    let mut steps = Vec::new();
    let mut i = leaf;
    // Parents come before their children, so this walk ends at the root.
    while let Some(&p) = parents.get(i).filter(|&&p| p != crate::tree::NO_CHILD && (p as usize) < i) {
        let p = p as usize;
        steps.push(if tree.children(p).is_some_and(|c| c[0] == i) { b'0' } else { b'1' });
        i = p;
    }
    let mut s = String::with_capacity(base.len() + 2 * steps.len());
    s.push_str(base);
    for &st in steps.iter().rev() {
        s.push('/');
        s.push(st as char);
    }
    s
}

/// The abstract path of every leaf of `tree` (breadth-first leaf order), each prefixed by
/// `base`. Leaf `j` of a group's tree is the virtual root of the group's child `j`. (One
/// string per leaf: [`GroupLeaves::path`] names them one at a time.)
pub fn leaf_paths(tree: &crate::SceneTree, base: &str) -> Vec<String> {
    let parents = tree.parents();
    tree.leaves().map(|leaf| path_of(tree, &parents, leaf, base)).collect()
}

/// The bound of graph node `node` of `file` in that file's frame: a tree's or group's root,
/// an inline's recorded bound, an instance's child bound transformed (and tinted).
pub fn graph_bound(file: &SctReader, node: u32) -> Option<Node> {
    bound_in_graph(file.graph(), node, |t| {
        let t = file.trees().get(t as usize)?;
        (t.header.node_count > 0).then_some(t.header.root)
    })
}

/// [`graph_bound`] over any source of tree roots: `tree_root(t)` is tree `t`'s root, `None`
/// when the tree is empty or unusable.
pub(crate) fn bound_in_graph(g: &SceneGraph, node: u32, tree_root: impl Fn(u32) -> Option<Node>) -> Option<Node> {
    let mut state = TraversalState::IDENTITY;
    let mut at = node;
    // Instance chains only point backwards, so this loop ends after at most `nodes` steps.
    for _ in 0..=g.nodes.len() {
        match g.nodes.get(at as usize)? {
            GraphNode::Tree { tree } | GraphNode::Group { tree, .. } => return tree_root(*tree).map(|r| state.apply(&r)),
            GraphNode::Inline { bound, .. } => return Some(state.apply(bound)),
            n @ (GraphNode::Instance { .. } | GraphNode::Affine { .. }) => {
                let (child, transform, attrs) = n.instance()?;
                state = state.push(&transform, &attrs);
                at = child;
            }
        }
    }
    None
}

/// What kind of scene tree was reached.
#[derive(Clone, Debug, PartialEq)]
pub enum ReachedKind {
    /// A geometry tree: its leaves are surface samples.
    Tree,
    /// A group's tree: leaf `j` bounds graph node `children[j]`, which the traversal visits
    /// next (unless skipped or culled).
    Group {
        /// The group's child graph nodes.
        children: Vec<u32>,
    },
}

/// One scene tree reached by the traversal.
#[derive(Clone, Debug)]
pub struct Reached {
    /// Abstract path of the tree's root (see the module docs).
    pub path: String,
    /// The file holding the tree.
    pub file: Arc<SctReader>,
    /// That file's path.
    pub file_path: PathBuf,
    /// The graph node (in `file`) that owns the tree.
    pub graph_node: u32,
    /// Tree index in `file`.
    pub tree: usize,
    /// World transform and tint for the tree's nodes.
    pub state: TraversalState,
    /// Geometry or group tree.
    pub kind: ReachedKind,
    /// Number of inlines followed to get here.
    pub inline_depth: u32,
}

impl Reached {
    /// The tree's root in world space (from the tree header; no block is read).
    pub fn world_root(&self) -> Option<Node> {
        let t = self.file.trees().get(self.tree)?;
        (t.header.node_count > 0).then(|| self.state.apply(&t.header.root))
    }
}

/// Why a branch of the traversal could not be followed. The traversal goes on with the other
/// branches, except after [`Limits::max_traversal_visits`] is reached (a
/// [`TraverseErrorKind::Read`] of [`Error::LimitExceeded`]), where it ends.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum TraverseErrorKind {
    /// The inline target does not exist or cannot be opened.
    #[error("inline target {target} cannot be opened: {source}")]
    InlineMissing {
        /// Resolved target path.
        target: PathBuf,
        /// The I/O error.
        #[source]
        source: std::io::Error,
    },
    /// The inline target's BLAKE3 hash differs from the recorded one.
    #[error("inline target {target} has BLAKE3 {found}, the inline records {expected}")]
    InlineHash {
        /// Resolved target path.
        target: PathBuf,
        /// Recorded hash (hex).
        expected: String,
        /// Hash of the file (hex).
        found: String,
    },
    /// The inline target is already being traversed on this branch.
    #[error("inline cycle: {}", chain.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(" -> "))]
    InlineCycle {
        /// The files on the branch, ending with the repeated one.
        chain: Vec<PathBuf>,
    },
    /// More nested inlines than [`Limits::max_inline_depth`].
    #[error("inline nesting deeper than the limit of {limit}")]
    InlineDepth {
        /// The limit.
        limit: u32,
    },
    /// The inline target (symlinks resolved) lies outside the scene's directory, and the
    /// caller did not allow that ([`TraverseOptions::allow_outside_inlines`]). The target is
    /// not opened, so a scene cannot make a tool read (or report the hash of) files
    /// elsewhere on the system.
    #[error("inline target {target} lies outside the scene directory {root} (not followed unless outside inlines are allowed)")]
    InlineOutside {
        /// Resolved target path.
        target: PathBuf,
        /// The scene directory.
        root: PathBuf,
    },
    /// The inline target (or a group tree) could not be read, or the traversal reached
    /// [`Limits::max_traversal_visits`].
    #[error("{0}")]
    Read(#[from] Error),
}

/// A traversal failure at `path`.
#[derive(Debug, thiserror::Error)]
#[error("{path}: {kind}")]
pub struct TraverseError {
    /// Abstract path of the node that failed.
    pub path: String,
    /// The file whose graph holds the failing node.
    pub file: PathBuf,
    /// Graph node index in that file.
    pub graph_node: u32,
    /// What went wrong.
    pub kind: TraverseErrorKind,
}

impl TraverseError {
    /// True when the traversal stopped at [`Limits::max_traversal_visits`] (it yields nothing
    /// after this error).
    pub fn is_visit_limit(&self) -> bool {
        matches!(&self.kind, TraverseErrorKind::Read(Error::LimitExceeded { what, .. }) if *what == VISITS)
    }
}

/// The quantity [`Limits::max_traversal_visits`] caps, as errors name it.
pub const VISITS: &str = "graph nodes visited by a traversal (a shared node counts once per path that reaches it)";

/// Counts graph-node visits against [`Limits::max_traversal_visits`]. [`Traversal`] uses one;
/// a consumer with its own graph walk (a renderer refining group trees lazily) charges one
/// per node it visits, so that every walk of a DAG of shared groups is bounded alike.
#[derive(Clone, Debug)]
pub struct VisitBudget {
    used: u64,
    limit: u64,
}

impl VisitBudget {
    /// A budget of `limits.max_traversal_visits`.
    pub fn new(limits: &Limits) -> Self {
        VisitBudget { used: 0, limit: limits.max_traversal_visits }
    }

    /// Records `n` more visits; [`Error::LimitExceeded`] (naming [`VISITS`]) past the limit.
    pub fn charge(&mut self, n: u64) -> Result<(), Error> {
        self.used = self.used.saturating_add(n);
        Limits::check(VISITS, self.used, self.limit)
    }

    /// Visits recorded so far.
    pub fn used(&self) -> u64 {
        self.used
    }
}

/// Resolves inline path `rel` of the file at `from` (a canonical path): joined to `from`'s
/// directory and canonicalized (symlinks resolved). With `root` (a canonical directory), a
/// target outside it is [`TraverseErrorKind::InlineOutside`] and is not opened. The same
/// rules for every consumer that follows inlines.
pub fn resolve_inline(from: &Path, rel: &str, root: Option<&Path>) -> Result<PathBuf, TraverseErrorKind> {
    let dir = from.parent().unwrap_or(Path::new("."));
    let target = dir.join(rel);
    let canon = std::fs::canonicalize(&target).map_err(|source| TraverseErrorKind::InlineMissing { target: target.clone(), source })?;
    if let Some(root) = root {
        if !canon.starts_with(root) {
            return Err(TraverseErrorKind::InlineOutside { target: canon, root: root.to_path_buf() });
        }
    }
    Ok(canon)
}

/// The directory inline targets must stay in for a scene whose top file is at `canonical`.
pub fn scene_root(canonical: &Path) -> PathBuf {
    canonical.parent().unwrap_or(Path::new("/")).to_path_buf()
}

/// The inline chain of one branch, for cycle detection (a persistent stack shared by
/// siblings).
#[derive(Debug)]
struct Chain {
    path: PathBuf,
    parent: Option<Arc<Chain>>,
    depth: u32,
}

impl Chain {
    fn contains(self: &Arc<Self>, p: &Path) -> bool {
        let mut c = Some(self);
        while let Some(x) = c {
            if x.path == p {
                return true;
            }
            c = x.parent.as_ref();
        }
        false
    }
    fn to_vec(self: &Arc<Self>) -> Vec<PathBuf> {
        let mut v = Vec::new();
        let mut c = Some(self);
        while let Some(x) = c {
            v.push(x.path.clone());
            c = x.parent.as_ref();
        }
        v.reverse();
        v
    }
}

struct Pending {
    file: Arc<SctReader>,
    chain: Arc<Chain>,
    node: u32,
    path: String,
    state: TraversalState,
    /// World bound known before expansion (group leaf or inline bound), for culling.
    bound: Option<Node>,
}

impl Pending {
    /// What the traversal yields on arriving at this node's scene tree.
    fn reached(&self, tree: u32, kind: ReachedKind) -> Reached {
        Reached {
            path: self.path.clone(),
            file: self.file.clone(),
            file_path: self.chain.path.clone(),
            graph_node: self.node,
            tree: tree as usize,
            state: self.state,
            kind,
            inline_depth: self.chain.depth,
        }
    }
}

/// The children of one use of a group, handed out one at a time: a group of a million
/// children costs one frame on the stack, not a million pending entries, and each child's
/// path is built only when the child is visited.
struct GroupFrame {
    group: Pending,
    leaves: Arc<GroupLeaves>,
    next: usize,
}

/// Most nodes of group trees a traversal keeps decoded for reuse ([`Traversal`]): 2^21
/// (about 100 MB). A group used on many paths (a DAG of shared groups, a group instanced a
/// million times) is decoded once instead of once per path: at 10^7 visits, decoding per
/// path took an export 26 s.
const GROUP_CACHE_NODES: usize = 1 << 21;

/// An entry of the traversal's stack. A pending node carries its world transform (an
/// affine one is a few hundred bytes); the stack holds one path, so its size does not matter.
#[allow(clippy::large_enum_variant)]
enum Frame {
    One(Pending),
    Children(Box<GroupFrame>),
}

/// Options of a traversal.
#[derive(Clone, Debug)]
pub struct TraverseOptions {
    /// Limits for every file opened (inline depth and visits included).
    pub limits: Limits,
    /// Check each inline target's BLAKE3 hash (reads the whole target once per file).
    pub verify_inline_hashes: bool,
    /// Follow inlines whose target (symlinks resolved) lies outside the directory of the file
    /// the traversal started from. Off by default: a scene file is data, and following
    /// `../../` paths would let it make a tool open (and hash) any file on the system.
    pub allow_outside_inlines: bool,
}

impl Default for TraverseOptions {
    fn default() -> Self {
        TraverseOptions { limits: Limits::default(), verify_inline_hashes: true, allow_outside_inlines: false }
    }
}

type CullFn = Box<dyn FnMut(&Node, &str) -> bool + Send>;

/// A lazy depth-first walk of a scene graph and the files it inlines; an iterator of
/// [`Reached`] trees (or [`TraverseError`]s for branches that cannot be followed).
///
/// Bounded work: every graph node visited on every path counts against
/// [`Limits::max_traversal_visits`] (a shared subgraph is expanded once per path that
/// reaches it, and a DAG of shared groups has exponentially many paths); past the limit
/// the traversal yields one limit-exceeded error and ends. Memory is the stack of the
/// current path (a group is one frame whatever its width), the group trees on it, decoded
/// group trees kept for reuse (at most [`GROUP_CACHE_NODES`] nodes), and one reader per
/// distinct file opened.
pub struct Traversal {
    opts: TraverseOptions,
    stack: Vec<Frame>,
    /// The last yielded group, expanded on the next call unless skipped.
    deferred: Option<Pending>,
    /// Open files by canonical path (each reader remembers its hash once computed).
    files: HashMap<PathBuf, Arc<SctReader>>,
    cull: Option<CullFn>,
    /// The directory inline targets must stay in (unless allowed).
    root: PathBuf,
    budget: VisitBudget,
    /// Decoded group trees by (reader, tree), while they total at most
    /// [`GROUP_CACHE_NODES`] nodes; the readers live in `files` as long as the traversal, so
    /// their addresses identify them.
    groups: HashMap<(usize, u32), Arc<GroupLeaves>>,
    group_nodes: usize,
}

impl std::fmt::Debug for Traversal {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Traversal").field("pending", &self.stack.len()).field("visits", &self.budget.used()).finish_non_exhaustive()
    }
}

impl Traversal {
    /// Opens `path` and starts a traversal at its graph root.
    pub fn open(path: &Path, opts: TraverseOptions) -> Result<Traversal, Error> {
        let canon = std::fs::canonicalize(path).map_err(|e| Error::io(path, e))?;
        let file = Arc::new(SctReader::open(&canon, &opts.limits)?);
        Ok(Self::from_reader(file, canon, opts))
    }

    /// Starts a traversal at the graph root of an open file; `canonical_path` locates its
    /// inlines (their paths are relative to its directory, and stay inside it unless
    /// [`TraverseOptions::allow_outside_inlines`]).
    pub fn from_reader(file: Arc<SctReader>, canonical_path: PathBuf, opts: TraverseOptions) -> Traversal {
        let root = file.graph().root;
        let chain = Arc::new(Chain { path: canonical_path.clone(), parent: None, depth: 0 });
        let mut files = HashMap::new();
        files.insert(canonical_path.clone(), file.clone());
        let pending = Pending { file, chain, node: root, path: "root".into(), state: TraversalState::IDENTITY, bound: None };
        let budget = VisitBudget::new(&opts.limits);
        Traversal {
            opts,
            stack: vec![Frame::One(pending)],
            deferred: None,
            files,
            cull: None,
            root: scene_root(&canonical_path),
            budget,
            groups: HashMap::new(),
            group_nodes: 0,
        }
    }

    /// Installs a predicate called with each pending node's world bound and path before it
    /// is expanded (group children, inline targets); returning false skips the subtree.
    pub fn set_cull(&mut self, cull: impl FnMut(&Node, &str) -> bool + Send + 'static) {
        self.cull = Some(Box::new(cull));
    }

    /// Do not visit the children of the group yielded last.
    pub fn skip_children(&mut self) {
        self.deferred = None;
    }

    /// Graph nodes visited so far (what [`Limits::max_traversal_visits`] caps).
    pub fn visits(&self) -> u64 {
        self.budget.used()
    }

    // Built once per failing group, never on a hot path: no need to box it.
    #[allow(clippy::result_large_err)]
    fn expand_group(&mut self, g: Pending) -> Result<(), TraverseError> {
        let Some(GraphNode::Group { tree, .. }) = g.file.graph().nodes.get(g.node as usize) else { return Ok(()) };
        let err = |kind| TraverseError { path: g.path.clone(), file: g.chain.path.clone(), graph_node: g.node, kind };
        let key = (Arc::as_ptr(&g.file) as usize, *tree);
        let leaves = match self.groups.get(&key) {
            Some(l) => l.clone(),
            None => {
                let t = g.file.read_tree(*tree as usize).map_err(|e| err(TraverseErrorKind::Read(e)))?;
                let l = Arc::new(GroupLeaves::new(t));
                let n = l.tree.len();
                if self.group_nodes.saturating_add(n) <= GROUP_CACHE_NODES {
                    self.group_nodes += n;
                    self.groups.insert(key, l.clone());
                }
                l
            }
        };
        self.stack.push(Frame::Children(Box::new(GroupFrame { leaves, group: g, next: 0 })));
        Ok(())
    }

    /// The next child of the group frame on top of the stack (the frame stays while it has
    /// more), or `None` when it is done.
    fn next_child(f: &mut GroupFrame) -> Option<Pending> {
        let GraphNode::Group { children, .. } = f.group.file.graph().nodes.get(f.group.node as usize)? else { return None };
        // A child without a leaf (a group tree with fewer leaves than children, which the
        // reader refuses) is skipped, as before.
        while f.next < children.len() {
            let j = f.next;
            f.next += 1;
            let (Some(leaf), Some(path)) = (f.leaves.leaf(j), f.leaves.path(j, &f.group.path)) else { continue };
            let g = &f.group;
            return Some(Pending {
                file: g.file.clone(),
                chain: g.chain.clone(),
                node: children[j],
                path,
                state: g.state,
                bound: Some(g.state.apply(leaf)),
            });
        }
        None
    }

    // The error is built once per failing inline, never on a hot path: no need to box it.
    #[allow(clippy::result_large_err)]
    fn follow_inline(&mut self, p: &Pending, rel: &str, hash: &[u8; 32]) -> Result<Pending, TraverseErrorKind> {
        let root = (!self.opts.allow_outside_inlines).then_some(self.root.as_path());
        let canon = resolve_inline(&p.chain.path, rel, root)?;
        // The cycle check comes before the hash check: a file that (transitively) inlines
        // itself can never record its own hash correctly, and the cycle is the real fault.
        if p.chain.contains(&canon) {
            let mut chain = p.chain.to_vec();
            chain.push(canon);
            return Err(TraverseErrorKind::InlineCycle { chain });
        }
        if p.chain.depth + 1 > self.opts.limits.max_inline_depth {
            return Err(TraverseErrorKind::InlineDepth { limit: self.opts.limits.max_inline_depth });
        }
        let file = match self.files.get(&canon) {
            Some(f) => f.clone(),
            None => {
                let f = SctReader::open(&canon, &self.opts.limits).map_err(|e| match e {
                    Error::Io { source, .. } => TraverseErrorKind::InlineMissing { target: canon.clone(), source },
                    e => TraverseErrorKind::Read(e),
                })?;
                let f = Arc::new(f);
                self.files.insert(canon.clone(), f.clone());
                f
            }
        };
        if self.opts.verify_inline_hashes {
            // Computed once per file (the reader keeps it), however many inlines name it.
            let found = file.content_hash().map_err(|e| match e {
                Error::Io { source, .. } => TraverseErrorKind::InlineMissing { target: canon.clone(), source },
                e => TraverseErrorKind::Read(e),
            })?;
            if &found != hash {
                return Err(TraverseErrorKind::InlineHash { target: canon, expected: hex(hash), found: hex(&found) });
            }
        }
        let root = file.graph().root;
        let depth = p.chain.depth + 1;
        Ok(Pending {
            file,
            chain: Arc::new(Chain { path: canon, parent: Some(p.chain.clone()), depth }),
            node: root,
            path: p.path.clone(),
            state: p.state,
            bound: None,
        })
    }

    /// Ends the traversal with the visit-limit error at `p`.
    fn stop(&mut self, p: &Pending, e: Error) -> Option<Result<Reached, TraverseError>> {
        self.stack.clear();
        self.deferred = None;
        Some(Err(TraverseError { path: p.path.clone(), file: p.chain.path.clone(), graph_node: p.node, kind: TraverseErrorKind::Read(e) }))
    }
}

/// Lowercase hex of a hash.
pub fn hex(h: &[u8]) -> String {
    h.iter().map(|b| format!("{b:02x}")).collect()
}

impl Iterator for Traversal {
    type Item = Result<Reached, TraverseError>;

    fn next(&mut self) -> Option<Self::Item> {
        if let Some(g) = self.deferred.take() {
            if let Err(e) = self.expand_group(g) {
                return Some(Err(e));
            }
        }
        loop {
            let p = match self.stack.last_mut()? {
                Frame::Children(f) => match Self::next_child(f) {
                    Some(p) => p,
                    None => {
                        self.stack.pop();
                        continue;
                    }
                },
                Frame::One(_) => match self.stack.pop() {
                    Some(Frame::One(p)) => p,
                    _ => continue,
                },
            };
            if let Err(e) = self.budget.charge(1) {
                return self.stop(&p, e);
            }
            if let (Some(b), Some(cull)) = (&p.bound, self.cull.as_mut()) {
                if !cull(b, &p.path) {
                    continue;
                }
            }
            let Some(node) = p.file.graph().nodes.get(p.node as usize) else {
                let kind = TraverseErrorKind::Read(Error::malformed(0, format!("graph node {} does not exist", p.node)));
                return Some(Err(TraverseError { path: p.path, file: p.chain.path.clone(), graph_node: p.node, kind }));
            };
            match node {
                GraphNode::Tree { tree } => return Some(Ok(p.reached(*tree, ReachedKind::Tree))),
                GraphNode::Group { children, tree } => {
                    let r = p.reached(*tree, ReachedKind::Group { children: children.clone() });
                    self.deferred = Some(p);
                    return Some(Ok(r));
                }
                GraphNode::Instance { .. } | GraphNode::Affine { .. } => {
                    let Some((child, transform, attrs)) = node.instance() else { continue };
                    let state = p.state.push(&transform, &attrs);
                    self.stack.push(Frame::One(Pending { node: child, state, bound: None, ..p }));
                }
                GraphNode::Inline { path, hash, bound } => {
                    let world = p.state.apply(bound);
                    if let (None, Some(cull)) = (&p.bound, self.cull.as_mut()) {
                        if !cull(&world, &p.path) {
                            continue;
                        }
                    }
                    let (path, hash) = (path.clone(), *hash);
                    match self.follow_inline(&p, &path, &hash) {
                        Ok(next) => self.stack.push(Frame::One(next)),
                        Err(kind) => {
                            return Some(Err(TraverseError { path: p.path, file: p.chain.path.clone(), graph_node: p.node, kind }))
                        }
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::parent_of;
    use crate::graph::{Generator, SceneGraph};
    use crate::write::{write_scene_file, Scene, WriteOptions};
    use crate::{Profile, SceneTree};

    fn leaf(x: f32, c: u8) -> Node {
        Node { center: [x, 0.0, 0.0], radius: 0.5, normal: [0.0, 0.0, 1.0], cone: 0.0, area: 1.0, color: [c, c, c, 255] }
    }

    /// A 3-leaf tree: root -> (p, c), p -> (a, b).
    fn tree3(x: f32) -> SceneTree {
        let (a, b, c) = (leaf(x, 10), leaf(x + 1.0, 20), leaf(x + 3.0, 30));
        let p = parent_of(&a, &b);
        let r = parent_of(&p, &c);
        SceneTree::from_bfs(vec![r, p, c, a, b], vec![true, true, false, false, false]).unwrap()
    }

    fn write(path: &Path, graph: SceneGraph, trees: Vec<SceneTree>) {
        let scene = Scene { generator: Generator::default(), graph, trees };
        write_scene_file(path, &scene, &WriteOptions { profile: Profile::Raw, ..Default::default() }).unwrap();
    }

    fn hash_of(p: &Path) -> [u8; 32] {
        *blake3::hash(&std::fs::read(p).unwrap()).as_bytes()
    }

    #[test]
    fn composes_state() {
        let t = Similarity { translation: [1.0, 0.0, 0.0], rotation: [0.0, 0.0, 0.0, 1.0], scale: 2.0 };
        let attrs = InstanceAttrs { size: Propagation::PullUp, color: Propagation::PushDown, tint: Some([255, 0, 128, 255]) };
        let s = TraversalState::IDENTITY.push_instance(&t, &attrs).push_instance(&t, &attrs);
        let n = s.apply(&leaf(1.0, 200));
        assert_eq!(n.center, [7.0, 0.0, 0.0]);
        assert_eq!(n.radius, 2.0);
        assert_eq!(n.area, 16.0);
        assert_eq!(n.color, [200, 0, 50, 255]);
        // Pull-up colour ignores the tint.
        let pull = InstanceAttrs { tint: Some([0; 4]), ..Default::default() };
        assert!(!TraversalState::IDENTITY.push_instance(&t, &pull).is_tinted());
    }

    /// Group children are named one at a time; the names are those of `leaf_paths`, for
    /// unbalanced trees too, and the leaves are the tree's leaves in breadth-first order.
    #[test]
    fn group_leaves_name_children_as_leaf_paths() {
        // root -> (p, c), p -> (q, d), q -> (a, b): leaves c, d, a, b.
        let n = leaf(0.0, 1);
        let t = SceneTree::from_bfs(vec![n; 7], vec![true, true, false, true, false, false, false]).expect("tree");
        let g = GroupLeaves::new(t.clone());
        let want = leaf_paths(&t, "root/1");
        assert_eq!(want, ["root/1/1", "root/1/0/1", "root/1/0/0/0", "root/1/0/0/1"]);
        let got: Vec<String> = (0..g.len()).map(|j| g.path(j, "root/1").expect("leaf")).collect();
        assert_eq!(got, want);
        assert_eq!(g.path(4, "root"), None);
        assert_eq!((0..4).map(|j| g.leaf_index(j).expect("leaf")).collect::<Vec<_>>(), t.leaves().collect::<Vec<_>>());
        assert!(GroupLeaves::new(SceneTree::default()).is_empty());
    }

    /// Visits are charged one by one and the limit names its quantity.
    #[test]
    fn visit_budget_stops_at_the_limit() {
        let mut b = VisitBudget::new(&Limits { max_traversal_visits: 3, ..Limits::default() });
        assert!(b.charge(2).is_ok() && b.charge(1).is_ok());
        assert!(matches!(b.charge(1), Err(Error::LimitExceeded { what: VISITS, value: 4, limit: 3 })));
        assert_eq!(b.used(), 4);
    }

    #[test]
    fn walks_group_instances_and_inline() {
        let dir = tempfile::tempdir().unwrap();
        let sub = dir.path().join("sub");
        std::fs::create_dir(&sub).unwrap();
        let inner = sub.join("inner.sct");
        write(&inner, SceneGraph { nodes: vec![GraphNode::Tree { tree: 0 }], root: 0 }, vec![tree3(0.0)]);
        let bound = tree3(0.0).nodes()[0];
        let t = Similarity { translation: [10.0, 0.0, 0.0], rotation: [0.0, 0.0, 0.0, 1.0], scale: 1.0 };
        // Group tree over 3 children; leaf j bounds child j: the plain tree, the instance, the inline.
        let b = [bound, t.apply_node(&bound), bound];
        let p = parent_of(&b[1], &b[2]);
        let r = parent_of(&p, &b[0]);
        let gtree = SceneTree::from_bfs(vec![r, p, b[0], b[1], b[2]], vec![true, true, false, false, false]).unwrap();
        let nodes = vec![
            GraphNode::Tree { tree: 0 },
            GraphNode::Instance { child: 0, transform: t, attrs: InstanceAttrs::default() },
            GraphNode::Inline { path: "sub/inner.sct".into(), hash: hash_of(&inner), bound },
            GraphNode::Group { children: vec![0, 1, 2], tree: 1 },
        ];
        let top = dir.path().join("top.sct");
        write(&top, SceneGraph { nodes, root: 3 }, vec![tree3(0.0), gtree]);
        let items: Vec<Reached> = Traversal::open(&top, TraverseOptions::default()).unwrap().map(|r| r.unwrap()).collect();
        let summary: Vec<(String, usize, u32)> = items.iter().map(|r| (r.path.clone(), r.tree, r.inline_depth)).collect();
        // Leaves in BFS order: node 2 (path root/1), then nodes 3, 4 (root/0/0, root/0/1).
        assert_eq!(
            summary,
            vec![("root".into(), 1, 0), ("root/1".into(), 0, 0), ("root/0/0".into(), 0, 0), ("root/0/1".into(), 0, 1)]
        );
        assert!(matches!(items[0].kind, ReachedKind::Group { .. }));
        assert_eq!(items[2].state.transform, t);
        assert_eq!(items[2].world_root().unwrap().center, t.apply_node(&bound).center);

        // Culling by path skips the inline before it is opened.
        let mut tr = Traversal::open(&top, TraverseOptions::default()).unwrap();
        tr.set_cull(|_, p| p != "root/0/1");
        assert_eq!(tr.count(), 3);
        // skip_children leaves only the group.
        let mut tr = Traversal::open(&top, TraverseOptions::default()).unwrap();
        assert!(tr.next().unwrap().is_ok());
        tr.skip_children();
        assert!(tr.next().is_none());
        assert_eq!(graph_bound(&SctReader::open(&top, &Limits::default()).unwrap(), 1).unwrap().center, t.apply_node(&bound).center);
    }

    #[test]
    fn inline_errors() {
        let dir = tempfile::tempdir().unwrap();
        let bound = tree3(0.0).nodes()[0];
        // Self-inline: a cycle, reported before (impossible) hash agreement.
        let a = dir.path().join("a.sct");
        write(&a, SceneGraph { nodes: vec![GraphNode::Inline { path: "a.sct".into(), hash: [0; 32], bound }], root: 0 }, vec![]);
        let e: Vec<_> = Traversal::open(&a, TraverseOptions::default()).unwrap().collect();
        assert!(matches!(&e[..], [Err(TraverseError { kind: TraverseErrorKind::InlineCycle { .. }, .. })]), "{e:?}");
        // Missing target and wrong hash.
        let inner = dir.path().join("inner.sct");
        write(&inner, SceneGraph { nodes: vec![GraphNode::Tree { tree: 0 }], root: 0 }, vec![tree3(0.0)]);
        let nodes = vec![
            GraphNode::Inline { path: "nope.sct".into(), hash: [0; 32], bound },
            GraphNode::Inline { path: "inner.sct".into(), hash: [1; 32], bound },
            GraphNode::Group { children: vec![0, 1], tree: 0 },
        ];
        let gt = SceneTree::from_bfs(vec![parent_of(&bound, &bound), bound, bound], vec![true, false, false]).unwrap();
        let b = dir.path().join("b.sct");
        write(&b, SceneGraph { nodes, root: 2 }, vec![gt]);
        let e: Vec<_> = Traversal::open(&b, TraverseOptions::default()).unwrap().collect();
        assert_eq!(e.len(), 3);
        assert!(matches!(&e[1], Err(TraverseError { kind: TraverseErrorKind::InlineMissing { .. }, .. })));
        assert!(matches!(&e[2], Err(TraverseError { kind: TraverseErrorKind::InlineHash { .. }, .. })));
        // Depth limit.
        let mut opts = TraverseOptions::default();
        opts.limits.max_inline_depth = 0;
        opts.verify_inline_hashes = false;
        let e: Vec<_> = Traversal::open(&b, opts).unwrap().collect();
        assert!(matches!(&e[2], Err(TraverseError { kind: TraverseErrorKind::InlineDepth { .. }, .. })));
    }
}
