//! Reading the stored samples: the chunked `SMPS`/`SMPC` sections and the legacy `SMPL`
//! frame, checked against the limits before anything is inflated, decoded in parallel.

use super::*;

/// The samples as stored, after the section's CRC check.
pub(super) enum StoredSamples<'a> {
    /// `SMPL`: one section of columns (one zstd frame), decoded as it inflates.
    Legacy(Legacy<'a>),
    /// `SMPS` or `SMPC`: the chunks, walked and checked, the number of samples they hold and
    /// how a chunk lays out its samples.
    Chunks(Vec<Chunk<'a>>, u64, ChunkLayout),
}

impl StoredSamples<'_> {
    /// The number of samples the stored bytes declare.
    pub(super) fn count(&self) -> u64 {
        match self {
            StoredSamples::Legacy(l) => l.count,
            StoredSamples::Chunks(_, count, _) => *count,
        }
    }
}

/// A legacy `SMPL` section, located and sized but not inflated.
pub(super) struct Legacy<'a> {
    /// The stored bytes (one zstd frame when `compressed`).
    pub(super) stored: &'a [u8],
    pub(super) compressed: bool,
    /// Samples, from the section's raw length (`8 + 36 · count`).
    pub(super) count: u64,
    /// The section's offset, for errors.
    pub(super) offset: u64,
}

/// How a chunk's inflated 36 · n bytes hold its samples.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum ChunkLayout {
    /// `SMPS`: byte planes ([`put_planes`]).
    Planes,
    /// `SMPC`: columns, as `SMPL`.
    Columns,
}

/// One chunk: `n` samples whose bytes are the zstd frame `frame`.
pub(super) struct Chunk<'a> {
    pub(super) n: usize,
    pub(super) frame: &'a [u8],
    /// The frame's offset, for errors.
    pub(super) offset: u64,
}

/// The file's samples section: exactly one of `SMPS`, `SMPC` and `SMPL`.
pub(super) fn stored_samples<'a>(c: &Container<'a>, limits: &Limits) -> Result<StoredSamples<'a>> {
    let present: Vec<[u8; 4]> = [SMPS, SMPC, tags::SMPL].into_iter().filter(|&tag| c.sections.iter().any(|s| s.tag == tag)).collect();
    let at = c.header.section_table_offset;
    match present[..] {
        [tag] if tag == tags::SMPL => {
            let e = c.single(tags::SMPL)?;
            // The count follows from the raw length (8 + 36 per sample), so the limits are
            // checked before anything is inflated; the frame is then decoded as it inflates,
            // never held whole (a 4 GiB frame once took 9.8 GB: columns and samples).
            let count = e.raw_len.checked_sub(8).filter(|b| b % SAMPLE_BYTES as u64 == 0).map(|b| b / SAMPLE_BYTES as u64).ok_or_else(|| {
                Error::malformed(e.offset, format!("section SMPL of {} raw bytes is not a count and whole samples (8 + 36 per sample)", e.raw_len))
            })?;
            check_sample_totals(count, e.offset, limits)?;
            Limits::check("decompressed size", e.raw_len, limits.max_decompressed_bytes)?;
            c.verify(e)?;
            let stored = c.stored(e)?;
            if e.compressed() {
                check_frame(stored, e.raw_len, e.offset)?;
            }
            Ok(StoredSamples::Legacy(Legacy { stored, compressed: e.compressed(), count, offset: e.offset }))
        }
        [tag] => {
            let e = c.single(tag)?;
            let name = String::from_utf8_lossy(&tag).into_owned();
            if e.compressed() {
                return Err(Error::malformed(e.offset, format!("section {name} is zstd-flagged; its chunks are compressed, the section is not")));
            }
            c.verify(e)?;
            let chunks = walk_chunks(c.stored(e)?, e.offset, limits)?;
            let count = chunks.iter().map(|k| k.n as u64).sum();
            let layout = if tag == SMPS { ChunkLayout::Planes } else { ChunkLayout::Columns };
            Ok(StoredSamples::Chunks(chunks, count, layout))
        }
        [] => Err(Error::malformed(at, "required samples section SMPS (or SMPC or SMPL) is missing")),
        _ => {
            let names: Vec<_> = present.iter().map(|t| String::from_utf8_lossy(t).into_owned()).collect();
            Err(Error::malformed(at, format!("the file has more than one samples section: {}", names.join(", "))))
        }
    }
}

