//! The section container shared by SCT and samples files (spec §2): header, section
//! table, per-section CRC-32 and optional zstd compression.

use std::borrow::Cow;
use std::io::{Read, Write};

use crate::error::{Error, Result};
use crate::limits::Limits;
use crate::raw::{Cursor, FileHeader, SectionEntry, FILE_HEADER_LEN, SECTION_ENTRY_LEN};

/// The major version this crate reads and writes.
pub const MAJOR: u16 = 1;
/// The newest minor version this crate writes. A writer labels a file with the smallest
/// minor version whose features it uses (1.1: two-sided trees; 1.2: centre offsets; spec
/// §6.2; 1.3: affine instances, §7), so files without them stay byte-for-byte files of the
/// older version.
pub const MINOR: u16 = 3;

/// A section to be written (low-level API: [`crate::write`] and [`crate::samples`] build these).
pub struct SectionOut {
    /// Four ASCII bytes.
    pub tag: [u8; 4],
    /// Whether readers must understand the section.
    pub required: bool,
    /// Stored bytes (already compressed when `compressed`).
    pub stored: Vec<u8>,
    /// Length after decompression.
    pub raw_len: u64,
    /// Whether `stored` is one zstd frame.
    pub compressed: bool,
}

impl SectionOut {
    /// A section stored as given that readers may skip (spec §2.2: not *required*).
    pub fn optional(tag: [u8; 4], data: Vec<u8>) -> Self {
        SectionOut { required: false, ..SectionOut::plain(tag, data) }
    }

    /// A section stored as given.
    pub fn plain(tag: [u8; 4], data: Vec<u8>) -> Self {
        SectionOut { tag, required: true, raw_len: data.len() as u64, stored: data, compressed: false }
    }

    /// Its section-table entry when stored at `offset` (flags, lengths, CRC-32).
    pub fn entry(&self, offset: u64) -> SectionEntry {
        let mut flags = 0;
        if self.required {
            flags |= SectionEntry::REQUIRED;
        }
        if self.compressed {
            flags |= SectionEntry::ZSTD;
        }
        SectionEntry {
            tag: self.tag,
            flags,
            offset,
            stored_len: self.stored.len() as u64,
            raw_len: self.raw_len,
            crc: crc32fast::hash(&self.stored),
        }
    }

    /// A section stored as one zstd frame.
    pub fn zstd(tag: [u8; 4], data: &[u8], level: i32) -> Result<Self> {
        let stored = zstd::bulk::compress(data, level)?;
        Ok(SectionOut { tag, required: true, raw_len: data.len() as u64, stored, compressed: true })
    }
}

/// Writes header, section table and sections; returns the number of bytes written and
/// the absolute offset of each section.
pub fn write_container<W: Write>(magic: [u8; 8], sections: &[SectionOut], w: W) -> Result<(u64, Vec<u64>)> {
    write_container_minor(magic, 0, sections, w)
}

/// [`write_container`] labelling the file with minor version `minor`.
pub fn write_container_minor<W: Write>(magic: [u8; 8], minor: u16, sections: &[SectionOut], mut w: W) -> Result<(u64, Vec<u64>)> {
    let mut offset = (FILE_HEADER_LEN + sections.len() * SECTION_ENTRY_LEN) as u64;
    let mut entries = Vec::with_capacity(sections.len());
    for s in sections {
        entries.push(s.entry(offset));
        offset += s.stored.len() as u64;
    }
    w.write_all(&header_and_table(magic, minor, &entries, offset))?;
    for s in sections {
        w.write_all(&s.stored)?;
    }
    Ok((offset, entries.iter().map(|e| e.offset).collect()))
}

/// The file header followed by the section table of `entries`, for a file of `file_length`
/// bytes (streaming writers reserve these bytes and fill them in last).
pub(crate) fn header_and_table(magic: [u8; 8], minor: u16, entries: &[SectionEntry], file_length: u64) -> Vec<u8> {
    let (mut out, table) = header_and_table_at(magic, minor, entries, FILE_HEADER_LEN as u64, file_length);
    out.extend_from_slice(&table);
    out
}

