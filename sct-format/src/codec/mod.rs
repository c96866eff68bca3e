//! Node codecs: how the children of one level are stored relative to their decoded parents.
//!
//! A block holds sibling pairs; pair `k` of a block has decoded parent `parents[k]`. Every
//! profile encodes children relative to the *decoded* parent (thesis §5.9.1) so that
//! quantization errors never accumulate down the tree. The root is always stored raw in
//! the tree header.

pub mod canopy;
mod color;
pub mod default;
mod normal;
mod posrad;
pub mod raw;
mod rounding;

use crate::error::{Error, Result};
use crate::node::Node;

/// A node encoding profile (spec §5).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Profile {
    /// 40 bytes per node: f32 attributes, 8-bit RGBA.
    Raw,
    /// The thesis's 86-bit node (§5.9.1): 14-bit position/radius state, 16-bit normal, 8-bit
    /// cone, RGB565 / RGBA5654, f32 area.
    Canopy,
    /// Our default: separated attribute streams predicted from the parent, zstd-coded.
    #[default]
    Default,
}

impl Profile {
    /// The profile id stored in the tree header.
    pub fn id(self) -> u8 {
        match self {
            Profile::Raw => 0,
            Profile::Canopy => 1,
            Profile::Default => 2,
        }
    }

    /// The profile with stored id `id`.
    pub fn from_id(id: u8) -> Option<Profile> {
        match id {
            0 => Some(Profile::Raw),
            1 => Some(Profile::Canopy),
            2 => Some(Profile::Default),
            _ => None,
        }
    }

    /// Name used on command lines and in reports.
    pub fn name(self) -> &'static str {
        match self {
            Profile::Raw => "raw",
            Profile::Canopy => "canopy",
            Profile::Default => "default",
        }
    }

    /// Whether blocks of this profile are zstd-compressed by default.
    pub fn compress_by_default(self) -> bool {
        matches!(self, Profile::Default)
    }

    /// Documented containment tolerance: a decoded child lies inside its decoded parent
    /// grown by this fraction of the parent's radius (spec §5).
    pub fn containment_slack(self) -> f32 {
        match self {
            Profile::Raw => raw::CONTAINMENT_SLACK,
            Profile::Canopy => canopy::CONTAINMENT_SLACK,
            Profile::Default => default::CONTAINMENT_SLACK,
        }
    }
}

impl std::str::FromStr for Profile {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "raw" => Ok(Profile::Raw),
            "canopy" => Ok(Profile::Canopy),
            "default" => Ok(Profile::Default),
            _ => Err(format!("unknown profile {s:?} (expected raw, canopy or default)")),
        }
    }
}

/// Tree-wide settings a codec needs (stored in the tree header).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CodecParams {
    /// True when some node has alpha < 255 (Canopy switches from RGB565 to RGBA5654).
    pub alpha: bool,
    /// Default profile only: every child carries a centre offset along its normal (1.2, tree
    /// flag bit 2; [`default`]'s "Centre offsets").
    pub centre_offsets: bool,
    /// Default profile only: every child carries a centre step and a radius cut relative to
    /// its own decoded radius (1.4, tree flag bit 3; [`default`]'s "Leaf refinement").
    pub leaf_refinement: bool,
}

impl CodecParams {
    /// The parameters a tree header's flags byte selects.
    pub fn from_tree_flags(flags: u8) -> CodecParams {
        CodecParams { alpha: flags & 1 != 0, centre_offsets: flags & 4 != 0, leaf_refinement: flags & 8 != 0 }
    }
}

/// Encodes `children` (sibling pairs, `children.len() == 2 * parents.len()`), appending to
/// `out`; returns the children exactly as a reader will decode them.
pub fn encode_children(
    profile: Profile,
    params: CodecParams,
    parents: &[Node],
    children: &[Node],
    out: &mut Vec<u8>,
) -> Result<Vec<Node>> {
    encode_children_with_leaves(profile, params, parents, children, None, out)
}