/// Walks the chunk headers of an `SMPS` or `SMPC` section (`bytes`, at `offset`): every count in
/// 1..=[`CHUNK_SAMPLES`], every frame inside the section and exactly one zstd frame long,
/// the totals within the limits. Nothing is allocated for the samples here; what is
/// (a few words a chunk) grows with the bytes walked.
pub(super) fn walk_chunks<'a>(bytes: &'a [u8], offset: u64, limits: &Limits) -> Result<Vec<Chunk<'a>>> {
    let mut cur = Cursor::new(bytes, offset);
    let mut chunks = Vec::new();
    let mut total = 0u64;
    while cur.remaining() > 0 {
        let at = cur.offset();
        let n = cur.u32("chunk sample count")?;
        if n == 0 || n as usize > CHUNK_SAMPLES {
            return Err(Error::malformed(at, format!("chunk sample count is {n}, must be 1 to {CHUNK_SAMPLES}")));
        }
        let len = cur.u32("chunk stored length")?;
        let frame_at = cur.offset();
        let frame = cur.take(len as usize, "chunk zstd frame")?;
        total = total.checked_add(u64::from(n)).ok_or_else(|| Error::malformed(at, "sample count overflows"))?;
        check_sample_totals(total, at, limits)?;
        check_frame(frame, n as u64 * SAMPLE_BYTES as u64, frame_at)?;
        chunks.push(Chunk { n: n as usize, frame, offset: frame_at });
    }
    Ok(chunks)
}

/// The limits on a samples file's sample count, checked from the headers before anything is
/// decoded: the count, its bytes as stored columns ([`Limits::max_decompressed_bytes`]) and
/// its decoded memory ([`Limits::max_sample_bytes`], 40 bytes a sample).
pub(super) fn check_sample_totals(count: u64, at: u64, limits: &Limits) -> Result<()> {
    Limits::check("sample count", count, limits.max_samples)?;
    let raw = count.checked_mul(SAMPLE_BYTES as u64).ok_or_else(|| Error::malformed(at, "sample bytes overflow"))?;
    Limits::check("decompressed size", raw, limits.max_decompressed_bytes)?;
    let decoded = count.checked_mul(std::mem::size_of::<Node>() as u64).ok_or_else(|| Error::malformed(at, "sample bytes overflow"))?;
    Limits::check("decoded sample bytes", decoded, limits.max_sample_bytes)
}

/// Cheap checks of a chunk's frame before anything is decompressed: exactly one frame, and
/// the content size its header may declare is the chunk's.
pub(super) fn check_frame(frame: &[u8], raw_len: u64, offset: u64) -> Result<()> {
    use zstd::zstd_safe::{find_frame_compressed_size, get_error_name, get_frame_content_size};
    match find_frame_compressed_size(frame) {
        Ok(len) if len == frame.len() => {}
        Ok(len) => return Err(Error::malformed(offset, format!("{} bytes follow the chunk's zstd frame", frame.len().saturating_sub(len)))),
        Err(code) => return Err(Error::malformed(offset, format!("chunk zstd frame is corrupt: {}", get_error_name(code)))),
    }
    if let Ok(Some(declared)) = get_frame_content_size(frame) {
        if declared != raw_len {
            return Err(Error::malformed(offset, format!("chunk zstd frame declares {declared} bytes, the chunk's columns are {raw_len}")));
        }
    }
    Ok(())
}

/// Chunks decoded per round. The samples' memory is taken a round at a time, so a file whose
/// frames do not inflate fails before the reader holds memory for every sample it claims.
pub(super) const DECODE_ROUND_CHUNKS: usize = 64;

