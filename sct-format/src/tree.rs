//! In-memory scene tree in breadth-first order (the order it is stored in).
//!
//! The tree is a full binary tree: every internal node has exactly two children. Stored
//! breadth first, the children of the `k`-th internal node of a level are nodes `2k` and
//! `2k + 1` of the next level, so no child pointers are needed: one "has children" bit per
//! node is the whole topology (spec §6).

use rayon::prelude::*;

use crate::error::{Error, Result};
use crate::node::Node;

/// A decoded scene tree, possibly truncated to its first levels.
#[derive(Clone, Debug, PartialEq)]
pub struct SceneTree {
    nodes: Vec<Node>,
    internal: Vec<bool>,
    /// `level_starts[d]` is the index of the first node of level `d`; one extra entry at the end.
    level_starts: Vec<usize>,
    /// Rank directory of `internal`: bit `i % 64` of word `i / 64` is `internal[i]`, and
    /// `rank[i / 64]` counts the internal nodes before word `i / 64`. The `k`-th internal node
    /// (breadth first, from 0) has its children at `2k + 1` and `2k + 2`, so this is all the
    /// child addressing needs: 0.19 bytes per node instead of a 4-byte index.
    bits: Vec<u64>,
    rank: Vec<u32>,
    /// Surfaces seen from both sides (spec §6.2, tree flag bit 1).
    two_sided: bool,
}

impl Default for SceneTree {
    /// The empty tree (same as `from_bfs(vec![], vec![])`).
    fn default() -> Self {
        SceneTree { nodes: Vec::new(), internal: Vec::new(), level_starts: vec![0], bits: Vec::new(), rank: Vec::new(), two_sided: false }
    }
}

/// Sentinel for "no child".
pub const NO_CHILD: u32 = u32::MAX;

impl SceneTree {
    /// Builds a tree from nodes in breadth-first order and their "has children" flags.
    ///
    /// When the last stored level still has internal nodes the tree is *truncated* (a
    /// prefix of the levels, as a progressive reader produces); those nodes report no
    /// children.
    pub fn from_bfs(nodes: Vec<Node>, internal: Vec<bool>) -> Result<Self> {
        if nodes.len() != internal.len() {
            return Err(Error::Misuse(format!(
                "{} nodes but {} internal flags",
                nodes.len(),
                internal.len()
            )));
        }
        if nodes.len() >= NO_CHILD as usize {
            return Err(Error::Misuse("too many nodes for one tree (max 2^32 - 2)".into()));
        }
        let mut level_starts = vec![0usize];
        if nodes.is_empty() {
            return Ok(SceneTree { nodes, internal, level_starts, bits: Vec::new(), rank: Vec::new(), two_sided: false });
        }
        // The rank directory first (in parallel: a few passes over every flag otherwise),
        // so each level's internal nodes are counted in constant time.
        let bits: Vec<u64> = internal
            .par_chunks(64)
            .map(|w| w.iter().enumerate().fold(0u64, |b, (k, &f)| b | (f as u64) << k))
            .collect();
        let rank: Vec<u32> = bits
            .iter()
            .scan(0u32, |acc, &w| {
                let before = *acc;
                *acc += w.count_ones();
                Some(before)
            })
            .collect();
        let before = |i: usize| match bits.get(i / 64) {
            Some(&w) => rank[i / 64] as usize + (w & ((1u64 << (i % 64)) - 1)).count_ones() as usize,
            None => rank.last().map_or(0, |&r| r as usize) + bits.last().map_or(0, |w| w.count_ones() as usize),
        };
        let (mut start, mut end) = (0usize, 1usize);
        loop {
            level_starts.push(end);
            let parents = before(end) - before(start);
            let next_end = end + 2 * parents;
            if parents == 0 || end == nodes.len() {
                if end != nodes.len() {
                    return Err(Error::Misuse(format!(
                        "{} nodes after the last level (node count does not match the flags)",
                        nodes.len() - end
                    )));
                }
                break;
            }
            if next_end > nodes.len() {
                return Err(Error::Misuse(format!(
                    "level starting at node {end} needs {} nodes, only {} given",
                    2 * parents,
                    nodes.len() - end
                )));
            }
            start = end;
            end = next_end;
        }
        Ok(SceneTree { nodes, internal, level_starts, bits, rank, two_sided: false })
    }

