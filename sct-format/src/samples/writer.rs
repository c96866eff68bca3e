//! Writing a samples file as the samples come: chunks compressed in batches on every
//! thread, in byte planes.

use super::*;

/// Chunks compressed together by [`SamplesWriter`]: enough to keep the threads busy; it
/// buffers fewer samples than this many chunks hold (42 MB).
pub(super) const BATCH_CHUNKS: usize = 16;

/// Writes a samples file as the samples come (spec §8): the `SMPS` section straight after the
/// header, chunk by chunk; at [`SamplesWriter::finish`] the tables, the section table and,
/// seeking back, the header. The same bytes as [`SamplesFile::write_to`] for the same
/// content, however the samples were split into pushes and on any number of threads.
///
/// ```
/// use sct_format::samples::{MeshEntry, SampleInstance, SamplesFile, SamplesWriter};
/// use sct_format::{Generator, Limits, Node, Similarity};
///
/// let mut out = std::io::Cursor::new(Vec::new());
/// let mut w = SamplesWriter::new(&mut out)?;
/// for batch in 0..3 {
///     w.push(&vec![Node { radius: 0.1, area: 0.01, ..Node::default() }; 1000 + batch])?;
/// }
/// let meshes = [MeshEntry { name: "m".into(), first: 0, count: w.samples_written(), two_sided: false }];
/// let instances = [SampleInstance { mesh: 0, transform: Similarity::IDENTITY }];
/// w.finish(&Generator::default(), &meshes, &instances, &[])?;
/// let file = SamplesFile::read(out.get_ref(), &Limits::default())?;
/// assert_eq!(file.samples.len(), 3003);
/// # Ok::<(), sct_format::Error>(())
/// ```
pub struct SamplesWriter<W: Write + Seek> {
    w: W,
    /// Stream position of the file's first byte.
    start: u64,
    /// Pushed samples not yet in a chunk; fewer than a batch, and they start a chunk.
    pending: Vec<Node>,
    /// Samples in the chunks written.
    written: u64,
    /// Bytes of the `SMPS` section written.
    section_len: u64,
    /// CRC-32 of those bytes.
    crc: crc32fast::Hasher,
}

impl<W: Write + Seek> SamplesWriter<W> {
    /// Starts a samples file at `w`'s current position (the header is reserved, filled in by
    /// [`Self::finish`]).
    pub fn new(mut w: W) -> Result<Self> {
        let start = w.stream_position()?;
        w.write_all(&[0u8; FILE_HEADER_LEN])?;
        Ok(SamplesWriter { w, start, pending: Vec::new(), written: 0, section_len: 0, crc: crc32fast::Hasher::new() })
    }

    /// Appends samples, in order. Whole chunks are compressed (in parallel, a batch at a
    /// time) and written; what is left of a chunk, or fewer whole chunks from small pushes
    /// than there are threads (at most 16, 42 MB), stays buffered until more come or
    /// [`Self::finish`]. Compressing as soon as every thread has a chunk lets a producer
    /// that pushes while its other threads work (the sampler) overlap the two, rather than
    /// leave the whole file's compression to the end when it is smaller than 16 chunks.
    pub fn push(&mut self, samples: &[Node]) -> Result<()> {
        let flush_at = rayon::current_num_threads().clamp(1, BATCH_CHUNKS) * CHUNK_SAMPLES;
        let mut rest = samples;
        if !self.pending.is_empty() {
            let take = rest.len().min(flush_at.saturating_sub(self.pending.len()));
            self.pending.extend_from_slice(&rest[..take]);
            rest = &rest[take..];
            if self.pending.len() < flush_at {
                return Ok(());
            }
            let pending = std::mem::take(&mut self.pending);
            self.write_chunks(&pending)?;
            self.pending = pending;
            self.pending.clear();
        }
        // Whole chunks straight from the caller's slice: no copy for large pushes.
        let whole = rest.len() / CHUNK_SAMPLES * CHUNK_SAMPLES;
        self.write_chunks(&rest[..whole])?;
        self.pending.extend_from_slice(&rest[whole..]);
        Ok(())
    }

    /// Samples pushed so far.
    pub fn samples_written(&self) -> u64 {
        self.written + self.pending.len() as u64
    }

    /// Writes the last chunk, the tables (`AFFI` only when `affine` is not empty), the section
    /// table and the header; returns the file's length. The tables must describe the samples
    /// pushed, as [`SamplesFile::check`] requires (else [`Error::Misuse`], and the file is
    /// not finished).
    pub fn finish(self, generator: &Generator, meshes: &[MeshEntry], instances: &[SampleInstance], affine: &[AffineInstance]) -> Result<u64> {
        check_tables_for_writer(meshes, instances, affine, self.samples_written())?;
        self.finish_unchecked(generator, meshes, instances, affine)
    }

