//! The scene graph (thesis §5.10): generator provenance, trees, groups, instances, inlines.

use serde::{Deserialize, Serialize};

use crate::node::Node;

/// Provenance of a file: enough to regenerate it (thesis §5.10.1, "generator").
///
/// Stored as UTF-8 JSON in the `GENR` section, the first section of every file.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Generator {
    /// Tool name, e.g. `sct-build-tree`.
    pub tool: String,
    /// Tool version, e.g. `0.1.0`.
    pub version: String,
    /// Every parameter that influenced the output (tool specific).
    #[serde(default)]
    pub parameters: serde_json::Value,
    /// The files the output was made from.
    #[serde(default)]
    pub sources: Vec<SourceRef>,
}

/// One input file and the BLAKE3 hash of its bytes.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct SourceRef {
    /// Path as given to the tool.
    pub path: String,
    /// BLAKE3 hash of the file's content, lowercase hex.
    pub blake3: String,
}

/// A similarity transform: `x' = translation + scale * rotate(rotation, x)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Similarity {
    /// Translation.
    pub translation: [f64; 3],
    /// Unit quaternion `(x, y, z, w)` (glTF order).
    pub rotation: [f64; 4],
    /// Uniform scale, > 0.
    pub scale: f64,
}

/// For messages: `translation (x, y, z), rotation (x, y, z, w), scale s`, never a Rust
/// debug structure.
impl std::fmt::Display for Similarity {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let [x, y, z] = self.translation;
        let [qx, qy, qz, qw] = self.rotation;
        write!(f, "translation ({x}, {y}, {z}), rotation ({qx}, {qy}, {qz}, {qw}), scale {}", self.scale)
    }
}

impl Default for Similarity {
    fn default() -> Self {
        Similarity::IDENTITY
    }
}

impl Similarity {
    /// The identity transform.
    pub const IDENTITY: Similarity =
        Similarity { translation: [0.0; 3], rotation: [0.0, 0.0, 0.0, 1.0], scale: 1.0 };

    /// Rotates `v` by the (assumed unit) quaternion.
    pub fn rotate(&self, v: [f64; 3]) -> [f64; 3] {
        let [qx, qy, qz, qw] = self.rotation;
        // t = 2 q.xyz × v ; v' = v + w t + q.xyz × t
        let t = [
            2.0 * (qy * v[2] - qz * v[1]),
            2.0 * (qz * v[0] - qx * v[2]),
            2.0 * (qx * v[1] - qy * v[0]),
        ];
        [
            v[0] + qw * t[0] + (qy * t[2] - qz * t[1]),
            v[1] + qw * t[1] + (qz * t[0] - qx * t[2]),
            v[2] + qw * t[2] + (qx * t[1] - qy * t[0]),
        ]
    }

    /// Applies the transform to a point.
    pub fn apply_point(&self, p: [f64; 3]) -> [f64; 3] {
        let r = self.rotate(p);
        [
            self.translation[0] + self.scale * r[0],
            self.translation[1] + self.scale * r[1],
            self.translation[2] + self.scale * r[2],
        ]
    }

    /// `self ∘ inner`: first `inner`, then `self`.
    pub fn compose(&self, inner: &Similarity) -> Similarity {
        let [ax, ay, az, aw] = self.rotation;
        let [bx, by, bz, bw] = inner.rotation;
        let rotation = [
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz,
        ];
        Similarity {
            translation: self.apply_point(inner.translation),
            rotation,
            scale: self.scale * inner.scale,
        }
    }

    /// Transforms a node: centre, radius × s, cone axis rotated, area × s², cone and colour unchanged.
    pub fn apply_node(&self, n: &Node) -> Node {
        let c = self.apply_point([n.center[0] as f64, n.center[1] as f64, n.center[2] as f64]);
        let d = self.rotate([n.normal[0] as f64, n.normal[1] as f64, n.normal[2] as f64]);
        Node {
            center: [c[0] as f32, c[1] as f32, c[2] as f32],
            radius: (n.radius as f64 * self.scale) as f32,
            normal: [d[0] as f32, d[1] as f32, d[2] as f32],
            cone: n.cone,
            area: (n.area as f64 * self.scale * self.scale) as f32,
            color: n.color,
        }
    }