    /// Breadth-first index of the first child node `i` has in the full tree (whether loaded
    /// or not), if it is internal.
    #[inline]
    fn first_child(&self, i: usize) -> Option<usize> {
        let (w, b) = (i / 64, i % 64);
        let word = *self.bits.get(w)?;
        if word >> b & 1 == 0 {
            return None;
        }
        let k = self.rank[w] as usize + (word & ((1u64 << b) - 1)).count_ones() as usize;
        Some(2 * k + 1)
    }

    /// Whether the tree's surfaces are seen from both sides (spec §6.2, tree flag bit 1): its
    /// cones bound the normals up to sign, so a renderer does not cull its nodes as
    /// back-facing and lights each from the side facing the eye.
    pub fn is_two_sided(&self) -> bool {
        self.two_sided
    }

    /// Marks the tree two-sided (or not); a group tree over a two-sided child is marked too
    /// (spec §6.2), so no group node above it is culled by its cone.
    pub fn set_two_sided(&mut self, two_sided: bool) {
        self.two_sided = two_sided;
    }

    /// All nodes, breadth first.
    pub fn nodes(&self) -> &[Node] {
        &self.nodes
    }

    /// Mutable access to node attributes (topology stays fixed).
    pub fn nodes_mut(&mut self) -> &mut [Node] {
        &mut self.nodes
    }

    /// The nodes and "has children" flags, breadth first (what [`SceneTree::from_bfs`] takes).
    pub fn into_parts(self) -> (Vec<Node>, Vec<bool>) {
        (self.nodes, self.internal)
    }

    /// "Has children" flag of every node.
    pub fn internal_flags(&self) -> &[bool] {
        &self.internal
    }

    /// Number of nodes.
    pub fn len(&self) -> usize {
        self.nodes.len()
    }

    /// True for a tree without nodes.
    pub fn is_empty(&self) -> bool {
        self.nodes.is_empty()
    }

    /// Number of stored levels.
    pub fn level_count(&self) -> usize {
        self.level_starts.len() - 1
    }

    /// Node index range of level `d`.
    pub fn level(&self, d: usize) -> std::ops::Range<usize> {
        self.level_starts[d]..self.level_starts[d + 1]
    }

    /// The two children of node `i`, if it has children and they are loaded.
    pub fn children(&self, i: usize) -> Option<[usize; 2]> {
        match self.first_child(i) {
            Some(c) if c + 1 < self.nodes.len() => Some([c, c + 1]),
            _ => None,
        }
    }

    /// True when node `i` has children in the full tree (loaded or not).
    pub fn is_internal(&self, i: usize) -> bool {
        self.internal[i]
    }

    /// Number of nodes without children (counting only loaded levels; a truncated tree's
    /// bottom internal nodes are not leaves).
    pub fn leaf_count(&self) -> usize {
        // From the rank directory: the internal nodes before the last word, plus its own.
        let internal = self.rank.last().map_or(0, |&r| r as usize) + self.bits.last().map_or(0, |w| w.count_ones() as usize);
        self.nodes.len() - internal
    }

    /// Parent of every node (`NO_CHILD` for the root), computed in one pass.
    pub fn parents(&self) -> Vec<u32> {
        let mut p = vec![NO_CHILD; self.nodes.len()];
        let mut c = 1usize;
        for (i, &f) in self.internal.iter().enumerate() {
            if f {
                if c + 1 >= p.len() {
                    break;
                }
                p[c] = i as u32;
                p[c + 1] = i as u32;
                c += 2;
            }
        }
        p
    }

    /// Indices of the leaves in breadth-first order.
    pub fn leaves(&self) -> impl Iterator<Item = usize> + '_ {
        self.internal.iter().enumerate().filter(|(_, &b)| !b).map(|(i, _)| i)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn n() -> Node {
        Node::default()
    }

