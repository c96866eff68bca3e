//! Scene nodes one at a time, for renderers that refine node by node (the `canopy` image
//! graph): an [`Item`] is one scene-tree node under one instance state, or an inline not yet
//! opened; its children are the tree node's two children, a group leaf's child graph node, or
//! the inlined file's root, with the same rules as [`SceneFiles::collect`] (instance state
//! composition, inline checks).

use std::collections::VecDeque;
use std::rc::Rc;

use sct_format::traverse::{TraversalState, VisitBudget};
use sct_format::{GraphNode, Node, Transform};

use super::{placement, Chain, SceneFiles};
use crate::camera::View;
use crate::error::{Error, Result};
use crate::lod::{self, Decision, LodParams, LodStats, Placement, TreeOut};
use crate::raster::Splat;

/// One scene node under one instance state.
#[derive(Clone)]
pub(crate) struct Item {
    chain: Rc<Chain>,
    /// World placement and tint.
    pub state: TraversalState,
    kind: Kind,
}

#[derive(Clone, Copy)]
enum Kind {
    /// Node `i` of level `d` of a tree; `graph_node` is the Tree or Group graph node.
    Tree { tree: u32, group: bool, graph_node: u32, d: u32, i: u64 },
    /// An inline graph node, drawn by its stored bound until opened.
    Inline { graph_node: u32 },
}

impl Item {
    /// Identifies the item across frames: file, tree, level, node, and the bits of its
    /// instance state's translation, scale and rotation, or matrix (one tree drawn under two
    /// instances is two items).
    pub(crate) fn key(&self) -> [u64; 5] {
        // Each word is folded in through a full-avalanche mix (one SplitMix64 step): a
        // multiply alone carries a bit only upwards, so the sign bits of two coordinates
        // cancelled and the instances at (x, z) and (−x, −z) of a centred grid shared a key.
        let mut h = 0xcbf2_9ce4_8422_2325u64;
        let mut mix = |v: f64| h = sct_format::rng::SplitMix64(h ^ v.to_bits()).next_u64();
        match &self.state.transform {
            Transform::Similarity(t) => t.translation.iter().chain(t.rotation.iter()).chain(std::iter::once(&t.scale)).for_each(|v| mix(*v)),
            Transform::Affine(a) => a.affine.matrix.iter().flatten().for_each(|v| mix(*v)),
        }
        match self.kind {
            Kind::Tree { tree, d, i, .. } => [self.chain.file as u64, u64::from(tree), u64::from(d), i, h],
            Kind::Inline { graph_node } => [self.chain.file as u64, u64::MAX, u64::from(graph_node), 0, h],
        }
    }

    /// Whether the item is a node of a plain tree (not a group tree, not an inline).
    pub(crate) fn is_plain_tree(&self) -> bool {
        matches!(self.kind, Kind::Tree { group: false, .. })
    }

    /// Whether both items are nodes of one tree under one instance state (siblings that the
    /// tree's own split separates).
    pub(crate) fn same_tree(&self, o: &Item) -> bool {
        match (self.kind, o.kind) {
            (Kind::Tree { tree: a, .. }, Kind::Tree { tree: b, .. }) => a == b && self.chain.file == o.chain.file && self.state.transform == o.state.transform,
            _ => false,
        }
    }
}

/// Where a tree item sits (see [`SceneFiles::item_spot`]).
#[derive(Clone, Copy, Debug)]
pub(crate) struct TreeSpot {
    pub file: usize,
    pub tree: usize,
    pub group: bool,
    pub d: usize,
    pub i: u64,
}

/// What a renderer needs to know about an item.
#[derive(Clone, Copy, Debug)]
pub(crate) struct ItemNode {
    /// The node in its tree's frame (an inline's stored bound).
    pub node: Node,
    /// Whether it has children (internal nodes, group leaves and inlines do).
    pub refinable: bool,
    /// Never cull by the normal cone (two-sided trees, inlines' bounds).
    pub two_sided: bool,
}

impl SceneFiles {
    /// The items of the main file's root graph node.
    pub(crate) fn root_items(&mut self) -> Result<Vec<Item>> {
        if self.files.is_empty() {
            return Ok(Vec::new());
        }
        let root = self.files[0].reader.graph().root;
        let chain = Rc::new(Chain { file: 0, parent: None, depth: 0 });
        self.expand(chain, root, TraversalState::IDENTITY)
    }

