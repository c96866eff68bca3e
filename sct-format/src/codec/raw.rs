//! Raw profile: every attribute stored as-is (f32 little-endian, 8-bit RGBA); 40 bytes a node.

use crate::error::{Error, Result};
use crate::node::Node;

/// Bytes per node.
pub const NODE_BYTES: usize = 40;

/// Raw nodes are stored exactly, so a child decodes exactly where the builder put it.
pub const CONTAINMENT_SLACK: f32 = 1e-5;

/// Appends nodes to `out`; returns them unchanged (raw is lossless).
pub fn encode(children: &[Node], out: &mut Vec<u8>) -> Vec<Node> {
    out.reserve(children.len() * NODE_BYTES);
    for n in children {
        write_node(n, out);
    }
    children.to_vec()
}

/// Writes one node in the 40-byte raw layout.
pub fn write_node(n: &Node, out: &mut Vec<u8>) {
    for v in n.center {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out.extend_from_slice(&n.radius.to_le_bytes());
    for v in n.normal {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out.extend_from_slice(&n.cone.to_le_bytes());
    out.extend_from_slice(&n.area.to_le_bytes());
    out.extend_from_slice(&n.color);
}

/// Reads one node from exactly [`NODE_BYTES`] bytes.
pub fn read_node(b: &[u8; NODE_BYTES]) -> Node {
    let f = |i: usize| f32::from_le_bytes([b[i], b[i + 1], b[i + 2], b[i + 3]]);
    Node {
        center: [f(0), f(4), f(8)],
        radius: f(12),
        normal: [f(16), f(20), f(24)],
        cone: f(28),
        area: f(32),
        color: [b[36], b[37], b[38], b[39]],
    }
}

/// Decodes `count` nodes.
pub fn decode(count: usize, bytes: &[u8], offset: u64, out: &mut Vec<Node>) -> Result<()> {
    let need = count.checked_mul(NODE_BYTES).ok_or_else(|| Error::malformed(offset, "node count overflows"))?;
    if bytes.len() != need {
        return Err(Error::malformed(
            offset,
            format!("raw block holds {} bytes, {count} nodes need {need}", bytes.len()),
        ));
    }
    out.reserve(count);
    for chunk in bytes.chunks_exact(NODE_BYTES) {
        let arr: &[u8; NODE_BYTES] = chunk.try_into().map_err(|_| Error::malformed(offset, "short node"))?;
        out.push(read_node(arr));
    }
    Ok(())
}
