//! Building hostile SCT and samples files byte by byte, with valid checksums, so that a
//! reader must catch problems by their meaning. Shared by the tests and (through `#[path]`)
//! by the structure-aware fuzz target, which mutates what these build and then calls
//! [`fix_crcs`].
#![allow(dead_code)]

use sct_format::raw::{BlockEntry, FileHeader, LevelEntry, SectionEntry, TreeHeader, BLOCK_ENTRY_LEN, FILE_HEADER_LEN, LEVEL_ENTRY_LEN, SECTION_ENTRY_LEN, TREE_HEADER_LEN};
use sct_format::{Node, Similarity};

/// One section of a crafted container.
#[derive(Clone, Debug)]
pub struct Sec {
    pub tag: [u8; 4],
    pub flags: u32,
    /// Where the stored bytes are: `None` lays them out after the previous section's; `Some`
    /// points the entry at bytes already placed (aliasing) and stores nothing.
    pub at: Option<u64>,
    pub stored: Vec<u8>,
    pub raw_len: u64,
}

impl Sec {
    /// Stored as is, flagged required.
    pub fn plain(tag: [u8; 4], data: Vec<u8>) -> Sec {
        Sec { tag, flags: SectionEntry::REQUIRED, at: None, raw_len: data.len() as u64, stored: data }
    }

    /// One zstd frame of `data` (level 1), flagged required and zstd.
    pub fn zstd(tag: [u8; 4], data: &[u8]) -> Sec {
        let stored = zstd::bulk::compress(data, 1).expect("compress");
        Sec::frame(tag, stored, data.len() as u64)
    }

    /// The given stored bytes (a frame, possibly hostile) claiming `raw_len`.
    pub fn frame(tag: [u8; 4], stored: Vec<u8>, raw_len: u64) -> Sec {
        Sec { tag, flags: SectionEntry::REQUIRED | SectionEntry::ZSTD, at: None, stored, raw_len }
    }

    /// An entry for `len` bytes at `at` that are already in the file (aliasing them).
    pub fn alias(tag: [u8; 4], at: u64, len: u64, flags: u32) -> Sec {
        Sec { tag, flags, at: Some(at), stored: vec![0; len as usize], raw_len: len }
    }
}

/// A container: header, section table at 64, then the sections' stored bytes in order (or at
/// their `at`), every CRC and the length computed.
pub fn container(magic: [u8; 8], secs: &[Sec]) -> Vec<u8> {
    let table_at = FILE_HEADER_LEN as u64;
    let mut data_at = table_at + (secs.len() * SECTION_ENTRY_LEN) as u64;
    let mut body = Vec::new();
    let mut entries = Vec::new();
    for s in secs {
        let (offset, len) = match s.at {
            Some(a) => (a, s.stored.len() as u64),
            None => {
                let o = data_at;
                body.extend_from_slice(&s.stored);
                data_at += s.stored.len() as u64;
                (o, s.stored.len() as u64)
            }
        };
        entries.push(SectionEntry { tag: s.tag, flags: s.flags, offset, stored_len: len, raw_len: s.raw_len, crc: 0 });
    }
    let mut table = Vec::new();
    entries.iter().for_each(|e| e.write(&mut table));
    let mut out = vec![0u8; FILE_HEADER_LEN];
    out.extend_from_slice(&table);
    out.extend_from_slice(&body);
    let header = FileHeader {
        magic,
        major: 1,
        minor: 0,
        flags: 0,
        section_count: secs.len() as u32,
        section_table_offset: table_at,
        file_length: out.len() as u64,
        table_crc: 0,
        header_crc: 0,
    };
    let mut h = Vec::new();
    header.write(&mut h);
    out[..FILE_HEADER_LEN].copy_from_slice(&h);
    fix_crcs(&mut out);
    out
}