    /// The items a graph node stands for: instances composed down to their tree or inline.
    fn expand(&mut self, chain: Rc<Chain>, mut node: u32, mut state: TraversalState) -> Result<Vec<Item>> {
        let fi = chain.file;
        for _ in 0..=1024 {
            let f = &self.files[fi];
            let g = f.reader.graph().nodes.get(node as usize).cloned().ok_or_else(|| Error::Invalid(format!("{}: graph node {node} does not exist", f.path.display())))?;
            match g {
                GraphNode::Instance { .. } | GraphNode::Affine { .. } => {
                    let Some((child, transform, attrs)) = g.instance() else { break };
                    state = state.push(&transform, &attrs);
                    node = child;
                }
                GraphNode::Tree { tree } | GraphNode::Group { tree, .. } => {
                    let group = matches!(g, GraphNode::Group { .. });
                    let has_root = f.trees.get(tree as usize).ok_or_else(|| Error::Invalid(format!("{}: graph refers to missing tree {tree}", f.path.display())))?.root().is_some();
                    return Ok(if has_root { vec![Item { chain, state, kind: Kind::Tree { tree, group, graph_node: node, d: 0, i: 0 } }] } else { Vec::new() });
                }
                GraphNode::Inline { .. } => return Ok(vec![Item { chain, state, kind: Kind::Inline { graph_node: node } }]),
            }
        }
        Err(Error::Invalid(format!("{}: instances nested more than 1024 deep", self.files[fi].path.display())))
    }

    /// The item's node.
    pub(crate) fn item_node(&self, it: &Item) -> Result<ItemNode> {
        let f = &self.files[it.chain.file];
        match it.kind {
            Kind::Tree { tree, group, d, i, .. } => {
                let cache = &f.trees[tree as usize];
                let at = cache.node_at(&f.reader, d as usize, i)?;
                Ok(ItemNode { node: at.node, refinable: at.internal || group, two_sided: cache.two_sided(&f.reader) })
            }
            Kind::Inline { graph_node } => match f.reader.graph().nodes.get(graph_node as usize) {
                Some(GraphNode::Inline { bound, .. }) => Ok(ItemNode { node: *bound, refinable: true, two_sided: true }),
                _ => Err(Error::Invalid(format!("{}: graph node {graph_node} is not an inline", f.path.display()))),
            },
        }
    }

    /// The nodes `levels` levels below a plain tree's item (and the leaves above that depth),
    /// left to right, appended to `out`; nothing for other items. Walks level ranges: the
    /// children of consecutive internal nodes are consecutive in the next level.
    pub(crate) fn descendants(&self, it: &Item, levels: u32, out: &mut Vec<Node>) -> Result<()> {
        let Kind::Tree { tree, group: false, d, i, .. } = it.kind else { return Ok(()) };
        let f = &self.files[it.chain.file];
        let cache = &f.trees[tree as usize];
        let (mut lo, mut hi, mut level) = (i, i + 1, d as usize);
        for step in 0..=levels {
            let mut next: Option<(u64, u64)> = None;
            for j in lo..hi {
                let at = cache.node_at(&f.reader, level, j)?;
                if at.internal && step < levels {
                    let first = next.map_or(at.first_child, |(l, _)| l);
                    next = Some((first, at.first_child + 2));
                } else {
                    out.push(at.node);
                }
            }
            match next {
                Some((l, h)) => (lo, hi, level) = (l, h, level + 1),
                None => break,
            }
        }
        Ok(())
    }