/// [`encode_children`] told which children have children of their own (`has_children`, one
/// flag a child), so that centre offsets refine only leaves (see [`default::encode_with_leaves`]).
pub fn encode_children_with_leaves(
    profile: Profile,
    params: CodecParams,
    parents: &[Node],
    children: &[Node],
    has_children: Option<&[bool]>,
    out: &mut Vec<u8>,
) -> Result<Vec<Node>> {
    if params.centre_offsets && profile != Profile::Default {
        return Err(Error::Misuse(format!("centre offsets need the default profile, not {}", profile.name())));
    }
    if params.leaf_refinement && profile != Profile::Default {
        return Err(Error::Misuse(format!("leaf refinement needs the default profile, not {}", profile.name())));
    }
    if children.len() != 2 * parents.len() {
        return Err(Error::Misuse(format!(
            "{} children for {} parents (need exactly two each)",
            children.len(),
            parents.len()
        )));
    }
    match profile {
        Profile::Raw => Ok(raw::encode(children, out)),
        Profile::Canopy => canopy::encode(params, parents, children, out),
        Profile::Default => default::encode_with_leaves(params, parents, children, has_children, out),
    }
}

/// Attribute names used by [`streams`], in the order a report lists them.
pub const ATTRIBUTES: [&str; 6] = ["position_radius", "normal", "cone", "color", "area", "other"];

/// The payload of `m` children as consecutive homogeneous streams: `(attribute, bytes)`, where
/// the attribute is an index into [`ATTRIBUTES`]. A writer may end compression blocks at
/// these boundaries and attribute stored bytes to them; the payload itself is unchanged.
/// Record profiles (raw, canopy) interleave fields, so they are one stream each, split over
/// the attributes by field width (exact without compression).
pub fn streams(profile: Profile, params: CodecParams, m: usize) -> Vec<Stream> {
    match profile {
        // centre + radius 16, normal 12, cone 4, colour 4, area 4 bytes.
        Profile::Raw => vec![Stream { len: m * raw::NODE_BYTES, widths: [16, 12, 4, 4, 4, 0] }],
        // state 2, normal 2, cone 1, colour 2 (3 with alpha), area 4 bytes.
        Profile::Canopy => vec![Stream { len: m * canopy::node_bytes(params), widths: [2, 2, 1, 2 + params.alpha as u32, 4, 0] }],
        Profile::Default => default::streams(params, m),
    }
}

/// One consecutive stream of a block payload (see [`streams`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Stream {
    /// Bytes.
    pub len: usize,
    /// How its bytes split over [`ATTRIBUTES`] (relative widths).
    pub widths: [u32; 6],
}

impl Stream {
    /// A stream holding one attribute.
    pub(crate) fn of(attribute: usize, len: usize) -> Stream {
        let mut widths = [0; 6];
        widths[attribute] = 1;
        Stream { len, widths }
    }
}

/// Bytes of a block of `nodes` nodes (whole sibling pairs) after decompression: the
/// has-children mask, then the profile payload (spec §6.3). Every profile codes a fixed
/// number of bytes per sibling pair, so a block's raw length follows from its node count; a
/// reader checks the stored raw length against this before it inflates anything, so a
/// block can never make it hold more than its nodes need. `None` on overflow.
pub fn block_raw_len(profile: Profile, params: CodecParams, nodes: u64) -> Option<u64> {
    let mask = nodes.div_ceil(8);
    let payload = match profile {
        Profile::Raw => nodes.checked_mul(raw::NODE_BYTES as u64)?,
        Profile::Canopy => nodes.checked_mul(canopy::node_bytes(params) as u64)?,
        Profile::Default => default::payload_len(params, usize::try_from(nodes / 2).ok()?)? as u64,
    };
    mask.checked_add(payload)
}

/// Decodes the children of `parents` from `bytes` (one block's codec payload), appending
/// `2 * parents.len()` nodes to `out`. `offset` is the payload's position, for errors.
pub fn decode_children(
    profile: Profile,
    params: CodecParams,
    parents: &[Node],
    bytes: &[u8],
    offset: u64,
    out: &mut Vec<Node>,
) -> Result<()> {
    match profile {
        Profile::Raw => raw::decode(parents.len() * 2, bytes, offset, out),
        Profile::Canopy => canopy::decode(params, parents, bytes, offset, out),
        Profile::Default => default::decode(params, parents, bytes, offset, out),
    }
}
