//! Plain structs that mirror the on-disk tables of `spec/SCT.md` one to one.
//!
//! Nothing here checks meaning beyond "the bytes are there": the validated layer
//! ([`crate::read`], [`crate::samples`]) decides what the values may be.

pub(crate) mod cursor;
mod header;
mod tree;

pub use cursor::Cursor;
pub use header::{FileHeader, SectionEntry, FILE_HEADER_LEN, SAMPLES_MAGIC, SCT_MAGIC, SECTION_ENTRY_LEN};
pub use tree::{BlockEntry, LevelEntry, TreeHeader, BLOCK_ENTRY_LEN, LEVEL_ENTRY_LEN, TREE_HEADER_LEN};

/// Section tags (spec §3).
pub mod tags {
    /// Generator provenance, JSON (required, first).
    pub const GENR: [u8; 4] = *b"GENR";
    /// Scene graph (required).
    pub const GRPH: [u8; 4] = *b"GRPH";
    /// One scene tree (required; the i-th TREE section is tree i).
    pub const TREE: [u8; 4] = *b"TREE";
    /// Samples (samples file, required).
    pub const SMPL: [u8; 4] = *b"SMPL";
    /// Mesh table (samples file, required).
    pub const MESH: [u8; 4] = *b"MESH";
    /// Instance list (samples file, required).
    pub const INST: [u8; 4] = *b"INST";
}