fn get<const N: usize>(b: &[u8], at: u64) -> Option<[u8; N]> {
    let at = usize::try_from(at).ok()?;
    b.get(at..at.checked_add(N)?)?.try_into().ok()
}
fn u32_at(b: &[u8], at: u64) -> Option<u32> {
    get::<4>(b, at).map(u32::from_le_bytes)
}
fn u64_at(b: &[u8], at: u64) -> Option<u64> {
    get::<8>(b, at).map(u64::from_le_bytes)
}
fn put(b: &mut [u8], at: u64, v: &[u8]) {
    if let Some(s) = usize::try_from(at).ok().and_then(|a| b.get_mut(a..a.checked_add(v.len())?)) {
        s.copy_from_slice(v);
    }
}
fn range(b: &[u8], at: u64, len: u64) -> Option<&[u8]> {
    let at = usize::try_from(at).ok()?;
    b.get(at..at.checked_add(usize::try_from(len).ok()?)?)
}

/// Sets the header's file length to the file's.
pub fn fix_length(b: &mut [u8]) {
    let n = b.len() as u64;
    put(b, 32, &n.to_le_bytes());
}

/// Recomputes every checksum of a (possibly mutated) SCT or samples file: the block CRCs of
/// every `TREE` section, every section's CRC, the table CRC and the header CRC. Entries that
/// point outside the file are left as they are.
pub fn fix_crcs(b: &mut [u8]) {
    let (Some(count), Some(table)) = (u32_at(b, 16), u64_at(b, 24)) else { return };
    let count = count.min(1 << 16) as u64;
    for i in 0..count {
        let e = table + i * SECTION_ENTRY_LEN as u64;
        let (Some(tag), Some(off), Some(len)) = (get::<4>(b, e), u64_at(b, e + 8), u64_at(b, e + 16)) else { break };
        if &tag == b"TREE" {
            fix_block_crcs(b, off, len);
        }
        if let Some(s) = range(b, off, len) {
            let c = crc32fast::hash(s);
            put(b, e + 32, &c.to_le_bytes());
        }
    }
    if let Some(t) = range(b, table, count * SECTION_ENTRY_LEN as u64) {
        let c = crc32fast::hash(t);
        put(b, 40, &c.to_le_bytes());
    }
    if b.len() >= FILE_HEADER_LEN {
        let c = crc32fast::hash(&b[..60]);
        put(b, 60, &c.to_le_bytes());
    }
}

/// The block CRCs of the tree section at `off` (`len` bytes).
fn fix_block_crcs(b: &mut [u8], off: u64, len: u64) {
    let (Some(levels), Some(blocks)) = (u32_at(b, off + 4), u32_at(b, off + 24)) else { return };
    let table = off + TREE_HEADER_LEN as u64 + levels as u64 * LEVEL_ENTRY_LEN as u64;
    for k in 0..(blocks as u64).min(1 << 20) {
        let e = table + k * BLOCK_ENTRY_LEN as u64;
        let (Some(boff), Some(blen)) = (u64_at(b, e + 24), u32_at(b, e + 32)) else { break };
        if boff.checked_add(blen as u64).is_none_or(|end| end > len) {
            continue;
        }
        if let Some(s) = range(b, off + boff, blen as u64) {
            let c = crc32fast::hash(s);
            put(b, e + 40, &c.to_le_bytes());
        }
    }
}

/// A `TREE` section: `header` (its level and block counts as given), the tables, then
/// `data` (the stored blocks; block entries' offsets are relative to the section, so the
/// first block usually sits at [`index_len`]). Block CRCs are filled in by [`fix_crcs`].
pub fn tree_section(header: &TreeHeader, levels: &[LevelEntry], blocks: &[BlockEntry], data: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    header.write(&mut out);
    levels.iter().for_each(|l| l.write(&mut out));
    blocks.iter().for_each(|bl| bl.write(&mut out));
    out.extend_from_slice(data);
    out
}

/// Bytes before a tree section's block data.
pub fn index_len(levels: usize, blocks: usize) -> u64 {
    (TREE_HEADER_LEN + levels * LEVEL_ENTRY_LEN + blocks * BLOCK_ENTRY_LEN) as u64
}

/// A scene-graph record (spec §7).
#[derive(Clone, Debug)]
pub enum G {
    Tree(u32),
    Group(u32, Vec<u32>),
    /// child, transform, flags, tint
    Instance(u32, Similarity, u8, [u8; 4]),
    /// child, row-major 3 × 4 matrix, flags, tint (format 1.3)
    Affine(u32, [[f64; 4]; 3], u8, [u8; 4]),
    Inline(String, [u8; 32], Node),
}