/// Decodes the chunks (`total` samples) in parallel, each straight into its slice of the
/// samples; the first bad chunk (in file order) is the error.
pub(super) fn decode_chunks(chunks: &[Chunk<'_>], total: u64, layout: ChunkLayout) -> Result<Vec<Node>> {
    let mut samples: Vec<Node> = Vec::new();
    let total = usize::try_from(total).map_err(|_| Error::LimitExceeded { what: "sample count", value: total, limit: usize::MAX as u64 })?;
    for round in chunks.chunks(DECODE_ROUND_CHUNKS) {
        let start = samples.len();
        // Room a round at a time, doubling but never past the total (plain doubling could
        // reserve twice what the file holds).
        let want: usize = round.iter().map(|c| c.n).sum();
        if samples.capacity() - start < want {
            samples.reserve_exact(want.max(start).min(total.saturating_sub(start)).max(want));
        }
        samples.par_extend(rayon::iter::repeat_n(Node::default(), round.iter().map(|c| c.n).sum()));
        let mut outs = Vec::with_capacity(round.len());
        let mut rest = &mut samples[start..];
        for c in round {
            let k = c.n.min(rest.len());
            let (out, tail) = std::mem::take(&mut rest).split_at_mut(k);
            outs.push(out);
            rest = tail;
        }
        let errors: Vec<Error> = round
            .par_iter()
            .zip(outs)
            .map_init(Vec::new, |scratch, (c, out)| decode_chunk(c, layout, out, scratch).err())
            .flatten()
            .collect();
        if let Some(e) = errors.into_iter().next() {
            return Err(e);
        }
    }
    Ok(samples)
}

/// Inflates one chunk into `scratch` (at most its 36 · n bytes: the capacity bounds the
/// memory) and lays its planes or columns out as the samples `out`.
pub(super) fn decode_chunk(c: &Chunk<'_>, layout: ChunkLayout, out: &mut [Node], scratch: &mut Vec<u8>) -> Result<()> {
    let raw_len = c.n * SAMPLE_BYTES;
    scratch.clear();
    scratch.reserve_exact(raw_len);
    inflate_into(c.frame, scratch, c.offset)?;
    if scratch.len() != raw_len || out.len() != c.n {
        return Err(Error::malformed(c.offset, format!("chunk of {} samples inflates to {} bytes, {raw_len} expected", c.n, scratch.len())));
    }
    match layout {
        ChunkLayout::Planes => samples_from_planes(scratch, out),
        ChunkLayout::Columns => samples_from_columns(scratch, out),
    }
    Ok(())
}

/// The samples `out` from a chunk's columns (`bytes`, 36 · out.len()).
pub(super) fn samples_from_columns(bytes: &[u8], out: &mut [Node]) {
    let n = out.len();
    let (centers, rest) = bytes.split_at(12 * n);
    let (radii, rest) = rest.split_at(4 * n);
    let (normals, rest) = rest.split_at(12 * n);
    let (areas, colors) = rest.split_at(4 * n);
    let columns = centers.chunks_exact(12).zip(radii.chunks_exact(4)).zip(normals.chunks_exact(12)).zip(areas.chunks_exact(4)).zip(colors.chunks_exact(4));
    for (o, ((((c, r), nm), ar), co)) in out.iter_mut().zip(columns) {
        *o = node_from_columns(c, r, nm, ar, co);
    }
}

/// A sample from its bytes in the five columns.
#[inline]
pub(super) fn node_from_columns(c: &[u8], r: &[u8], nm: &[u8], ar: &[u8], co: &[u8]) -> Node {
    Node { center: f3(c), radius: f1(r), normal: f3(nm), cone: 0.0, area: f1(ar), color: [co[0], co[1], co[2], co[3]] }
}

/// Decodes a legacy `SMPL` section (files written before chunks): the count, then whole
/// columns, read as the frame inflates, a piece at a time, into the samples. Memory is the
/// samples (grown with the data produced, up to the count already checked against the
/// limits) and one piece: a frame that does not inflate as claimed fails before the reader
/// holds memory for samples it never produced.
pub(super) fn decode_legacy(l: &Legacy<'_>) -> Result<Vec<Node>> {
    use std::io::Read;
    let corrupt = |e: std::io::Error| Error::malformed(l.offset, format!("SMPL: {e}"));
    let mut input: Box<dyn Read + '_> = if l.compressed {
        Box::new(zstd::stream::read::Decoder::with_buffer(l.stored).map_err(corrupt)?.single_frame())
    } else {
        Box::new(l.stored)
    };
    let mut head = [0u8; 8];
    input.read_exact(&mut head).map_err(corrupt)?;
    let n = u64::from_le_bytes(head);
    if n != l.count {
        return Err(Error::malformed(l.offset, format!("SMPL holds {n} samples by its count, {} by its length", l.count)));
    }
    let n = usize::try_from(n).map_err(|_| Error::LimitExceeded { what: "sample count", value: n, limit: usize::MAX as u64 })?;
    let mut out: Vec<Node> = Vec::new();
    // A multiple of every field's size (12 and 4), so a piece never splits a value.
    let mut buf = vec![0u8; 48 << 10];
    /// Sets a field of sample `i` from its bytes.
    type Set<'s> = &'s mut dyn FnMut(&mut Vec<Node>, usize, &[u8]);
    let mut column = |width: usize, out: &mut Vec<Node>, set: Set<'_>| -> Result<()> {
        let mut i = 0usize;
        let mut left = n * width;
        while left > 0 {
            let k = left.min(buf.len());
            input.read_exact(&mut buf[..k]).map_err(corrupt)?;
            for v in buf[..k].chunks_exact(width) {
                set(out, i, v);
                i += 1;
            }
            left -= k;
        }
        Ok(())
    };
    column(12, &mut out, &mut |out, _, c| {
        if out.len() == out.capacity() {
            // Doubling, but never past the count.
            out.reserve_exact(out.len().max(4096).min(n - out.len()));
        }
        out.push(Node { center: f3(c), radius: 0.0, normal: [0.0; 3], cone: 0.0, area: 0.0, color: [0; 4] });
    })?;
    column(4, &mut out, &mut |out, i, r| out[i].radius = f1(r))?;
    column(12, &mut out, &mut |out, i, v| out[i].normal = f3(v))?;
    column(4, &mut out, &mut |out, i, a| out[i].area = f1(a))?;
    column(4, &mut out, &mut |out, i, c| out[i].color = [c[0], c[1], c[2], c[3]])?;
    let mut more = [0u8; 1];
    match input.read(&mut more) {
        Ok(0) => Ok(out),
        Ok(_) => Err(Error::malformed(l.offset, format!("SMPL inflates to more than {} bytes", 8 + SAMPLE_BYTES * n))),
        Err(e) => Err(corrupt(e)),
    }
}

/// One little-endian f32 from a 4-byte chunk.
#[inline]
pub(super) fn f1(b: &[u8]) -> f32 {
    f32::from_le_bytes([b[0], b[1], b[2], b[3]])
}

/// Three little-endian f32 from a 12-byte chunk.
#[inline]
pub(super) fn f3(b: &[u8]) -> [f32; 3] {
    [f1(&b[0..4]), f1(&b[4..8]), f1(&b[8..12])]
}