/// The file header and, apart, the section table of `entries`, for a table stored at
/// `table_offset` (the samples writer puts it after the sections, §8).
pub(crate) fn header_and_table_at(magic: [u8; 8], minor: u16, entries: &[SectionEntry], table_offset: u64, file_length: u64) -> (Vec<u8>, Vec<u8>) {
    let mut table = Vec::with_capacity(entries.len() * SECTION_ENTRY_LEN);
    entries.iter().for_each(|e| e.write(&mut table));
    let mut header = Vec::with_capacity(FILE_HEADER_LEN + table.len());
    FileHeader {
        magic,
        major: MAJOR,
        minor,
        flags: 0,
        section_count: entries.len() as u32,
        section_table_offset: table_offset,
        file_length,
        table_crc: crc32fast::hash(&table),
        header_crc: 0,
    }
    .write(&mut header);
    (header, table)
}

/// CRC-32 of `bytes`, pieces of a large input hashed in parallel and combined in order.
pub(crate) fn crc32(bytes: &[u8]) -> u32 {
    use rayon::prelude::*;
    /// Large enough that combining (a few hundred operations) is noise.
    const PIECE: usize = 4 << 20;
    if bytes.len() <= PIECE {
        return crc32fast::hash(bytes);
    }
    bytes
        .par_chunks(PIECE)
        .map(|p| {
            let mut h = crc32fast::Hasher::new();
            h.update(p);
            h
        })
        .reduce(crc32fast::Hasher::new, |mut a, b| {
            a.combine(&b);
            a
        })
        .finalize()
}

/// A parsed container over borrowed bytes.
#[derive(Clone, Debug)]
pub struct Container<'a> {
    pub(crate) data: &'a [u8],
    /// The file header.
    pub header: FileHeader,
    /// Known sections in table order (unknown optional sections are skipped).
    pub sections: Vec<SectionEntry>,
    /// Tags of unknown optional sections that were skipped.
    pub skipped: Vec<String>,
}

impl<'a> Container<'a> {
    /// Parses and checks the header and section table. `known` lists the tags this reader
    /// understands; unknown required sections are an error, unknown optional ones skipped.
    pub fn parse(data: &'a [u8], magic: [u8; 8], expected: &'static str, known: &[[u8; 4]], limits: &Limits) -> Result<Self> {
        let header = parse_header(data, data.len() as u64, magic, expected)?;
        let table_len = (header.section_count as u64) * SECTION_ENTRY_LEN as u64;
        Limits::check("section count", header.section_count as u64, limits.max_sections as u64)?;
        let table = slice(data, header.section_table_offset, table_len, "section table")?;
        let (sections, skipped) = parse_table(&header, table, data.len() as u64, known, limits)?;
        Ok(Container { data, header, sections, skipped })
    }

    /// The whole file.
    pub fn data(&self) -> &'a [u8] {
        self.data
    }

    /// Sections with `tag`, in table order.
    pub fn sections_with(&self, tag: [u8; 4]) -> impl Iterator<Item = &SectionEntry> {
        self.sections.iter().filter(move |e| e.tag == tag)
    }

    /// The only section with `tag`; an error if it is missing or repeated.
    pub fn single(&self, tag: [u8; 4]) -> Result<&SectionEntry> {
        single_in(&self.sections, tag, self.header.section_table_offset)
    }

    /// Stored bytes of a section, without checking the CRC.
    pub fn stored(&self, e: &SectionEntry) -> Result<&'a [u8]> {
        slice(self.data, e.offset, e.stored_len, "section data")
    }

    /// Verifies a section's CRC.
    pub fn verify(&self, e: &SectionEntry) -> Result<()> {
        let stored = self.stored(e)?;
        let computed = crc32(stored);
        if computed != e.crc {
            return Err(Error::Checksum { what: format!("section {}", e.tag_str()), offset: e.offset, stored: e.crc, computed });
        }
        Ok(())
    }

    /// The section's bytes after CRC check and decompression.
    pub fn section_bytes(&self, e: &SectionEntry, limits: &Limits) -> Result<Cow<'a, [u8]>> {
        self.verify(e)?;
        let stored = self.stored(e)?;
        if !e.compressed() {
            return Ok(Cow::Borrowed(stored));
        }
        decompress(stored, e.raw_len, e.offset, limits).map(Cow::Owned)
    }
}