    /// [`Self::finish`] without the table checks (tests write files the reader must refuse).
    pub(super) fn finish_unchecked(mut self, generator: &Generator, meshes: &[MeshEntry], instances: &[SampleInstance], affine: &[AffineInstance]) -> Result<u64> {
        let last = std::mem::take(&mut self.pending);
        self.write_chunks(&last)?;
        let (tables, extra) = table_sections(generator, meshes, instances, affine)?;
        let samples = SectionEntry {
            tag: SMPS,
            flags: SectionEntry::REQUIRED,
            offset: FILE_HEADER_LEN as u64,
            stored_len: self.section_len,
            raw_len: self.section_len,
            crc: self.crc.clone().finalize(),
        };
        let mut offset = FILE_HEADER_LEN as u64 + self.section_len;
        let mut entries = Vec::with_capacity(5);
        for s in tables.iter().chain(extra.iter()) {
            self.w.write_all(&s.stored)?;
            entries.push(s.entry(offset));
            offset += s.stored.len() as u64;
        }
        // Table order: GENR first (readers require it), the samples after the tables that
        // index them, AFFI and SIDE last (as before chunks).
        entries.insert(tables.len(), samples);
        let (header, table) = header_and_table_at(SAMPLES_MAGIC, 0, &entries, offset, offset + (entries.len() * SECTION_ENTRY_LEN) as u64);
        self.w.write_all(&table)?;
        let length = offset + table.len() as u64;
        self.w.seek(SeekFrom::Start(self.start))?;
        self.w.write_all(&header)?;
        self.w.seek(SeekFrom::Start(self.start + length))?;
        Ok(length)
    }

    /// Compresses `samples` as chunks of [`CHUNK_SAMPLES`] (the last may be short), a batch
    /// at a time in parallel, and writes them in order.
    fn write_chunks(&mut self, samples: &[Node]) -> Result<()> {
        for batch in samples.chunks(BATCH_CHUNKS * CHUNK_SAMPLES) {
            let chunks = batch.par_chunks(CHUNK_SAMPLES).map(compress_chunk).collect::<Result<Vec<_>>>()?;
            for c in chunks {
                self.w.write_all(&c.header)?;
                self.w.write_all(&c.frame)?;
                self.crc.combine(&c.crc);
                self.section_len += (CHUNK_HEADER_BYTES + c.frame.len()) as u64;
            }
            self.written += batch.len() as u64;
        }
        Ok(())
    }
}

/// One compressed chunk: header, frame and the CRC-32 of both (combined into the section's
/// in order, so no thread waits to hash).
pub(super) struct CompressedChunk {
    pub(super) header: [u8; CHUNK_HEADER_BYTES],
    pub(super) frame: Vec<u8>,
    pub(super) crc: crc32fast::Hasher,
}