    #[test]
    fn default_is_the_empty_tree() {
        // Regression: the derived Default left level_starts empty and level_count() underflowed.
        assert_eq!(SceneTree::default().level_count(), 0);
        assert_eq!(SceneTree::default(), SceneTree::from_bfs(vec![], vec![]).unwrap());
    }

    #[test]
    fn three_levels() {
        // root -> (a, b); a -> (c, d)
        let t = SceneTree::from_bfs(vec![n(); 5], vec![true, true, false, false, false]).unwrap();
        assert_eq!(t.level_count(), 3);
        assert_eq!(t.children(0), Some([1, 2]));
        assert_eq!(t.children(1), Some([3, 4]));
        assert_eq!(t.children(2), None);
        assert_eq!(t.parents(), vec![NO_CHILD, 0, 0, 1, 1]);
        assert_eq!(t.leaves().collect::<Vec<_>>(), vec![2, 3, 4]);
    }

    /// Children by rank must match the level-by-level assignment, across rank-word
    /// boundaries (trees of more than 64 nodes) and in truncated trees.
    #[test]
    fn children_by_rank_match_level_walk() {
        // A lopsided tree: at each level every fifth node is a leaf.
        let mut internal = vec![true];
        let (mut width, mut levels) = (1usize, 0);
        while levels < 9 {
            let parents = internal[internal.len() - width..].iter().filter(|&&b| b).count();
            width = 2 * parents;
            internal.extend((0..width).map(|i| levels < 8 && i % 5 != 4));
            levels += 1;
        }
        let t = SceneTree::from_bfs(vec![n(); internal.len()], internal.clone()).unwrap();
        assert!(t.len() > 200, "{}", t.len());
        // Expected first children, assigned level by level.
        let mut expect = vec![None; t.len()];
        for d in 0..t.level_count() - 1 {
            let mut c = t.level(d + 1).start;
            for i in t.level(d) {
                if internal[i] {
                    expect[i] = Some([c, c + 1]);
                    c += 2;
                }
            }
        }
        let got: Vec<_> = (0..t.len()).map(|i| t.children(i)).collect();
        assert_eq!(got, expect);
        let parents = t.parents();
        for (i, c) in expect.iter().enumerate() {
            if let Some([a, b]) = c {
                assert_eq!((parents[*a], parents[*b]), (i as u32, i as u32));
            }
        }
        // Truncated to its first levels: the bottom level's internal nodes have no children.
        let cut = t.level(5).end;
        let tt = SceneTree::from_bfs(vec![n(); cut], internal[..cut].to_vec()).unwrap();
        for (i, &e) in expect[..cut].iter().enumerate() {
            let want = if i < t.level(4).end { e } else { None };
            assert_eq!(tt.children(i), want, "node {i}");
        }
        assert!(tt.parents()[t.level(4).start..cut].iter().all(|&p| p != NO_CHILD));
        // The rank directory's leaf count: full and truncated (its bottom internal nodes
        // are not leaves), and the empty tree.
        for (tree, flags) in [(&t, &internal[..]), (&tt, &internal[..cut])] {
            assert_eq!(tree.leaf_count(), flags.iter().filter(|&&b| !b).count());
        }
        assert_eq!(SceneTree::default().leaf_count(), 0);
        assert_eq!(t.children(t.len()), None);
    }

    #[test]
    fn truncated_prefix_is_accepted() {
        let t = SceneTree::from_bfs(vec![n(); 3], vec![true, true, true]).unwrap();
        assert_eq!(t.level_count(), 2);
        assert_eq!(t.children(1), None);
        assert!(t.is_internal(1));
    }

    #[test]
    fn inconsistent_counts_are_rejected() {
        assert!(SceneTree::from_bfs(vec![n(); 4], vec![true, false, false, false]).is_err());
        assert!(SceneTree::from_bfs(vec![n(); 2], vec![true, false]).is_err());
        assert!(SceneTree::from_bfs(vec![n(); 2], vec![true]).is_err());
    }
}