/// The only section of `sections` with `tag`; an error (at the section table,
/// `table_offset`) if it is missing or repeated.
pub(crate) fn single_in(sections: &[SectionEntry], tag: [u8; 4], table_offset: u64) -> Result<&SectionEntry> {
    let mut it = sections.iter().filter(|e| e.tag == tag);
    let first = it.next().ok_or_else(|| Error::malformed(table_offset, format!("required section {} is missing", tag.escape_ascii())))?;
    if it.next().is_some() {
        return Err(Error::malformed(table_offset, format!("section {} appears twice", tag.escape_ascii())));
    }
    Ok(first)
}

/// Checks the file header at the start of `head` (at least its first bytes) for a file of
/// `file_len` bytes, in the order of spec §2.1: magic, header CRC, major version, length.
pub(crate) fn parse_header(head: &[u8], file_len: u64, magic: [u8; 8], expected: &'static str) -> Result<FileHeader> {
    let found_magic = head.get(..8).unwrap_or(head);
    if found_magic != magic {
        return Err(Error::BadMagic { expected, found: found_magic.to_vec() });
    }
    let mut c = Cursor::new(head, 0);
    let header = FileHeader::parse(&mut c)?;
    let computed = crc32fast::hash(&head[..FILE_HEADER_LEN - 4]);
    if computed != header.header_crc {
        return Err(Error::Checksum { what: "file header".into(), offset: 0, stored: header.header_crc, computed });
    }
    if header.major != MAJOR {
        return Err(Error::UnsupportedVersion { major: header.major, minor: header.minor, supported: MAJOR });
    }
    if header.file_length != file_len {
        return Err(Error::malformed(
            32,
            format!("header says the file has {} bytes, it has {file_len} (truncated or extended)", header.file_length),
        ));
    }
    Ok(header)
}

/// Parses and checks the section table `table` (the `40 × section_count` bytes at
/// `header.section_table_offset`) of a file of `file_len` bytes: its CRC, every entry's
/// range and flags, and that no two of the header, the table and the sections overlap (a
/// section aliasing another's bytes would make a reader do the same work twice, or
/// thousands of times, for one stored copy). Returns the known sections in table order and
/// the tags of the skipped unknown optional ones.
pub(crate) fn parse_table(header: &FileHeader, table: &[u8], file_len: u64, known: &[[u8; 4]], limits: &Limits) -> Result<(Vec<SectionEntry>, Vec<String>)> {
    Limits::check("section count", header.section_count as u64, limits.max_sections as u64)?;
    let computed = crc32fast::hash(table);
    if computed != header.table_crc {
        return Err(Error::Checksum { what: "section table".into(), offset: header.section_table_offset, stored: header.table_crc, computed });
    }
    let mut c = Cursor::new(table, header.section_table_offset);
    let mut sections = Vec::with_capacity(header.section_count as usize);
    let mut skipped = Vec::new();
    // (start, end, what, entry offset) of every non-empty range of the file, for the overlap check.
    let mut ranges: Vec<(u64, u64, String, u64)> = Vec::with_capacity(header.section_count as usize + 2);
    ranges.push((0, FILE_HEADER_LEN as u64, "the file header".into(), 0));
    let table_end = header.section_table_offset.saturating_add(table.len() as u64);
    ranges.push((header.section_table_offset, table_end, "the section table".into(), 24));
    for i in 0..header.section_count {
        let at = c.offset();
        let e = SectionEntry::parse(&mut c)?;
        if e.offset.checked_add(e.stored_len).is_none_or(|end| end > file_len) {
            return Err(Error::malformed(at, format!("section {} lies outside the file", e.tag_str())));
        }
        if !e.compressed() && e.raw_len != e.stored_len {
            return Err(Error::malformed(at, format!("uncompressed section {} has raw length != stored length", e.tag_str())));
        }
        if e.flags & !(SectionEntry::REQUIRED | SectionEntry::ZSTD) != 0 {
            return Err(Error::malformed(at + 4, format!("section {} has reserved flag bits set", e.tag_str())));
        }
        ranges.push((e.offset, e.offset + e.stored_len, format!("section {i} ({})", e.tag_str()), at));
        if known.contains(&e.tag) {
            sections.push(e);
        } else if e.required() {
            return Err(Error::UnknownRequiredSection { tag: e.tag_str(), offset: at });
        } else {
            skipped.push(e.tag_str());
        }
    }
    ranges.retain(|r| r.1 > r.0);
    ranges.sort_by_key(|r| (r.0, r.1));
    for w in ranges.windows(2) {
        let (a, b) = (&w[0], &w[1]);
        if b.0 < a.1 {
            // Reported at the table entry of the later-starting range (the header's own
            // offset field when it is the table that overlaps).
            return Err(Error::malformed(
                b.3,
                format!("{} (bytes {}..{}) overlaps {} (bytes {}..{}): sections must not overlap", b.2, b.0, b.1, a.2, a.0, a.1),
            ));
        }
    }
    Ok((sections, skipped))
}

