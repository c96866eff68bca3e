//! In-memory scene tree in breadth-first order (the order it is stored in).
//!
//! The tree is a full binary tree: every internal node has exactly two children. Stored
//! breadth first, the children of the `k`-th internal node of a level are nodes `2k` and
//! `2k + 1` of the next level, so no child pointers are needed: one "has children" bit per
//! node is the whole topology (spec §6).

use crate::error::{Error, Result};
use crate::node::Node;

/// A decoded scene tree, possibly truncated to its first levels.
#[derive(Clone, Debug, PartialEq)]
pub struct SceneTree {
    nodes: Vec<Node>,
    internal: Vec<bool>,
    /// `level_starts[d]` is the index of the first node of level `d`; one extra entry at the end.
    level_starts: Vec<usize>,
    /// Index of the first child of each node, `u32::MAX` for leaves and for nodes whose
    /// children are not loaded.
    first_child: Vec<u32>,
}

impl Default for SceneTree {
    /// The empty tree (same as `from_bfs(vec![], vec![])`).
    fn default() -> Self {
        SceneTree { nodes: Vec::new(), internal: Vec::new(), level_starts: vec![0], first_child: Vec::new() }
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
        let mut first_child = vec![NO_CHILD; nodes.len()];
        if nodes.is_empty() {
            return Ok(SceneTree { nodes, internal, level_starts, first_child });
        }
        let (mut start, mut end) = (0usize, 1usize);
        loop {
            level_starts.push(end);
            let parents = internal[start..end].iter().filter(|&&b| b).count();
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
            let mut child = end;
            for i in start..end {
                if internal[i] {
                    first_child[i] = child as u32;
                    child += 2;
                }
            }
            start = end;
            end = next_end;
        }
        Ok(SceneTree { nodes, internal, level_starts, first_child })
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
        match self.first_child.get(i) {
            Some(&c) if c != NO_CHILD => Some([c as usize, c as usize + 1]),
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
        self.internal.iter().filter(|&&b| !b).count()
    }

    /// Parent of every node (`NO_CHILD` for the root), computed in one pass.
    pub fn parents(&self) -> Vec<u32> {
        let mut p = vec![NO_CHILD; self.nodes.len()];
        for (i, &c) in self.first_child.iter().enumerate() {
            if c != NO_CHILD {
                p[c as usize] = i as u32;
                p[c as usize + 1] = i as u32;
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