pub(super) fn compress_chunk(samples: &[Node]) -> Result<CompressedChunk> {
    thread_local! {
        /// Plane scratch and compression context, reused chunk after chunk.
        static SCRATCH: std::cell::RefCell<(Vec<u8>, Option<zstd::bulk::Compressor<'static>>)> = const { std::cell::RefCell::new((Vec::new(), None)) };
    }
    let frame = SCRATCH.with(|cell| -> Result<Vec<u8>> {
        let mut cell = cell.borrow_mut();
        let (columns, compressor) = &mut *cell;
        put_planes(samples, columns);
        let compressor = match compressor {
            Some(c) => c,
            slot => slot.insert(zstd::bulk::Compressor::new(ZSTD_LEVEL)?),
        };
        Ok(compressor.compress(columns)?)
    })?;
    let n = u32::try_from(samples.len()).map_err(|_| Error::Misuse("chunk too large (bug)".into()))?;
    let len = u32::try_from(frame.len()).map_err(|_| Error::Misuse("compressed chunk too large (bug)".into()))?;
    let mut header = [0u8; CHUNK_HEADER_BYTES];
    header[..4].copy_from_slice(&n.to_le_bytes());
    header[4..].copy_from_slice(&len.to_le_bytes());
    let mut crc = crc32fast::Hasher::new();
    crc.update(&header);
    crc.update(&frame);
    Ok(CompressedChunk { header, frame, crc })
}

/// Samples per tile of the byte-plane transforms: a tile of samples (40 KB) and its slices of
/// the 36 planes stay in cache while the planes are filled or read one field at a time.
pub(super) const PLANE_TILE: usize = 1024;

/// The byte-plane layout of a chunk's `samples` (spec §8, `SMPS`), replacing `out`: byte k of
/// every sample's 36-byte record is plane k (n bytes), each centre coordinate's bits stored as
/// the wrapping difference from the previous sample's (voxel samples come sorted, so the
/// planes hold runs zstd finds cheaply).
pub(super) fn put_planes(samples: &[Node], out: &mut Vec<u8>) {
    let n = samples.len();
    // Every byte is written below, so a reused buffer of the right length is not cleared.
    out.resize(n * SAMPLE_BYTES, 0);
    let mut prev = [0u32; 3];
    for (t, tile) in samples.chunks(PLANE_TILE).enumerate() {
        let at = t * PLANE_TILE;
        let mut planes = out.chunks_exact_mut(n).map(|p| p.get_mut(at..).unwrap_or_default());
        let mut quad = || std::array::from_fn(|_| planes.next().unwrap_or_default());
        for (c, prev) in prev.iter_mut().enumerate() {
            scatter(tile, quad(), |s| {
                let bits = s.center[c].to_bits();
                let delta = bits.wrapping_sub(*prev);
                *prev = bits;
                delta.to_le_bytes()
            });
        }
        scatter(tile, quad(), |s| s.radius.to_le_bytes());
        for c in 0..3 {
            scatter(tile, quad(), |s| s.normal[c].to_le_bytes());
        }
        scatter(tile, quad(), |s| s.area.to_le_bytes());
        scatter(tile, quad(), |s| s.color);
    }
}

/// Byte k of `bytes_of(s)` for the i-th sample s of `tile` into `planes[k][i]`.
#[inline]
pub(super) fn scatter(tile: &[Node], [p0, p1, p2, p3]: [&mut [u8]; 4], mut bytes_of: impl FnMut(&Node) -> [u8; 4]) {
    let planes = p0.iter_mut().zip(p1.iter_mut()).zip(p2.iter_mut()).zip(p3.iter_mut());
    for (s, (((b0, b1), b2), b3)) in tile.iter().zip(planes) {
        [*b0, *b1, *b2, *b3] = bytes_of(s);
    }
}

/// The inverse of [`put_planes`]: the samples `out` from a chunk's `bytes` (36 · out.len()).
pub(super) fn samples_from_planes(bytes: &[u8], out: &mut [Node]) {
    let n = out.len();
    let mut prev = [0u32; 3];
    for (t, tile) in out.chunks_mut(PLANE_TILE).enumerate() {
        let at = t * PLANE_TILE;
        let mut planes = bytes.chunks_exact(n).map(|p| p.get(at..).unwrap_or_default());
        let mut quad = || std::array::from_fn(|_| planes.next().unwrap_or_default());
        for (c, prev) in prev.iter_mut().enumerate() {
            gather(tile, quad(), |o, b| {
                *prev = prev.wrapping_add(u32::from_le_bytes(b));
                o.center[c] = f32::from_bits(*prev);
            });
        }
        gather(tile, quad(), |o, b| o.radius = f32::from_le_bytes(b));
        for c in 0..3 {
            gather(tile, quad(), |o, b| o.normal[c] = f32::from_le_bytes(b));
        }
        gather(tile, quad(), |o, b| o.area = f32::from_le_bytes(b));
        gather(tile, quad(), |o, b| o.color = b);
    }
}

/// `set(o, [planes[0][i], …, planes[3][i]])` for the i-th sample o of `tile`.
#[inline]
pub(super) fn gather(tile: &mut [Node], [p0, p1, p2, p3]: [&[u8]; 4], mut set: impl FnMut(&mut Node, [u8; 4])) {
    let planes = p0.iter().zip(p1).zip(p2).zip(p3);
    for (o, (((b0, b1), b2), b3)) in tile.iter_mut().zip(planes) {
        set(o, [*b0, *b1, *b2, *b3]);
    }
}

/// The column layout of `samples` (centres, radii, normals, areas, colours), appended: what
/// `SMPL` and `SMPC` hold (test-only: writers write `SMPS`).
#[cfg(test)]
pub(super) fn put_columns(samples: &[Node], out: &mut Vec<u8>) {
    out.reserve(samples.len() * SAMPLE_BYTES);
    samples.iter().for_each(|s| s.center.iter().for_each(|v| out.extend_from_slice(&v.to_le_bytes())));
    samples.iter().for_each(|s| out.extend_from_slice(&s.radius.to_le_bytes()));
    samples.iter().for_each(|s| s.normal.iter().for_each(|v| out.extend_from_slice(&v.to_le_bytes())));
    samples.iter().for_each(|s| out.extend_from_slice(&s.area.to_le_bytes()));
    samples.iter().for_each(|s| out.extend_from_slice(&s.color));
}