/// `data[offset..offset + len]`, or a malformed error naming `what`.
pub(crate) fn slice<'d>(data: &'d [u8], offset: u64, len: u64, what: &str) -> Result<&'d [u8]> {
    let end = offset.checked_add(len).filter(|&e| e <= data.len() as u64).ok_or_else(|| {
        Error::malformed(offset, format!("{what} ({len} bytes at {offset}) extends past the end of the file ({} bytes)", data.len()))
    })?;
    Ok(&data[offset as usize..end as usize])
}

/// Decompresses `stored`, which must be exactly one zstd frame (spec §1: bytes after the
/// frame are malformed, not ignored) inflating to exactly `raw_len` bytes. Memory grows with
/// the data actually produced and never past `raw_len`, so callers bound `raw_len` by what
/// the section or block can mean before calling: a frame whose claim is plausible (at most
/// 8 times its stored size) is decompressed in one pass straight into a buffer of the
/// claimed size, which bounds it; any other streams into a buffer that grows as data comes
/// out.
pub(crate) fn decompress(stored: &[u8], raw_len: u64, offset: u64, limits: &Limits) -> Result<Vec<u8>> {
    Limits::check("decompressed size", raw_len, limits.max_decompressed_bytes)?;
    let corrupt = |code: usize| Error::malformed(offset, format!("zstd data is corrupt: {}", zstd::zstd_safe::get_error_name(code)));
    let frame_len = zstd::zstd_safe::find_frame_compressed_size(stored).map_err(corrupt)?;
    if frame_len != stored.len() {
        return Err(Error::malformed(
            offset,
            format!("{} bytes follow the zstd frame ({frame_len} bytes): the stored bytes must be exactly one frame", stored.len().saturating_sub(frame_len)),
        ));
    }
    let plausible = stored.len() as u64 * 8 + 4096;
    if raw_len <= plausible {
        let mut out = Vec::with_capacity(raw_len as usize);
        inflate_into(stored, &mut out, offset)?;
        if out.len() as u64 != raw_len {
            return Err(Error::malformed(offset, format!("decompressed to {} bytes, expected {raw_len}", out.len())));
        }
        return Ok(out);
    }
    let mut dec = zstd::stream::read::Decoder::with_buffer(stored)
        .map_err(|e| Error::malformed(offset, format!("zstd: {e}")))?
        .single_frame();
    let mut out = Vec::with_capacity(plausible as usize);
    (&mut dec)
        .take(raw_len.saturating_add(1))
        .read_to_end(&mut out)
        .map_err(|e| Error::malformed(offset, format!("zstd data is corrupt: {e}")))?;
    if out.len() as u64 != raw_len {
        return Err(Error::malformed(offset, format!("decompressed to {} bytes, expected {raw_len}", out.len())));
    }
    Ok(out)
}

/// Decompresses `frame` into `out` (cleared first), producing at most `out.capacity()` bytes:
/// a frame that would produce more is an error, so the capacity bounds the memory.
pub(crate) fn inflate_into(frame: &[u8], out: &mut Vec<u8>, offset: u64) -> Result<()> {
    thread_local! {
        /// One decompression context per thread, reused (blocks and chunks are decompressed
        /// by the thousand).
        static DCTX: std::cell::RefCell<Option<zstd::zstd_safe::DCtx<'static>>> = const { std::cell::RefCell::new(None) };
    }
    out.clear();
    let corrupt = |code: usize| Error::malformed(offset, format!("zstd data is corrupt: {}", zstd::zstd_safe::get_error_name(code)));
    DCTX.with(|cell| -> Result<()> {
        let mut cell = cell.borrow_mut();
        let dctx = match &mut *cell {
            Some(d) => d,
            slot => slot.insert(
                zstd::zstd_safe::DCtx::try_create().ok_or_else(|| Error::Io { path: None, source: std::io::ErrorKind::OutOfMemory.into() })?,
            ),
        };
        dctx.decompress(out, frame).map_err(corrupt)?;
        Ok(())
    })
}
