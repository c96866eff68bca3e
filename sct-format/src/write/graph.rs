//! The scene-graph (`GRPH`) section: checking a scene's graph against its trees before
//! writing, and encoding the graph records (spec §7).

use crate::error::{Error, Result};
use crate::graph::{GraphNode, Propagation, SceneGraph};
use crate::raw::cursor::Put;
use crate::samples::put_similarity;
use crate::tree::SceneTree;

use super::Scene;

pub(super) fn check_graph(scene: &Scene) -> Result<()> {
    let g = &scene.graph;
    if g.nodes.is_empty() {
        return Err(Error::Misuse("the scene graph has no nodes".into()));
    }
    if g.root as usize >= g.nodes.len() {
        return Err(Error::Misuse(format!("root {} out of range ({} graph nodes)", g.root, g.nodes.len())));
    }
    let tree_ok = |t: u32| -> Result<&SceneTree> {
        scene.trees.get(t as usize).ok_or_else(|| Error::Misuse(format!("graph refers to tree {t}, there are {}", scene.trees.len())))
    };
    for (i, n) in g.nodes.iter().enumerate() {
        let earlier = |c: u32| -> Result<()> {
            if c as usize >= i {
                return Err(Error::Misuse(format!("graph node {i} refers to node {c}; references must point to earlier nodes")));
            }
            Ok(())
        };
        match n {
            GraphNode::Tree { tree } => {
                tree_ok(*tree)?;
            }
            GraphNode::Group { children, tree } => {
                let t = tree_ok(*tree)?;
                children.iter().try_for_each(|&c| earlier(c))?;
                if t.leaf_count() != children.len() {
                    return Err(Error::Misuse(format!(
                        "group {i} has {} children but its tree has {} leaves",
                        children.len(),
                        t.leaf_count()
                    )));
                }
            }
            GraphNode::Instance { child, transform, .. } => {
                earlier(*child)?;
                if !transform.is_valid(1e-6) {
                    return Err(Error::Misuse(format!("instance {i} has an invalid transform ({transform})")));
                }
            }
            GraphNode::Affine { child, transform, .. } => {
                earlier(*child)?;
                if let Some(why) = transform.problem() {
                    return Err(Error::Misuse(format!("affine instance {i}: {why}")));
                }
            }
            GraphNode::Inline { path, .. } => {
                if path.is_empty() || path.contains('\\') || path.starts_with('/') {
                    return Err(Error::Misuse(format!("inline {i} path {path:?} must be relative with '/' separators")));
                }
            }
        }
    }
    for (i, t) in scene.trees.iter().enumerate() {
        if t.level_count() > 0 && t.leaf_count() * 2 != t.len() + 1 {
            return Err(Error::Misuse(format!("tree {i} is truncated (not all levels are present)")));
        }
        // The reader refuses such a file at open. A group tree built over instances whose
        // placements reach past f32 (an affine entry near f32::MAX, a huge scale) gets one.
        if let Some(root) = t.nodes().first().filter(|r| !r.is_finite()) {
            return Err(Error::Misuse(format!("tree {i} has a root with non-finite or out-of-range attributes ({root})")));
        }
    }
    Ok(())
}

/// Graph record kinds (spec §7).
pub(crate) mod kind {
    pub const TREE: u8 = 0;
    pub const GROUP: u8 = 1;
    pub const INSTANCE: u8 = 2;
    pub const INLINE: u8 = 3;
    pub const AFFINE: u8 = 4;
}

/// An instance's flags byte (spec §7): bit 0 size push-down, bit 1 colour push-down, bit 2
/// tint present.
fn instance_flags(attrs: &crate::graph::InstanceAttrs) -> u8 {
    let mut flags = 0u8;
    if attrs.size == Propagation::PushDown {
        flags |= 1;
    }
    if attrs.color == Propagation::PushDown {
        flags |= 2;
    }
    if attrs.tint.is_some() {
        flags |= 4;
    }
    flags
}

pub(super) fn encode_graph(g: &SceneGraph) -> Vec<u8> {
    let mut out = Vec::new();
    out.put_u64(g.nodes.len() as u64);
    out.put_u32(g.root);
    for n in &g.nodes {
        match n {
            GraphNode::Tree { tree } => {
                out.put_u8(kind::TREE);
                out.put_u32(*tree);
            }
            GraphNode::Group { children, tree } => {
                out.put_u8(kind::GROUP);
                out.put_u32(*tree);
                out.put_u64(children.len() as u64);
                children.iter().for_each(|c| out.put_u32(*c));
            }
            GraphNode::Instance { child, transform, attrs } => {
                out.put_u8(kind::INSTANCE);
                out.put_u32(*child);
                put_similarity(&mut out, transform);
                out.put_u8(instance_flags(attrs));
                out.extend_from_slice(&attrs.tint.unwrap_or([255; 4]));
            }
            GraphNode::Affine { child, transform, attrs } => {
                out.put_u8(kind::AFFINE);
                out.put_u32(*child);
                transform.matrix.iter().flatten().for_each(|v| out.put_f64(*v));
                out.put_u8(instance_flags(attrs));
                out.extend_from_slice(&attrs.tint.unwrap_or([255; 4]));
            }
            GraphNode::Inline { path, hash, bound } => {
                out.put_u8(kind::INLINE);
                out.put_str(path);
                out.extend_from_slice(hash);
                crate::codec::raw::write_node(bound, &mut out);
            }
        }
    }
    out
}