    /// True when every component is finite, the quaternion has unit length within `tol`
    /// and the scale is positive.
    pub fn is_valid(&self, tol: f64) -> bool {
        let finite = self.translation.iter().chain(self.rotation.iter()).all(|v| v.is_finite())
            && self.scale.is_finite();
        let len2: f64 = self.rotation.iter().map(|v| v * v).sum();
        finite && (len2.sqrt() - 1.0).abs() <= tol && self.scale > 0.0
    }
}

/// Whether an instance takes an attribute from its subtree (pull-up) or imposes it on the
/// subtree (push-down), thesis §5.11.2.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum Propagation {
    /// The instance's attribute is derived from its child (hierarchically consistent).
    #[default]
    PullUp,
    /// The instance's attribute overrides the attribute of every node below it.
    PushDown,
}

/// Per-instance attribute handling (§5.11.2).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct InstanceAttrs {
    /// Size handling.
    pub size: Propagation,
    /// Colour handling.
    pub color: Propagation,
    /// Push-down tint: RGBA multiplied into every colour below (255 = unchanged).
    pub tint: Option<[u8; 4]>,
}

/// One scene-graph node. Children are referenced by index into [`SceneGraph::nodes`] and
/// must have a smaller index than the referring node, which makes cycles impossible.
#[derive(Clone, Debug, PartialEq)]
pub enum GraphNode {
    /// Geometry: scene tree `tree` of the file.
    Tree {
        /// Index into the file's trees.
        tree: u32,
    },
    /// A group owning a scene tree over its children's virtual roots: leaf `j` of `tree`
    /// (leaves counted in breadth-first order) bounds `children[j]`.
    Group {
        /// Child graph nodes.
        children: Vec<u32>,
        /// Index into the file's trees.
        tree: u32,
    },
    /// A transformed, optionally tinted use of `child`.
    Instance {
        /// The instanced graph node.
        child: u32,
        /// Placement.
        transform: Similarity,
        /// Pull-up / push-down handling and tint.
        attrs: InstanceAttrs,
    },
    /// A use of `child` placed by a general affine map (non-uniform scale, shear, mirror;
    /// spec §7, format 1.3), optionally tinted. Placements that are similarities are
    /// [`GraphNode::Instance`]s.
    Affine {
        /// The instanced graph node.
        child: u32,
        /// Placement: an invertible map within [`crate::affine::MAX_CONDITION`].
        transform: crate::affine::Affine,
        /// Pull-up / push-down handling and tint (as for [`GraphNode::Instance`]).
        attrs: InstanceAttrs,
    },
    /// Another SCT file, referenced by a path relative to this file.
    Inline {
        /// Relative path with `/` separators.
        path: String,
        /// BLAKE3 hash of the referenced file's bytes.
        hash: [u8; 32],
        /// The referenced file's root node, so traversal can cull without opening it.
        bound: Node,
    },
}

impl GraphNode {
    /// For an instance of either kind: its child, its transform and its attributes.
    pub fn instance(&self) -> Option<(u32, crate::affine::Transform, InstanceAttrs)> {
        match self {
            GraphNode::Instance { child, transform, attrs } => Some((*child, (*transform).into(), *attrs)),
            GraphNode::Affine { child, transform, attrs } => Some((*child, (*transform).into(), *attrs)),
            _ => None,
        }
    }
}

/// The scene graph of a file.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SceneGraph {
    /// Nodes; references point to smaller indices.
    pub nodes: Vec<GraphNode>,
    /// Index of the root graph node.
    pub root: u32,
}
