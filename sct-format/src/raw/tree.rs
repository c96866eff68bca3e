//! Tree section tables (spec §6): tree header, level table, block table.

use super::cursor::{Cursor, Put};
use crate::codec::raw::{read_node, write_node, NODE_BYTES};
use crate::error::Result;
use crate::node::Node;

/// Bytes in the tree header.
pub const TREE_HEADER_LEN: usize = 80;
/// Bytes in one level-table entry.
pub const LEVEL_ENTRY_LEN: usize = 16;
/// Bytes in one block-table entry.
pub const BLOCK_ENTRY_LEN: usize = 48;

/// The 80-byte header at the start of a `TREE` section.
#[derive(Clone, Debug, PartialEq)]
pub struct TreeHeader {
    /// Codec profile id (0 raw, 1 canopy, 2 default).
    pub profile: u8,
    /// Bit 0: some colour has alpha < 255.
    pub flags: u8,
    /// 1 when the root has children.
    pub root_internal: u8,
    /// Number of levels (0 for an empty tree).
    pub level_count: u32,
    /// Number of nodes.
    pub node_count: u64,
    /// Number of leaves.
    pub leaf_count: u64,
    /// Number of blocks.
    pub block_count: u32,
    /// The root node, raw.
    pub root: Node,
}

impl TreeHeader {
    /// Parses the header.
    pub fn parse(c: &mut Cursor<'_>) -> Result<Self> {
        let profile = c.u8("profile")?;
        let flags = c.u8("tree flags")?;
        let root_internal = c.u8("root internal flag")?;
        let _ = c.u8("reserved")?;
        let level_count = c.u32("level count")?;
        let node_count = c.u64("node count")?;
        let leaf_count = c.u64("leaf count")?;
        let block_count = c.u32("block count")?;
        let _ = c.u32("reserved")?;
        let root = read_node(&c.array::<NODE_BYTES>("root node")?);
        c.take(TREE_HEADER_LEN - 32 - NODE_BYTES, "reserved")?;
        Ok(TreeHeader { profile, flags, root_internal, level_count, node_count, leaf_count, block_count, root })
    }

    /// Serializes the header.
    pub fn write(&self, out: &mut Vec<u8>) {
        out.put_u8(self.profile);
        out.put_u8(self.flags);
        out.put_u8(self.root_internal);
        out.put_u8(0);
        out.put_u32(self.level_count);
        out.put_u64(self.node_count);
        out.put_u64(self.leaf_count);
        out.put_u32(self.block_count);
        out.put_u32(0);
        write_node(&self.root, out);
        out.extend_from_slice(&[0u8; TREE_HEADER_LEN - 32 - NODE_BYTES]);
    }
}

/// One level-table entry.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LevelEntry {
    /// Nodes on this level.
    pub node_count: u64,
    /// Index of the level's first block (level 0 has no blocks).
    pub first_block: u32,
    /// Number of blocks of this level.
    pub block_count: u32,
}

impl LevelEntry {
    /// Parses one entry.
    pub fn parse(c: &mut Cursor<'_>) -> Result<Self> {
        Ok(LevelEntry {
            node_count: c.u64("level node count")?,
            first_block: c.u32("level first block")?,
            block_count: c.u32("level block count")?,
        })
    }
    /// Serializes the entry.
    pub fn write(&self, out: &mut Vec<u8>) {
        out.put_u64(self.node_count);
        out.put_u32(self.first_block);
        out.put_u32(self.block_count);
    }
}

/// One block-table entry: a run of sibling pairs on one level.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BlockEntry {
    /// Level of the block's nodes (≥ 1).
    pub level: u32,
    /// Nodes in the block (even).
    pub node_count: u32,
    /// Index within the level of the block's first node.
    pub first_node: u64,
    /// Internal nodes of this level before the block.
    pub internal_before: u64,
    /// Offset of the stored bytes from the start of the section.
    pub offset: u64,
    /// Stored length.
    pub stored_len: u32,
    /// Length after decompression.
    pub raw_len: u32,
    /// CRC-32 of the stored bytes.
    pub crc: u32,
    /// Bit 0: zstd-compressed.
    pub flags: u32,
}

impl BlockEntry {
    /// Parses one entry.
    pub fn parse(c: &mut Cursor<'_>) -> Result<Self> {
        Ok(BlockEntry {
            level: c.u32("block level")?,
            node_count: c.u32("block node count")?,
            first_node: c.u64("block first node")?,
            internal_before: c.u64("block internal-before count")?,
            offset: c.u64("block offset")?,
            stored_len: c.u32("block stored length")?,
            raw_len: c.u32("block raw length")?,
            crc: c.u32("block CRC")?,
            flags: c.u32("block flags")?,
        })
    }
    /// Serializes the entry.
    pub fn write(&self, out: &mut Vec<u8>) {
        out.put_u32(self.level);
        out.put_u32(self.node_count);
        out.put_u64(self.first_node);
        out.put_u64(self.internal_before);
        out.put_u64(self.offset);
        out.put_u32(self.stored_len);
        out.put_u32(self.raw_len);
        out.put_u32(self.crc);
        out.put_u32(self.flags);
    }
}
