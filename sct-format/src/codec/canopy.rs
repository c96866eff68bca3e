//! canopy profile (being written; falls back to raw storage until then).

use super::CodecParams;
use crate::error::Result;
use crate::node::Node;

/// Documented containment slack (fraction of the parent radius).
pub const CONTAINMENT_SLACK: f32 = 0.5;

/// Encodes sibling pairs relative to their decoded parents.
pub fn encode(_params: CodecParams, _parents: &[Node], children: &[Node], out: &mut Vec<u8>) -> Result<Vec<Node>> {
    Ok(super::raw::encode(children, out))
}

/// Decodes the children of `parents`.
pub fn decode(_params: CodecParams, parents: &[Node], bytes: &[u8], offset: u64, out: &mut Vec<Node>) -> Result<()> {
    super::raw::decode(parents.len() * 2, bytes, offset, out)
}