    /// The item's children (empty for a tree leaf outside a group tree).
    pub(crate) fn item_children(&mut self, it: &Item) -> Result<Vec<Item>> {
        let fi = it.chain.file;
        match it.kind {
            Kind::Tree { tree, group, graph_node, d, i } => {
                let f = &self.files[fi];
                let at = f.trees[tree as usize].node_at(&f.reader, d as usize, i)?;
                if at.internal {
                    let child = |i| Item { chain: it.chain.clone(), state: it.state, kind: Kind::Tree { tree, group, graph_node, d: d + 1, i } };
                    return Ok(vec![child(at.first_child), child(at.first_child + 1)]);
                }
                if !group {
                    return Ok(Vec::new());
                }
                let child = match f.reader.graph().nodes.get(graph_node as usize) {
                    Some(GraphNode::Group { children, .. }) => children.get(at.leaf_no as usize).copied(),
                    _ => None,
                }
                .ok_or_else(|| Error::Invalid(format!("{}: group leaf {} has no child", f.path.display(), at.leaf_no)))?;
                self.expand(it.chain.clone(), child, it.state)
            }
            Kind::Inline { graph_node } => {
                let Some(GraphNode::Inline { path, hash, .. }) = self.files[fi].reader.graph().nodes.get(graph_node as usize).cloned() else {
                    return Err(Error::Invalid(format!("{}: graph node {graph_node} is not an inline", self.files[fi].path.display())));
                };
                let k = self
                    .follow_inline(&it.chain, &path, &hash)
                    .map_err(|kind| Error::Inline { file: self.files[fi].path.clone(), graph_node, kind: Box::new(kind) })?;
                let root = self.files[k].reader.graph().root;
                let chain = Rc::new(Chain { file: k, depth: it.chain.depth + 1, parent: Some(it.chain.clone()) });
                self.expand(chain, root, it.state)
            }
        }
    }

    /// Where a tree item sits: its file, tree, whether the tree is a group tree, and its
    /// level and index (`None` for an inline). Lets a renderer walk the tree below the item
    /// with [`SceneFiles::tree`], off the item queue and in parallel.
    pub(crate) fn item_spot(&self, it: &Item) -> Option<TreeSpot> {
        match it.kind {
            Kind::Tree { tree, group, d, i, .. } => Some(TreeSpot { file: it.chain.file, tree: tree as usize, group, d: d as usize, i }),
            Kind::Inline { .. } => None,
        }
    }

    /// The reader and block cache of tree `tree` of open file `file`.
    pub(crate) fn tree(&self, file: usize, tree: usize) -> Option<(&sct_format::SctReader, &lod::TreeCache)> {
        let f = self.files.get(file)?;
        Some((&f.reader, f.trees.get(tree)?))
    }

    /// Camera-space placement of an item.
    pub(crate) fn item_placement(&self, view: &View, it: &Item) -> Placement {
        placement(view, &it.state)
    }

    /// Refines `it` depth by depth with the LOD test of `p` (as [`SceneFiles::collect`] does
    /// from the root), appending its splats in a repeatable order.
    pub(crate) fn refine_item(&mut self, it: &Item, view: &View, p: &LodParams, splats: &mut Vec<Splat>, stats: &mut LodStats) -> Result<()> {
        let mut queue = VecDeque::from([it.clone()]);
        let mut budget = VisitBudget::new(&self.limits);
        while let Some(it) = queue.pop_front() {
            let fi = it.chain.file;
            budget.charge(1).map_err(|e| Error::sct(&self.files[fi].path, e))?;
            let pl = placement(view, &it.state);
            match it.kind {
                Kind::Tree { tree, group, graph_node, d, i } => {
                    let f = &self.files[fi];
                    let mut out = TreeOut::default();
                    lod::traverse_from(&f.reader, &f.trees[tree as usize], &pl, view, p, group, (d as usize, i), stats.nodes_visited, &mut out)?;
                    splats.append(&mut out.splats);
                    stats.add(&out.stats);
                    if let Some(GraphNode::Group { children, .. }) = f.reader.graph().nodes.get(graph_node as usize).cloned() {
                        for j in out.group_leaves {
                            let c = children.get(j as usize).copied().ok_or_else(|| Error::Invalid(format!("{}: group leaf {j} has no child", self.files[fi].path.display())))?;
                            queue.extend(self.expand(it.chain.clone(), c, it.state)?);
                        }
                    }
                }
                Kind::Inline { .. } => {
                    let n = self.item_node(&it)?;
                    let by_bound = LodParams { backface: false, ..*p };
                    match lod::decide(&n.node, true, true, &pl, view, &by_bound, stats) {
                        // `Leaf` comes only from leaf collection, which walks the graph in
                        // `SceneFiles::walk`.
                        Decision::Cull | Decision::Refine | Decision::Leaf(_) => {}
                        Decision::Draw(s) => splats.push(s),
                        Decision::Descend => queue.extend(self.item_children(&it)?),
                    }
                }
            }
        }
        Ok(())
    }
}