/// The raw node record (spec §5).
pub fn node_bytes(n: &Node, out: &mut Vec<u8>) {
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

/// A `GRPH` section's bytes (uncompressed).
pub fn graph_bytes(nodes: &[G], root: u32) -> Vec<u8> {
    let mut out = Vec::new();
    out.extend_from_slice(&(nodes.len() as u64).to_le_bytes());
    out.extend_from_slice(&root.to_le_bytes());
    for n in nodes {
        match n {
            G::Tree(t) => {
                out.push(0);
                out.extend_from_slice(&t.to_le_bytes());
            }
            G::Group(t, children) => {
                out.push(1);
                out.extend_from_slice(&t.to_le_bytes());
                out.extend_from_slice(&(children.len() as u64).to_le_bytes());
                children.iter().for_each(|c| out.extend_from_slice(&c.to_le_bytes()));
            }
            G::Instance(c, t, flags, tint) => {
                out.push(2);
                out.extend_from_slice(&c.to_le_bytes());
                for v in t.translation.iter().chain(&t.rotation) {
                    out.extend_from_slice(&v.to_le_bytes());
                }
                out.extend_from_slice(&t.scale.to_le_bytes());
                out.push(*flags);
                out.extend_from_slice(tint);
            }
            G::Affine(c, m, flags, tint) => {
                out.push(4);
                out.extend_from_slice(&c.to_le_bytes());
                m.iter().flatten().for_each(|v| out.extend_from_slice(&v.to_le_bytes()));
                out.push(*flags);
                out.extend_from_slice(tint);
            }
            G::Inline(path, hash, bound) => {
                out.push(3);
                out.extend_from_slice(&(path.len() as u32).to_le_bytes());
                out.extend_from_slice(path.as_bytes());
                out.extend_from_slice(hash);
                node_bytes(bound, &mut out);
            }
        }
    }
    out
}

/// A generator section's JSON.
pub fn genr() -> Vec<u8> {
    br#"{"tool":"craft","version":"0"}"#.to_vec()
}

/// Most bytes one zstd block may regenerate.
const ZSTD_BLOCK: u64 = 128 << 10;

fn zstd_header(content_size: u64) -> Vec<u8> {
    let mut f = vec![0x28, 0xB5, 0x2F, 0xFD];
    // Frame header descriptor: 8-byte content size, not single-segment, no checksum, no
    // dictionary; window descriptor 2^17 (every block's maximum).
    f.push(0xC0);
    f.push(7 << 3);
    f.extend_from_slice(&content_size.to_le_bytes());
    f
}

fn block_header(out: &mut Vec<u8>, kind: u32, size: u32, last: bool) {
    let h = size << 3 | kind << 1 | last as u32;
    out.extend_from_slice(&h.to_le_bytes()[..3]);
}

/// One zstd frame that inflates to `prefix` then `fill` repeated up to `total` bytes, made of
/// raw and RLE blocks: about 4 bytes per 128 KiB, so a 4 GiB frame takes 131 KB. Its header
/// declares the content size (as a real zstd bomb's would).
pub fn rle_frame(prefix: &[u8], fill: u8, total: u64) -> Vec<u8> {
    assert!(prefix.len() as u64 <= total);
    let mut f = zstd_header(total);
    let mut left = total;
    if total == 0 {
        block_header(&mut f, 0, 0, true);
        return f;
    }
    for piece in prefix.chunks(ZSTD_BLOCK as usize) {
        left -= piece.len() as u64;
        block_header(&mut f, 0, piece.len() as u32, left == 0);
        f.extend_from_slice(piece);
    }
    while left > 0 {
        let n = left.min(ZSTD_BLOCK);
        left -= n;
        block_header(&mut f, 1, n as u32, left == 0);
        f.push(fill);
    }
    f
}

/// A frame whose header and block structure are well formed (its length can be found
/// without decoding) but whose one compressed block is garbage: it fails only when inflated.
pub fn corrupt_frame(content_size: u64) -> Vec<u8> {
    let mut f = zstd_header(content_size);
    block_header(&mut f, 2, 16, true);
    f.extend_from_slice(&[0xFF; 16]);
    f
}
