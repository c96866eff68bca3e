//! File header and section table (spec §2).

use super::cursor::{Cursor, Put};
use crate::error::Result;

/// Magic of an SCT scene file.
pub const SCT_MAGIC: [u8; 8] = *b"\x89SCT\r\n\x1a\n";
/// Magic of a samples file.
pub const SAMPLES_MAGIC: [u8; 8] = *b"\x89SCS\r\n\x1a\n";
/// Bytes in the file header.
pub const FILE_HEADER_LEN: usize = 64;
/// Bytes in one section-table entry.
pub const SECTION_ENTRY_LEN: usize = 40;

/// The 64-byte file header.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FileHeader {
    /// Must be [`SCT_MAGIC`] or [`SAMPLES_MAGIC`].
    pub magic: [u8; 8],
    /// Must be 1 for this specification.
    pub major: u16,
    /// Minor version; readers accept any.
    pub minor: u16,
    /// Reserved, written 0, ignored by readers.
    pub flags: u32,
    /// Number of section-table entries.
    pub section_count: u32,
    /// Absolute offset of the section table.
    pub section_table_offset: u64,
    /// Total file length in bytes.
    pub file_length: u64,
    /// CRC-32 of the section table bytes.
    pub table_crc: u32,
    /// CRC-32 of header bytes 0..60.
    pub header_crc: u32,
}

impl FileHeader {
    /// Parses the header fields (no checks beyond length).
    pub fn parse(c: &mut Cursor<'_>) -> Result<Self> {
        let magic = c.array("magic")?;
        let major = c.u16("major version")?;
        let minor = c.u16("minor version")?;
        let flags = c.u32("flags")?;
        let section_count = c.u32("section count")?;
        let _reserved = c.u32("reserved")?;
        let section_table_offset = c.u64("section table offset")?;
        let file_length = c.u64("file length")?;
        let table_crc = c.u32("section table CRC")?;
        c.take(16, "reserved")?;
        let header_crc = c.u32("header CRC")?;
        Ok(FileHeader { magic, major, minor, flags, section_count, section_table_offset, file_length, table_crc, header_crc })
    }

    /// Serializes the header, computing `header_crc`.
    pub fn write(&self, out: &mut Vec<u8>) {
        let start = out.len();
        out.extend_from_slice(&self.magic);
        out.put_u16(self.major);
        out.put_u16(self.minor);
        out.put_u32(self.flags);
        out.put_u32(self.section_count);
        out.put_u32(0);
        out.put_u64(self.section_table_offset);
        out.put_u64(self.file_length);
        out.put_u32(self.table_crc);
        out.extend_from_slice(&[0u8; 16]);
        let crc = crc32fast::hash(&out[start..]);
        out.put_u32(crc);
    }
}

/// One 40-byte section-table entry.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SectionEntry {
    /// Four ASCII bytes.
    pub tag: [u8; 4],
    /// Bit 0: required; bit 1: zstd-compressed; other bits reserved (0).
    pub flags: u32,
    /// Absolute offset of the stored bytes.
    pub offset: u64,
    /// Stored (possibly compressed) length.
    pub stored_len: u64,
    /// Length after decompression (equals `stored_len` when not compressed).
    pub raw_len: u64,
    /// CRC-32 of the stored bytes.
    pub crc: u32,
}

impl SectionEntry {
    /// Flag: readers must understand this section.
    pub const REQUIRED: u32 = 1;
    /// Flag: the stored bytes are one zstd frame.
    pub const ZSTD: u32 = 2;

    /// Parses one entry.
    pub fn parse(c: &mut Cursor<'_>) -> Result<Self> {
        let tag = c.array("section tag")?;
        let flags = c.u32("section flags")?;
        let offset = c.u64("section offset")?;
        let stored_len = c.u64("section stored length")?;
        let raw_len = c.u64("section raw length")?;
        let crc = c.u32("section CRC")?;
        let _reserved = c.u32("reserved")?;
        Ok(SectionEntry { tag, flags, offset, stored_len, raw_len, crc })
    }

    /// Serializes the entry.
    pub fn write(&self, out: &mut Vec<u8>) {
        out.extend_from_slice(&self.tag);
        out.put_u32(self.flags);
        out.put_u64(self.offset);
        out.put_u64(self.stored_len);
        out.put_u64(self.raw_len);
        out.put_u32(self.crc);
        out.put_u32(0);
    }

    /// The tag as text (non-ASCII bytes escaped).
    pub fn tag_str(&self) -> String {
        self.tag.escape_ascii().to_string()
    }

    /// Required flag.
    pub fn required(&self) -> bool {
        self.flags & Self::REQUIRED != 0
    }

    /// Compressed flag.
    pub fn compressed(&self) -> bool {
        self.flags & Self::ZSTD != 0
    }
}
