//! The samples file (spec §8): what `sct-voxelize` writes and `sct-build-tree` reads.
//!
//! Samples are grouped by mesh (contiguous ranges); the scene is every instance's mesh
//! placed by its similarity transform, so a mesh used by many glTF nodes is sampled once.
//! Sections: `GENR` (provenance JSON), `MESH` (mesh table), `INST` (instances), `SMPS`
//! (samples in chunks of [`CHUNK_SAMPLES`], each chunk's samples one zstd frame of byte
//! planes; older files have `SMPC`, the same chunks holding columns, or `SMPL`, all columns
//! one frame, and both still read) and, only when some placement is not a similarity,
//! `AFFI` (affine instances, flagged required so that a reader that predates it refuses the
//! file instead of silently dropping those placements).
//!
//! Chunks let [`SamplesWriter`] write samples as they come (nothing holds them all) and let
//! both sides compress and decompress on every thread; the tables, known last, follow the
//! samples, and the section table ends the file.

use std::io::{Seek, SeekFrom, Write};
use std::path::Path;

use rayon::prelude::*;

use crate::container::{header_and_table_at, inflate_into, Container, SectionOut};
use crate::error::{Error, Result};
use crate::graph::{Generator, Similarity};
use crate::limits::Limits;
use crate::node::Node;
use crate::raw::{cursor::Put, tags, Cursor, SectionEntry, FILE_HEADER_LEN, SAMPLES_MAGIC, SECTION_ENTRY_LEN};

/// Bytes per sample in the column layout (centre 12, radius 4, normal 12, area 4, RGBA 4).
pub const SAMPLE_BYTES: usize = 36;
/// Section tag of the chunked samples as columns (spec §8), which writers wrote before
/// [`SMPS`] (and which still read).
pub const SMPC: [u8; 4] = *b"SMPC";
/// Section tag of the chunked samples as byte planes (spec §8), which writers write: the
/// chunks of `SMPC` with each chunk's samples split into 36 byte planes and centres stored as
/// differences. On voxel samples (bunny, spot) zstd level 1 makes them 22–31 % smaller than
/// columns with about 38 % fewer instructions, and inflates them with about 55 % fewer.
pub const SMPS: [u8; 4] = *b"SMPS";
/// Most samples in one `SMPC` chunk; writers cut chunks of exactly this many but the last,
/// so the bytes depend neither on the thread count nor on how samples were pushed. 2.4 MB
/// of columns: big enough for zstd's ratio, small enough for 36 chunks on the bunny.
pub const CHUNK_SAMPLES: usize = 1 << 16;
/// Bytes of a chunk header: sample count u32, stored length u32.
const CHUNK_HEADER_BYTES: usize = 8;
const MESH_ENTRY_MIN: usize = 20;
const INST_ENTRY_BYTES: usize = 68;
const AFFI_ENTRY_BYTES: usize = 100;
/// Section tag of the affine instances (spec §8); local to the samples file.
pub const AFFI: [u8; 4] = *b"AFFI";
/// Section tag of the two-sided mesh list (spec §8, optional); local to the samples file.
pub const SIDE: [u8; 4] = *b"SIDE";
/// zstd level of the samples file's sections. The file is an intermediate between the
/// toolchain's own tools, so speed wins: level 1 writes the bunny's 2.34 M samples in 0.24 s
/// instead of level 3's 0.35 s for a 2.6 % larger file, and reads as fast. (On byte planes,
/// negative levels save a little more time but lose the literals' Huffman coding: 3 % larger.)
const ZSTD_LEVEL: i32 = 1;

/// One mesh's samples: `samples[first .. first + count]`.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct MeshEntry {
    /// Mesh name (from the source file, may be empty).
    pub name: String,
    /// First sample.
    pub first: u64,
    /// Number of samples.
    pub count: u64,
    /// The mesh's surfaces are seen from both sides (glTF `doubleSided`, open or
    /// inconsistently oriented meshes, point clouds without normals): stored in the optional
    /// `SIDE` section (spec §8); its trees are built two-sided (spec §6.2).
    pub two_sided: bool,
}

/// One placement of a mesh.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SampleInstance {
    /// Index into [`SamplesFile::meshes`].
    pub mesh: u32,
    /// Mesh space to world space.
    pub transform: Similarity,
}

/// One placement of a mesh by a general (invertible) affine map: non-uniform scale, shear or
/// mirror, which a scene-tree instance (a similarity) cannot express. A consumer bakes the
/// mesh's samples through it ([`AffineInstance::transform_node`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AffineInstance {
    /// Index into [`SamplesFile::meshes`].
    pub mesh: u32,
    /// Row-major 3 × 4 matrix: `world[r] = Σc m[r][c]·p[c] + m[r][3]`.
    pub matrix: [[f64; 4]; 3],
}

impl AffineInstance {
    /// Applies the map to a point.
    pub fn apply_point(&self, p: [f64; 3]) -> [f64; 3] {
        let m = &self.matrix;
        std::array::from_fn(|r| m[r][0] * p[0] + m[r][1] * p[1] + m[r][2] * p[2] + m[r][3])
    }

    /// Determinant of the linear part.
    pub fn determinant(&self) -> f64 {
        let m = &self.matrix;
        m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
    }

    /// Finite entries and an invertible linear part (what the reader requires).
    pub fn is_valid(&self) -> bool {
        self.matrix.iter().flatten().all(|v| v.is_finite()) && self.determinant().is_normal()
    }

    /// The largest singular value of the linear part: the most it stretches any length, so a
    /// sphere of radius r maps into a sphere of radius r × this around the mapped centre.
    pub fn max_stretch(&self) -> f64 {
        let m = &self.matrix;
        // Largest eigenvalue of the symmetric AᵀA (closed form for 3 × 3, Smith 1961).
        let a: [[f64; 3]; 3] = std::array::from_fn(|i| std::array::from_fn(|j| (0..3).map(|k| m[k][i] * m[k][j]).sum()));
        let p1 = a[0][1] * a[0][1] + a[0][2] * a[0][2] + a[1][2] * a[1][2];
        let q = (a[0][0] + a[1][1] + a[2][2]) / 3.0;
        let p2 = (a[0][0] - q).powi(2) + (a[1][1] - q).powi(2) + (a[2][2] - q).powi(2) + 2.0 * p1;
        let p = (p2 / 6.0).sqrt();
        let lambda = if p == 0.0 {
            q
        } else {
            let b: [[f64; 3]; 3] = std::array::from_fn(|i| std::array::from_fn(|j| (a[i][j] - if i == j { q } else { 0.0 }) / p));
            let det_b = b[0][0] * (b[1][1] * b[2][2] - b[1][2] * b[2][1]) - b[0][1] * (b[1][0] * b[2][2] - b[1][2] * b[2][0])
                + b[0][2] * (b[1][0] * b[2][1] - b[1][1] * b[2][0]);
            let phi = (det_b / 2.0).clamp(-1.0, 1.0).acos() / 3.0;
            q + 2.0 * p * phi.cos()
        };
        // The closed form can land a few ulps low; the Frobenius norm is a hard upper bound.
        let frob = a[0][0] + a[1][1] + a[2][2];
        (lambda * (1.0 + 1e-12)).min(frob).max(0.0).sqrt()
    }

    /// Bakes one sample through the map: centre mapped; radius × [`Self::max_stretch`]
    /// (containment stays conservative); normal by the inverse transpose; area × |det| ×
    /// |A⁻ᵀ n| (Nanson's formula for a surface element); colour unchanged. `stretch` is
    /// [`Self::max_stretch`], passed in so it is computed once per instance.
    pub fn transform_node(&self, n: &Node, stretch: f64) -> Node {
        let m = &self.matrix;
        let det = self.determinant();
        let col = |c: usize| [m[0][c], m[1][c], m[2][c]];
        let cross = |a: [f64; 3], b: [f64; 3]| [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
        // Rows of A⁻¹ are (c1×c2, c2×c0, c0×c1)/det, so A⁻ᵀ n = Σ n_i (row i of A⁻¹).
        let (r0, r1, r2) = (cross(col(1), col(2)), cross(col(2), col(0)), cross(col(0), col(1)));
        let nn = n.normal.map(f64::from);
        let v: [f64; 3] = std::array::from_fn(|k| (nn[0] * r0[k] + nn[1] * r1[k] + nn[2] * r2[k]) / det);
        let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        let nlen = (nn[0] * nn[0] + nn[1] * nn[1] + nn[2] * nn[2]).sqrt();
        let (normal, factor) = if len > 0.0 && len.is_finite() && nlen > 0.0 {
            (v.map(|x| (x / len) as f32), det.abs() * len / nlen)
        } else {
            // No usable normal: the mean area factor |det|^(2/3) keeps totals plausible.
            (n.normal, det.abs().powf(2.0 / 3.0))
        };
        let center = self.apply_point(n.center.map(f64::from));
        // Widened by the centre's own f32 rounding (≤ ε·max|x|) and rounded up, so
        // containment holds in stored precision too.
        let slack = center.iter().fold(0.0f64, |a, x| a.max(x.abs())) * f64::from(f32::EPSILON);
        let r = f64::from(n.radius) * stretch + slack;
        let rf = r as f32;
        Node {
            center: center.map(|x| x as f32),
            radius: if f64::from(rf) < r { rf.next_up() } else { rf },
            normal,
            cone: n.cone,
            area: (f64::from(n.area) * factor) as f32,
            color: n.color,
        }
    }
}

/// A whole samples file in memory.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SamplesFile {
    /// Provenance.
    pub generator: Generator,
    /// Meshes, in sample order.
    pub meshes: Vec<MeshEntry>,
    /// Similarity placements.
    pub instances: Vec<SampleInstance>,
    /// Affine placements (non-similarities); every mesh appears at least once in
    /// `instances` or here.
    pub affine_instances: Vec<AffineInstance>,
    /// Leaf samples (cone 0).
    pub samples: Vec<Node>,
}

impl SamplesFile {
    /// A single-mesh file placed once at the identity.
    pub fn single_mesh(generator: Generator, name: &str, samples: Vec<Node>) -> Self {
        SamplesFile {
            generator,
            meshes: vec![MeshEntry { name: name.to_string(), first: 0, count: samples.len() as u64, two_sided: false }],
            instances: vec![SampleInstance { mesh: 0, transform: Similarity::IDENTITY }],
            affine_instances: Vec::new(),
            samples,
        }
    }

    /// Checks the invariants the reader enforces, so a writer cannot produce a file its own
    /// reader refuses.
    pub fn check(&self) -> Result<()> {
        check_tables_for_writer(&self.meshes, &self.instances, &self.affine_instances, self.samples.len() as u64)
    }

    /// Writes the file to `w`; returns the number of bytes written.
    pub fn write_to<W: Write>(&self, w: W) -> Result<u64> {
        self.check()?;
        self.write_unchecked(w)
    }

    /// [`Self::write_to`] without [`Self::check`] (tests write files the reader must refuse).
    fn write_unchecked<W: Write>(&self, mut w: W) -> Result<u64> {
        let mut buf = std::io::Cursor::new(Vec::new());
        let n = self.write_seekable(&mut buf)?;
        w.write_all(buf.get_ref())?;
        Ok(n)
    }

    /// Writes the file atomically (temporary file + rename).
    pub fn write_file(&self, path: &Path) -> Result<u64> {
        self.check()?;
        crate::atomic::write_atomic(path, |w| self.write_seekable(w))
    }

    /// Through [`SamplesWriter`], the one writer of samples files.
    fn write_seekable<W: Write + Seek>(&self, w: &mut W) -> Result<u64> {
        let mut sw = SamplesWriter::new(w)?;
        sw.push(&self.samples)?;
        sw.finish_unchecked(&self.generator, &self.meshes, &self.instances, &self.affine_instances)
    }

    /// Parses a samples file from bytes.
    pub fn read(data: &[u8], limits: &Limits) -> Result<Self> {
        let (mut file, stored, at) = Self::read_tables(data, limits)?;
        file.decode(stored, &at)?;
        Ok(file)
    }

    /// Everything but the samples, which come back as stored (after the section's CRC check:
    /// `SMPL` located and sized, `SMPS` or `SMPC` walked) with the offsets the table checks
    /// report.
    fn read_tables<'a>(data: &'a [u8], limits: &Limits) -> Result<(Self, StoredSamples<'a>, TableOffsets)> {
        let known = [tags::GENR, tags::MESH, tags::INST, tags::SMPL, SMPC, SMPS, AFFI, SIDE];
        let c = Container::parse(data, SAMPLES_MAGIC, "SCT samples", &known, limits)?;
        if c.sections.first().map(|e| e.tag) != Some(tags::GENR) {
            return Err(Error::malformed(c.header.section_table_offset, "the first section must be the generator (GENR)"));
        }
        let genr = c.single(tags::GENR)?;
        // Sizes are checked by meaning before anything is inflated: the generator is a
        // string, and each table, like the samples it places, at most the decoded-samples cap.
        Limits::check("generator size", genr.raw_len, limits.max_string_bytes as u64)?;
        let generator = parse_generator(&c.section_bytes(genr, limits)?, genr.offset, limits)?;
        let table_bytes = |e: &SectionEntry| {
            Limits::check("samples table bytes", e.raw_len, limits.max_sample_bytes)?;
            c.section_bytes(e, limits)
        };

        let stored = stored_samples(&c, limits)?;
        // Before any table or sample is inflated: what the file stands for must be in
        // proportion to its size (spec §2.4), or a few hundred kilobytes of chunks or
        // instances could stand for gigabytes.
        let mut tables = genr.raw_len;
        for e in c.sections.iter().filter(|e| [tags::MESH, tags::INST, AFFI].contains(&e.tag)) {
            // Each table's own cap first, as its message is the more precise.
            Limits::check("samples table bytes", e.raw_len, limits.max_sample_bytes)?;
            tables = tables.saturating_add(e.raw_len);
        }
        let sample_bytes = |n: u64| n.saturating_mul(std::mem::size_of::<Node>() as u64);
        let decoded = tables.saturating_add(sample_bytes(stored.count()));
        limits.check_decoded(decoded, data.len() as u64)?;

        let e = c.single(tags::MESH)?;
        let mesh_offset = e.offset;
        let bytes = table_bytes(e)?;
        let mut cur = Cursor::new(&bytes, e.offset);
        let n = cur.count(MESH_ENTRY_MIN, "mesh count")?;
        let mut meshes = Vec::with_capacity(n);
        for _ in 0..n {
            let first = cur.u64("mesh first sample")?;
            let count = cur.u64("mesh sample count")?;
            let name = cur.string(limits.max_string_bytes, "mesh name")?;
            meshes.push(MeshEntry { name, first, count, two_sided: false });
        }
        cur.finish("mesh table")?;

        let e = c.single(tags::INST)?;
        let bytes = table_bytes(e)?;
        let mut cur = Cursor::new(&bytes, e.offset);
        let n = cur.count(INST_ENTRY_BYTES, "instance count")?;
        let mut instances = Vec::with_capacity(n);
        for _ in 0..n {
            let mesh = cur.u32("instance mesh")?;
            let transform = read_similarity(&mut cur)?;
            instances.push(SampleInstance { mesh, transform });
        }
        cur.finish("instance list")?;
        let mut offsets = TableOffsets { mesh: mesh_offset, inst: e.offset, affi: e.offset };

        let mut affine_instances = Vec::new();
        if c.sections.iter().any(|s| s.tag == AFFI) {
            let e = c.single(AFFI)?;
            offsets.affi = e.offset;
            let bytes = table_bytes(e)?;
            let mut cur = Cursor::new(&bytes, e.offset);
            let n = cur.count(AFFI_ENTRY_BYTES, "affine instance count")?;
            affine_instances.reserve(n);
            for _ in 0..n {
                let mesh = cur.u32("affine instance mesh")?;
                let mut matrix = [[0f64; 4]; 3];
                for v in matrix.iter_mut().flatten() {
                    *v = cur.f64("affine matrix")?;
                }
                affine_instances.push(AffineInstance { mesh, matrix });
            }
            cur.finish("affine instance list")?;
        }
        if c.sections.iter().any(|s| s.tag == SIDE) {
            let e = c.single(SIDE)?;
            let bytes = c.section_bytes(e, limits)?;
            let mut cur = Cursor::new(&bytes, e.offset);
            let n = cur.count(4, "two-sided mesh count")?;
            let (mut prev, mesh_count) = (None, meshes.len());
            for _ in 0..n {
                let at = cur.offset();
                let m = cur.u32("two-sided mesh")?;
                // Ascending, so each mesh is listed once and the list has one encoding.
                if prev.is_some_and(|p| m <= p) {
                    return Err(Error::malformed(at, format!("two-sided mesh {m} is not above the previous entry")));
                }
                let mesh = meshes.get_mut(m as usize).ok_or_else(|| Error::malformed(at, format!("two-sided mesh {m} does not exist ({mesh_count} meshes)")))?;
                mesh.two_sided = true;
                prev = Some(m);
            }
            cur.finish("two-sided mesh list")?;
        }
        // Consumers bake a copy of a mesh's samples per affine placement (spec §8), so those
        // copies count too, once the tables say how many there are and before any sample is
        // decoded: a few bytes of `AFFI` could otherwise stand for a million copies of one
        // chunk. A mesh's count is taken at most the file's sample count (a larger one is
        // malformed, reported when the tables are checked below).
        let baked = affine_instances
            .iter()
            .filter_map(|a| meshes.get(a.mesh as usize))
            .fold(0u64, |s, m| s.saturating_add(sample_bytes(m.count.min(stored.count()))));
        limits.check_decoded(decoded.saturating_add(baked), data.len() as u64)?;
        // The tables are checked against the sample count when the samples are decoded.
        let file = SamplesFile { generator, meshes, instances, affine_instances, samples: Vec::new() };
        Ok((file, stored, offsets))
    }

    /// Checks the tables against the sample count the stored samples declare, then decodes
    /// them. Both layouts give the count before anything is decoded (chunks by their
    /// headers, `SMPL` by its length), so a file whose tables disagree costs no decoding.
    fn decode(&mut self, stored: StoredSamples<'_>, at: &TableOffsets) -> Result<()> {
        check_tables(&self.meshes, &self.instances, &self.affine_instances, stored.count(), at)?;
        self.samples = match stored {
            StoredSamples::Legacy(l) => decode_legacy(&l)?,
            StoredSamples::Chunks(chunks, count, layout) => decode_chunks(&chunks, count, layout)?,
        };
        Ok(())
    }

    /// Reads a samples file from disk (a regular file; see [`crate::fsio::open_regular`]).
    /// Chunks decode chunk by chunk from the file's bytes, a legacy `SMPL` section streams
    /// out of its frame: the peak is the file plus the samples (40 bytes each).
    pub fn read_file(path: &Path, limits: &Limits) -> Result<Self> {
        Ok(Self::read_file_impl(path, limits, false, |_, _| Ok(()))?.0)
    }

    /// [`Self::read_file`], calling `check(tables, sample_count)` once the tables are read
    /// and the samples located and counted, before any sample is decoded (`tables.samples` is
    /// still empty): a caller that will refuse a file for what it holds (too many points to
    /// export, say) refuses it before paying for the decoding.
    pub fn read_file_checked(path: &Path, limits: &Limits, check: impl FnOnce(&SamplesFile, u64) -> Result<()>) -> Result<Self> {
        Ok(Self::read_file_impl(path, limits, false, check)?.0)
    }

    /// [`Self::read_file`], also returning the BLAKE3 hash (lowercase hex) of the bytes read:
    /// provenance without reading the file twice, and of exactly the bytes the samples came
    /// from. Hashed on every thread ([`crate::atomic::hash_bytes`]) while the tables are read.
    pub fn read_file_hashed(path: &Path, limits: &Limits) -> Result<(Self, String)> {
        let (file, hash) = Self::read_file_impl(path, limits, true, |_, _| Ok(()))?;
        Ok((file, hash.unwrap_or_default()))
    }

    fn read_file_impl(path: &Path, limits: &Limits, hash: bool, check: impl FnOnce(&SamplesFile, u64) -> Result<()>) -> Result<(Self, Option<String>)> {
        let data = read_whole(path)?;
        let (hash, tables) = rayon::join(|| hash.then(|| crate::atomic::hash_bytes(&data)), || Self::read_tables(&data, limits));
        let (mut file, stored, at) = tables?;
        check(&file, stored.count())?;
        file.decode(stored, &at)?;
        Ok((file, hash))
    }
    /// Samples of mesh `m`.
    pub fn mesh_samples(&self, m: usize) -> &[Node] {
        let e = &self.meshes[m];
        &self.samples[e.first as usize..(e.first + e.count) as usize]
    }
}

/// Offsets of the sections [`check_tables`] checks, so each error points at the table that
/// holds the bad entry (the MESH and INST errors used to point at AFFI).
struct TableOffsets {
    mesh: u64,
    inst: u64,
    /// AFFI's, or INST's when the file has no AFFI (no affine error can arise then).
    affi: u64,
}

/// Room reserved for a samples file's bytes, at least: more than glibc's largest dynamic mmap
/// threshold (32 MiB). glibc raises that threshold to the size of any freed mapped block below
/// it, after which a build's later buffers come from the heap and stay resident when freed: a
/// 33 MB samples file freed after decoding raised `sct-build-tree`'s peak by 20 MB (94 → 103
/// B/leaf on the bunny). The pages beyond the file are reserved, never touched.
const MIN_READ_CAPACITY: usize = (32 << 20) + (1 << 16);

/// The whole regular file at `path`, in a buffer of at least [`MIN_READ_CAPACITY`]; never
/// more than the size it had when opened (a FIFO, a device or a growing file cannot make
/// the read endless; [`crate::fsio`]).
fn read_whole(path: &Path) -> Result<Vec<u8>> {
    crate::fsio::read_regular_with_capacity(path, u64::MAX, MIN_READ_CAPACITY)
}

fn check_tables(meshes: &[MeshEntry], instances: &[SampleInstance], affine: &[AffineInstance], samples: u64, at: &TableOffsets) -> Result<()> {
    let offset = at.mesh;
    let mut next = 0u64;
    for (i, m) in meshes.iter().enumerate() {
        if m.first != next {
            return Err(Error::malformed(offset, format!("mesh {i} starts at sample {}, expected {next}", m.first)));
        }
        next = m.first.checked_add(m.count).ok_or_else(|| Error::malformed(offset, "mesh sample range overflows"))?;
    }
    if next != samples {
        return Err(Error::malformed(offset, format!("meshes cover {next} samples, the file has {samples}")));
    }
    let mut used = vec![false; meshes.len()];
    let offset = at.inst;
    for (i, inst) in instances.iter().enumerate() {
        let slot = used
            .get_mut(inst.mesh as usize)
            .ok_or_else(|| Error::malformed(offset, format!("instance {i} names mesh {}, there are {}", inst.mesh, meshes.len())))?;
        *slot = true;
        if !inst.transform.is_valid(1e-6) {
            return Err(Error::malformed(
                offset,
                format!("instance {i} has an invalid transform (non-finite, non-unit quaternion or scale <= 0)"),
            ));
        }
    }
    for (i, inst) in affine.iter().enumerate() {
        let offset = at.affi;
        let slot = used.get_mut(inst.mesh as usize).ok_or_else(|| {
            Error::malformed(offset, format!("affine instance {i} names mesh {}, there are {}", inst.mesh, meshes.len()))
        })?;
        *slot = true;
        if !inst.is_valid() {
            return Err(Error::malformed(offset, format!("affine instance {i} has a non-finite or singular matrix")));
        }
    }
    if let Some(m) = used.iter().position(|u| !u) {
        // The missing entry belongs in the instance list.
        return Err(Error::malformed(at.inst, format!("mesh {m} has no instance")));
    }
    Ok(())
}

pub(crate) fn parse_generator(bytes: &[u8], offset: u64, limits: &Limits) -> Result<Generator> {
    Limits::check("generator size", bytes.len() as u64, limits.max_string_bytes as u64)?;
    serde_json::from_slice(bytes).map_err(|e| Error::malformed(offset, format!("generator JSON: {e}")))
}

pub(crate) fn put_similarity(out: &mut Vec<u8>, t: &Similarity) {
    for v in t.translation.iter().chain(t.rotation.iter()) {
        out.put_f64(*v);
    }
    out.put_f64(t.scale);
}

pub(crate) fn read_similarity(c: &mut Cursor<'_>) -> Result<Similarity> {
    let mut v = [0f64; 8];
    for x in &mut v {
        *x = c.f64("transform")?;
    }
    Ok(Similarity { translation: [v[0], v[1], v[2]], rotation: [v[3], v[4], v[5], v[6]], scale: v[7] })
}

/// [`check_tables`] for a writer: what the reader would call malformed is the caller's
/// mistake.
fn check_tables_for_writer(meshes: &[MeshEntry], instances: &[SampleInstance], affine: &[AffineInstance], samples: u64) -> Result<()> {
    check_tables(meshes, instances, affine, samples, &TableOffsets { mesh: 0, inst: 0, affi: 0 }).map_err(|e| match e {
        Error::Malformed { what, .. } => Error::Misuse(what),
        other => other,
    })
}

/// The sections other than the samples, in table order: `GENR`, `MESH`, `INST`; and apart
/// `AFFI`, present only when there are affine placements, so that files without them stay
/// readable by readers that predate it, then `SIDE`, present only when some mesh is
/// two-sided (optional: an older reader skips it and draws those meshes one-sided).
fn table_sections(
    generator: &Generator,
    meshes: &[MeshEntry],
    instances: &[SampleInstance],
    affine: &[AffineInstance],
) -> Result<([SectionOut; 3], Vec<SectionOut>)> {
    let genr = serde_json::to_vec(generator).map_err(|e| Error::Misuse(format!("generator: {e}")))?;
    let mut mesh = Vec::new();
    mesh.put_u64(meshes.len() as u64);
    for m in meshes {
        mesh.put_u64(m.first);
        mesh.put_u64(m.count);
        mesh.put_str(&m.name);
    }
    let mut inst = Vec::with_capacity(8 + instances.len() * INST_ENTRY_BYTES);
    inst.put_u64(instances.len() as u64);
    for i in instances {
        inst.put_u32(i.mesh);
        put_similarity(&mut inst, &i.transform);
    }
    let tables = [SectionOut::plain(tags::GENR, genr), SectionOut::plain(tags::MESH, mesh), SectionOut::zstd(tags::INST, &inst, ZSTD_LEVEL)?];
    let affi = if affine.is_empty() {
        None
    } else {
        let mut affi = Vec::with_capacity(8 + affine.len() * AFFI_ENTRY_BYTES);
        affi.put_u64(affine.len() as u64);
        for a in affine {
            affi.put_u32(a.mesh);
            a.matrix.iter().flatten().for_each(|v| affi.put_f64(*v));
        }
        Some(SectionOut::zstd(AFFI, &affi, ZSTD_LEVEL)?)
    };
    let two_sided: Vec<u32> = meshes.iter().enumerate().filter(|(_, m)| m.two_sided).map(|(i, _)| i as u32).collect();
    let side = (!two_sided.is_empty()).then(|| {
        let mut side = Vec::with_capacity(8 + 4 * two_sided.len());
        side.put_u64(two_sided.len() as u64);
        two_sided.iter().for_each(|&m| side.put_u32(m));
        SectionOut::optional(SIDE, side)
    });
    Ok((tables, affi.into_iter().chain(side).collect()))
}

/// Chunks compressed together by [`SamplesWriter`]: enough to keep the threads busy; it
/// buffers fewer samples than this many chunks hold (42 MB).
const BATCH_CHUNKS: usize = 16;

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
    /// time) and written; what is left of a chunk, or fewer than 16 chunks (42 MB)
    /// from small pushes, stays buffered until more come or [`Self::finish`].
    pub fn push(&mut self, samples: &[Node]) -> Result<()> {
        let mut rest = samples;
        if !self.pending.is_empty() {
            let take = rest.len().min((BATCH_CHUNKS * CHUNK_SAMPLES).saturating_sub(self.pending.len()));
            self.pending.extend_from_slice(&rest[..take]);
            rest = &rest[take..];
            if self.pending.len() < BATCH_CHUNKS * CHUNK_SAMPLES {
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
    fn finish_unchecked(mut self, generator: &Generator, meshes: &[MeshEntry], instances: &[SampleInstance], affine: &[AffineInstance]) -> Result<u64> {
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
struct CompressedChunk {
    header: [u8; CHUNK_HEADER_BYTES],
    frame: Vec<u8>,
    crc: crc32fast::Hasher,
}

fn compress_chunk(samples: &[Node]) -> Result<CompressedChunk> {
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
const PLANE_TILE: usize = 1024;

/// The byte-plane layout of a chunk's `samples` (spec §8, `SMPS`), replacing `out`: byte k of
/// every sample's 36-byte record is plane k (n bytes), each centre coordinate's bits stored as
/// the wrapping difference from the previous sample's (voxel samples come sorted, so the
/// planes hold runs zstd finds cheaply).
fn put_planes(samples: &[Node], out: &mut Vec<u8>) {
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
fn scatter(tile: &[Node], [p0, p1, p2, p3]: [&mut [u8]; 4], mut bytes_of: impl FnMut(&Node) -> [u8; 4]) {
    let planes = p0.iter_mut().zip(p1.iter_mut()).zip(p2.iter_mut()).zip(p3.iter_mut());
    for (s, (((b0, b1), b2), b3)) in tile.iter().zip(planes) {
        [*b0, *b1, *b2, *b3] = bytes_of(s);
    }
}

/// The inverse of [`put_planes`]: the samples `out` from a chunk's `bytes` (36 · out.len()).
fn samples_from_planes(bytes: &[u8], out: &mut [Node]) {
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
fn gather(tile: &mut [Node], [p0, p1, p2, p3]: [&[u8]; 4], mut set: impl FnMut(&mut Node, [u8; 4])) {
    let planes = p0.iter().zip(p1).zip(p2).zip(p3);
    for (o, (((b0, b1), b2), b3)) in tile.iter_mut().zip(planes) {
        set(o, [*b0, *b1, *b2, *b3]);
    }
}

/// The column layout of `samples` (centres, radii, normals, areas, colours), appended: what
/// `SMPL` and `SMPC` hold (test-only: writers write `SMPS`).
#[cfg(test)]
fn put_columns(samples: &[Node], out: &mut Vec<u8>) {
    out.reserve(samples.len() * SAMPLE_BYTES);
    samples.iter().for_each(|s| s.center.iter().for_each(|v| out.extend_from_slice(&v.to_le_bytes())));
    samples.iter().for_each(|s| out.extend_from_slice(&s.radius.to_le_bytes()));
    samples.iter().for_each(|s| s.normal.iter().for_each(|v| out.extend_from_slice(&v.to_le_bytes())));
    samples.iter().for_each(|s| out.extend_from_slice(&s.area.to_le_bytes()));
    samples.iter().for_each(|s| out.extend_from_slice(&s.color));
}

/// The samples as stored, after the section's CRC check.
enum StoredSamples<'a> {
    /// `SMPL`: one section of columns (one zstd frame), decoded as it inflates.
    Legacy(Legacy<'a>),
    /// `SMPS` or `SMPC`: the chunks, walked and checked, the number of samples they hold and
    /// how a chunk lays out its samples.
    Chunks(Vec<Chunk<'a>>, u64, ChunkLayout),
}

impl StoredSamples<'_> {
    /// The number of samples the stored bytes declare.
    fn count(&self) -> u64 {
        match self {
            StoredSamples::Legacy(l) => l.count,
            StoredSamples::Chunks(_, count, _) => *count,
        }
    }
}

/// A legacy `SMPL` section, located and sized but not inflated.
struct Legacy<'a> {
    /// The stored bytes (one zstd frame when `compressed`).
    stored: &'a [u8],
    compressed: bool,
    /// Samples, from the section's raw length (`8 + 36 · count`).
    count: u64,
    /// The section's offset, for errors.
    offset: u64,
}

/// How a chunk's inflated 36 · n bytes hold its samples.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum ChunkLayout {
    /// `SMPS`: byte planes ([`put_planes`]).
    Planes,
    /// `SMPC`: columns, as `SMPL`.
    Columns,
}

/// One chunk: `n` samples whose bytes are the zstd frame `frame`.
struct Chunk<'a> {
    n: usize,
    frame: &'a [u8],
    /// The frame's offset, for errors.
    offset: u64,
}

/// The file's samples section: exactly one of `SMPS`, `SMPC` and `SMPL`.
fn stored_samples<'a>(c: &Container<'a>, limits: &Limits) -> Result<StoredSamples<'a>> {
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
fn walk_chunks<'a>(bytes: &'a [u8], offset: u64, limits: &Limits) -> Result<Vec<Chunk<'a>>> {
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
fn check_sample_totals(count: u64, at: u64, limits: &Limits) -> Result<()> {
    Limits::check("sample count", count, limits.max_samples)?;
    let raw = count.checked_mul(SAMPLE_BYTES as u64).ok_or_else(|| Error::malformed(at, "sample bytes overflow"))?;
    Limits::check("decompressed size", raw, limits.max_decompressed_bytes)?;
    let decoded = count.checked_mul(std::mem::size_of::<Node>() as u64).ok_or_else(|| Error::malformed(at, "sample bytes overflow"))?;
    Limits::check("decoded sample bytes", decoded, limits.max_sample_bytes)
}

/// Cheap checks of a chunk's frame before anything is decompressed: exactly one frame, and
/// the content size its header may declare is the chunk's.
fn check_frame(frame: &[u8], raw_len: u64, offset: u64) -> Result<()> {
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
const DECODE_ROUND_CHUNKS: usize = 64;

/// Decodes the chunks (`total` samples) in parallel, each straight into its slice of the
/// samples; the first bad chunk (in file order) is the error.
fn decode_chunks(chunks: &[Chunk<'_>], total: u64, layout: ChunkLayout) -> Result<Vec<Node>> {
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
fn decode_chunk(c: &Chunk<'_>, layout: ChunkLayout, out: &mut [Node], scratch: &mut Vec<u8>) -> Result<()> {
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
fn samples_from_columns(bytes: &[u8], out: &mut [Node]) {
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
fn node_from_columns(c: &[u8], r: &[u8], nm: &[u8], ar: &[u8], co: &[u8]) -> Node {
    Node { center: f3(c), radius: f1(r), normal: f3(nm), cone: 0.0, area: f1(ar), color: [co[0], co[1], co[2], co[3]] }
}

/// Decodes a legacy `SMPL` section (files written before chunks): the count, then whole
/// columns, read as the frame inflates, a piece at a time, into the samples. Memory is the
/// samples (grown with the data produced, up to the count already checked against the
/// limits) and one piece: a frame that does not inflate as claimed fails before the reader
/// holds memory for samples it never produced.
fn decode_legacy(l: &Legacy<'_>) -> Result<Vec<Node>> {
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
fn f1(b: &[u8]) -> f32 {
    f32::from_le_bytes([b[0], b[1], b[2], b[3]])
}

/// Three little-endian f32 from a 12-byte chunk.
#[inline]
fn f3(b: &[u8]) -> [f32; 3] {
    [f1(&b[0..4]), f1(&b[4..8]), f1(&b[8..12])]
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(i: u32) -> Node {
        let f = i as f32;
        Node { center: [f, -f, 0.5], radius: 0.1, normal: [0.0, 0.0, 1.0], cone: 0.0, area: 0.02, color: [i as u8, 2, 3, 255] }
    }

    fn file() -> SamplesFile {
        let mut f = SamplesFile::single_mesh(Generator { tool: "t".into(), ..Default::default() }, "m", (0..100).map(sample).collect());
        f.meshes.push(MeshEntry { name: "second".into(), first: 100, count: 2, two_sided: false });
        f.samples.extend([sample(7), sample(8)]);
        let t = Similarity { translation: [1.0, 2.0, 3.0], rotation: [0.0, 0.0, 0.0, 1.0], scale: 2.0 };
        f.instances.push(SampleInstance { mesh: 1, transform: t });
        f.instances.push(SampleInstance { mesh: 1, transform: Similarity::IDENTITY });
        f
    }

    fn stretched() -> AffineInstance {
        // Non-uniform scale (1, 2, 0.5), a shear and a translation.
        AffineInstance { mesh: 0, matrix: [[1.0, 0.3, 0.0, 5.0], [0.0, 2.0, 0.0, -1.0], [0.0, 0.0, 0.5, 2.0]] }
    }

    fn file_affine() -> SamplesFile {
        let mut f = file();
        f.affine_instances.push(stretched());
        f.affine_instances.push(AffineInstance { mesh: 1, ..stretched() });
        f
    }

    /// Two-sided meshes come back through the optional `SIDE` section; a file without one
    /// has no `SIDE` section at all (so it stays what older readers read).
    #[test]
    fn two_sided_meshes_round_trip_through_side() {
        let has_side = |bytes: &[u8]| {
            let known = [tags::GENR, tags::MESH, tags::INST, SMPS, AFFI, SIDE];
            let c = Container::parse(bytes, SAMPLES_MAGIC, "SCT samples", &known, &Limits::default()).unwrap();
            c.sections.iter().find(|e| e.tag == SIDE).map(|e| e.flags & SectionEntry::REQUIRED)
        };
        let mut f = file_affine();
        let mut bytes = Vec::new();
        f.write_to(&mut bytes).unwrap();
        assert_eq!(has_side(&bytes), None);
        assert!(SamplesFile::read(&bytes, &Limits::default()).unwrap().meshes.iter().all(|m| !m.two_sided));
        f.meshes[1].two_sided = true;
        let mut bytes = Vec::new();
        f.write_to(&mut bytes).unwrap();
        assert_eq!(has_side(&bytes), Some(0), "SIDE is present and optional");
        let back = SamplesFile::read(&bytes, &Limits::default()).unwrap();
        assert_eq!(back.meshes.iter().map(|m| m.two_sided).collect::<Vec<_>>(), [false, true]);
        assert_eq!(back, f);
    }

    /// Table errors point at the table holding the bad entry, also when AFFI is present.
    #[test]
    fn table_errors_point_at_their_section() {
        let offset_of = |bytes: &[u8], tag: [u8; 4]| {
            let known = [tags::GENR, tags::MESH, tags::INST, SMPS, AFFI];
            let c = Container::parse(bytes, SAMPLES_MAGIC, "SCT samples", &known, &Limits::default()).unwrap();
            c.sections.iter().find(|e| e.tag == tag).map(|e| e.offset).unwrap()
        };
        let error_offset = |f: &SamplesFile| {
            let mut bytes = Vec::new();
            f.write_unchecked(&mut bytes).unwrap();
            match SamplesFile::read(&bytes, &Limits::default()) {
                Err(Error::Malformed { offset, .. }) => (bytes, offset),
                other => panic!("{:?}", other.map(|_| ())),
            }
        };
        let mut f = file_affine();
        f.instances[0].mesh = 99;
        let (bytes, at) = error_offset(&f);
        assert_eq!(at, offset_of(&bytes, tags::INST));
        assert_ne!(at, offset_of(&bytes, AFFI));
        let mut f = file_affine();
        f.meshes[1].first = 101;
        let (bytes, at) = error_offset(&f);
        assert_eq!(at, offset_of(&bytes, tags::MESH));
        let mut f = file_affine();
        f.affine_instances[0].mesh = 99;
        let (bytes, at) = error_offset(&f);
        assert_eq!(at, offset_of(&bytes, AFFI));
    }

    /// The whole file comes back, in a buffer past glibc's mmap threshold (see
    /// [`MIN_READ_CAPACITY`]: a smaller one raised the build's peak by 20 MB).
    #[test]
    fn read_whole_reserves_past_the_mmap_threshold() {
        let dir = std::env::temp_dir().join(format!("sct-read-whole-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("dir");
        let path = dir.join("x.samples");
        let bytes: Vec<u8> = (0..100_000u32).map(|i| (i * 7) as u8).collect();
        std::fs::write(&path, &bytes).expect("write");
        let data = read_whole(&path).expect("read");
        assert_eq!(data, bytes);
        assert!(data.capacity() >= MIN_READ_CAPACITY);
        assert!(matches!(read_whole(&dir.join("missing")), Err(Error::Io { .. })));
        std::fs::remove_dir_all(&dir).expect("clean");
    }

    #[test]
    fn round_trip_affine() {
        let f = file_affine();
        let mut bytes = Vec::new();
        f.write_to(&mut bytes).unwrap();
        assert_eq!(SamplesFile::read(&bytes, &Limits::default()).unwrap(), f);
        // A mesh placed only by an affine instance is placed.
        let mut g = f.clone();
        g.instances.retain(|i| i.mesh != 0);
        let mut bytes = Vec::new();
        g.write_to(&mut bytes).unwrap();
        assert_eq!(SamplesFile::read(&bytes, &Limits::default()).unwrap(), g);
    }

    #[test]
    fn affine_section_only_when_needed_and_required() {
        let mut plain = Vec::new();
        file().write_to(&mut plain).unwrap();
        let mut with = Vec::new();
        file_affine().write_to(&mut with).unwrap();
        let before_affi = [tags::GENR, tags::MESH, tags::INST, SMPS];
        // A reader that predates AFFI would read files without it …
        assert!(Container::parse(&plain, SAMPLES_MAGIC, "SCT samples", &before_affi, &Limits::default()).is_ok());
        // … and refuses files with it rather than silently dropping placements.
        let e = Container::parse(&with, SAMPLES_MAGIC, "SCT samples", &before_affi, &Limits::default()).unwrap_err();
        assert!(e.to_string().contains("AFFI"), "{e}");
    }

    /// A reader that predates SMPS (or SMPC) refuses the file (the section is required)
    /// instead of reading a file without samples.
    #[test]
    fn chunked_section_is_required() {
        let mut bytes = Vec::new();
        file().write_to(&mut bytes).unwrap();
        for before in [[tags::GENR, tags::MESH, tags::INST, tags::SMPL, AFFI], [tags::GENR, tags::MESH, tags::INST, SMPC, AFFI]] {
            let e = Container::parse(&bytes, SAMPLES_MAGIC, "SCT samples", &before, &Limits::default()).unwrap_err();
            assert!(matches!(&e, Error::UnknownRequiredSection { tag, .. } if tag == "SMPS"), "{e}");
        }
    }

    #[test]
    fn singular_affine_is_refused() {
        let mut f = file_affine();
        f.affine_instances[0].matrix[2] = [0.0, 0.0, 0.0, 1.0];
        assert!(matches!(f.write_to(Vec::new()), Err(Error::Misuse(_))));
        f.affine_instances[0].matrix = stretched().matrix;
        f.affine_instances[0].matrix[1][1] = f64::NAN;
        assert!(matches!(f.write_to(Vec::new()), Err(Error::Misuse(_))));
    }

    #[test]
    fn max_stretch_is_the_largest_singular_value() {
        let s = AffineInstance { mesh: 0, matrix: [[3.0, 0.0, 0.0, 1.0], [0.0, -0.5, 0.0, 0.0], [0.0, 0.0, 2.0, 0.0]] }.max_stretch();
        assert!((s - 3.0).abs() < 1e-9, "{s}");
        // Brute force over directions for a sheared map.
        let a = stretched();
        let mut best = 0.0f64;
        for i in 0..200 {
            for j in 0..100 {
                let (t, p) = (i as f64 * std::f64::consts::PI / 100.0, j as f64 * std::f64::consts::PI / 100.0);
                let d = [p.sin() * t.cos(), p.sin() * t.sin(), p.cos()];
                let o = a.apply_point([0.0; 3]);
                let q = a.apply_point(d);
                best = best.max((0..3).map(|k| (q[k] - o[k]).powi(2)).sum::<f64>().sqrt());
            }
        }
        let s = a.max_stretch();
        assert!(s >= best && s < best * 1.001, "stretch {s}, brute force {best}");
    }

    /// A baked sample's sphere contains the image of its sphere, its normal is perpendicular
    /// to mapped tangents and its area is the mapped area of a small disc.
    #[test]
    fn transform_node_is_conservative_and_exact_for_area() {
        let a = stretched();
        let st = a.max_stretch();
        let n = Node { center: [0.3, -0.2, 1.0], radius: 0.1, normal: [0.0, 0.6, 0.8], cone: 0.0, area: 0.01, color: [9, 8, 7, 255] };
        let b = a.transform_node(&n, st);
        assert_eq!(b.color, n.color);
        let c = n.center.map(f64::from);
        let bc = b.center.map(f64::from);
        for i in 0..50 {
            for j in 0..25 {
                let (t, p) = (i as f64 * 0.1257, j as f64 * 0.1257);
                let d = [p.sin() * t.cos(), p.sin() * t.sin(), p.cos()];
                let q = a.apply_point([0, 1, 2].map(|k| c[k] + 0.1 * d[k]));
                let dist = (0..3).map(|k| (q[k] - bc[k]).powi(2)).sum::<f64>().sqrt();
                assert!(dist <= f64::from(b.radius), "{dist} > {}", b.radius);
            }
        }
        // Tangents of the plane with normal (0, .6, .8): (1,0,0) and (0,.8,-.6).
        let map_dir = |d: [f64; 3]| {
            let (o, q) = (a.apply_point([0.0; 3]), a.apply_point(d));
            [q[0] - o[0], q[1] - o[1], q[2] - o[2]]
        };
        let (u, v) = (map_dir([1.0, 0.0, 0.0]), map_dir([0.0, 0.8, -0.6]));
        let nb = b.normal.map(f64::from);
        for t in [u, v] {
            assert!((t[0] * nb[0] + t[1] * nb[1] + t[2] * nb[2]).abs() < 1e-6);
        }
        let cr = [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]];
        let expect = 0.01 * (cr[0] * cr[0] + cr[1] * cr[1] + cr[2] * cr[2]).sqrt();
        assert!((f64::from(b.area) - expect).abs() < 1e-6 * expect, "{} vs {expect}", b.area);
        // Orientation kept: the baked normal points the same way as the mapped unit normal's
        // cofactor image (same side as u × v).
        assert!(cr[0] * nb[0] + cr[1] * nb[1] + cr[2] * nb[2] > 0.0);
    }

    #[test]
    fn round_trip() {
        let f = file();
        let mut bytes = Vec::new();
        let n = f.write_to(&mut bytes).unwrap();
        assert_eq!(n as usize, bytes.len());
        assert_eq!(SamplesFile::read(&bytes, &Limits::default()).unwrap(), f);
        // From disk (file bytes freed before the samples are decoded): same result, and a
        // mesh table that needs more samples than stored is still refused there.
        let path = std::env::temp_dir().join(format!("sct-samples-rt-{}.samples", std::process::id()));
        f.write_file(&path).unwrap();
        assert_eq!(SamplesFile::read_file(&path, &Limits::default()).unwrap(), f);
        let (g, hash) = SamplesFile::read_file_hashed(&path, &Limits::default()).unwrap();
        assert_eq!((g, hash), (f.clone(), crate::atomic::hash_file(&path).unwrap()));
        let mut bad = f.clone();
        bad.meshes[0].count += 1;
        let mut bytes = Vec::new();
        bad.write_unchecked(&mut bytes).unwrap();
        std::fs::write(&path, &bytes).unwrap();
        assert!(SamplesFile::read_file(&path, &Limits::default()).is_err());
        assert!(SamplesFile::read(&bytes, &Limits::default()).is_err());
        let _ = std::fs::remove_file(&path);
    }

    #[test]
    fn every_truncation_is_an_error() {
        let mut bytes = Vec::new();
        file_affine().write_to(&mut bytes).unwrap();
        for len in 0..bytes.len() {
            assert!(SamplesFile::read(&bytes[..len], &Limits::default()).is_err(), "truncated at {len}");
        }
    }

    #[test]
    fn every_bit_flip_is_detected() {
        let mut bytes = Vec::new();
        file_affine().write_to(&mut bytes).unwrap();
        for i in 0..bytes.len() {
            for bit in [0, 3, 7] {
                let mut b = bytes.clone();
                b[i] ^= 1 << bit;
                assert!(SamplesFile::read(&b, &Limits::default()).is_err(), "flip at byte {i} bit {bit}");
            }
        }
    }

    #[test]
    fn writer_refuses_what_reader_would_refuse() {
        let mut f = file();
        f.instances.retain(|i| i.mesh == 0);
        assert!(matches!(f.write_to(Vec::new()), Err(Error::Misuse(_))));
    }

    #[test]
    fn sample_limit_is_enforced() {
        let mut bytes = Vec::new();
        file().write_to(&mut bytes).unwrap();
        let limits = Limits { max_samples: 10, ..Limits::default() };
        assert!(matches!(SamplesFile::read(&bytes, &limits), Err(Error::LimitExceeded { .. })));
    }

    /// The writer of `SMPL` files (before `SMPC`), kept test-only to show that they still read.
    fn write_smpl(f: &SamplesFile) -> Vec<u8> {
        let (tables, affi) = table_sections(&f.generator, &f.meshes, &f.instances, &f.affine_instances).unwrap();
        let mut columns = Vec::new();
        columns.put_u64(f.samples.len() as u64);
        put_columns(&f.samples, &mut columns);
        let mut sections: Vec<SectionOut> = tables.into_iter().collect();
        sections.push(SectionOut::zstd(tags::SMPL, &columns, ZSTD_LEVEL).unwrap());
        sections.extend(affi);
        let mut out = Vec::new();
        crate::container::write_container(SAMPLES_MAGIC, &sections, &mut out).unwrap();
        out
    }

    fn many(n: usize) -> Vec<Node> {
        (0..n as u32).map(|i| Node { radius: (i as f32).sqrt(), area: (i % 7) as f32, ..sample(i) }).collect()
    }

    fn chunk_counts(bytes: &[u8]) -> Vec<usize> {
        let known = [tags::GENR, tags::MESH, tags::INST, SMPS, AFFI];
        let c = Container::parse(bytes, SAMPLES_MAGIC, "SCT samples", &known, &Limits::default()).unwrap();
        let e = c.single(SMPS).unwrap();
        walk_chunks(c.stored(e).unwrap(), e.offset, &Limits::default()).unwrap().iter().map(|k| k.n).collect()
    }

    #[test]
    fn round_trip_around_chunk_sizes() {
        let c = CHUNK_SAMPLES;
        for n in [0, 1, c - 1, c, c + 1, 3 * c + 5] {
            let f = SamplesFile::single_mesh(Generator::default(), "m", many(n));
            let mut bytes = Vec::new();
            assert_eq!(f.write_to(&mut bytes).unwrap() as usize, bytes.len());
            assert_eq!(SamplesFile::read(&bytes, &Limits::default()).unwrap(), f, "{n} samples");
            // Full chunks but the last.
            let counts = chunk_counts(&bytes);
            assert_eq!(counts.iter().sum::<usize>(), n);
            assert!(counts.iter().rev().skip(1).all(|&k| k == c) && counts.iter().all(|&k| k > 0), "{counts:?}");
        }
    }

    /// The samples section is written first and the section table last (§8).
    #[test]
    fn layout_samples_first_table_last() {
        let mut bytes = Vec::new();
        file_affine().write_to(&mut bytes).unwrap();
        let known = [tags::GENR, tags::MESH, tags::INST, SMPS, AFFI];
        let c = Container::parse(&bytes, SAMPLES_MAGIC, "SCT samples", &known, &Limits::default()).unwrap();
        let tags: Vec<_> = c.sections.iter().map(|e| e.tag).collect();
        assert_eq!(tags, [tags::GENR, tags::MESH, tags::INST, SMPS, AFFI]);
        assert_eq!(c.single(SMPS).unwrap().offset, FILE_HEADER_LEN as u64);
        assert_eq!(c.header.section_table_offset as usize, bytes.len() - 5 * SECTION_ENTRY_LEN);
    }

    /// Uneven pushes, through the atomic writer, on 1 and 2 threads: the bytes of
    /// `SamplesFile::write_to`. Over more than a batch, so pushes fill and flush the buffer.
    #[test]
    fn streaming_writer_is_write_to() {
        let mut f = SamplesFile::single_mesh(Generator { tool: "stream".into(), ..Default::default() }, "a", many((BATCH_CHUNKS + 1) * CHUNK_SAMPLES + 777));
        f.meshes[0].count -= 10;
        f.meshes.push(MeshEntry { name: "b".into(), first: f.meshes[0].count, count: 10, two_sided: false });
        f.instances.push(SampleInstance { mesh: 1, transform: Similarity::IDENTITY });
        f.affine_instances.push(AffineInstance { mesh: 1, ..stretched() });
        let mut want = Vec::new();
        f.write_to(&mut want).unwrap();
        let dir = tempfile::tempdir().unwrap();
        for threads in [1, 2] {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            for sizes in [vec![f.samples.len()], vec![0, 1, 10_007, CHUNK_SAMPLES, 3], vec![30_011], vec![3 * CHUNK_SAMPLES + 1, 5]] {
                let path = dir.path().join(format!("s{threads}.samples"));
                let len = pool.install(|| {
                    crate::atomic::write_atomic(&path, |w| {
                        let mut sw = SamplesWriter::new(&mut *w)?;
                        let mut rest = &f.samples[..];
                        for &k in sizes.iter().cycle() {
                            if rest.is_empty() {
                                break;
                            }
                            let (a, b) = rest.split_at(k.min(rest.len()));
                            sw.push(a)?;
                            rest = b;
                        }
                        assert_eq!(sw.samples_written(), f.samples.len() as u64);
                        sw.finish(&f.generator, &f.meshes, &f.instances, &f.affine_instances)
                    })
                });
                let got = std::fs::read(&path).unwrap();
                assert_eq!(len.unwrap() as usize, got.len());
                assert!(got == want, "{threads} threads, pushes {sizes:?}");
            }
            let bytes = pool.install(|| {
                let mut b = Vec::new();
                f.write_to(&mut b).unwrap();
                b
            });
            assert!(bytes == want, "write_to on {threads} threads");
        }
        assert_eq!(SamplesFile::read(&want, &Limits::default()).unwrap(), f);
    }

    /// A file written after other bytes of a stream is the same file, offsets included.
    #[test]
    fn streaming_writer_starts_where_the_stream_is() {
        let f = file_affine();
        let mut want = Vec::new();
        f.write_to(&mut want).unwrap();
        let mut out = std::io::Cursor::new(b"prefix".to_vec());
        out.seek(SeekFrom::End(0)).unwrap();
        let mut sw = SamplesWriter::new(&mut out).unwrap();
        sw.push(&f.samples).unwrap();
        assert_eq!(sw.finish(&f.generator, &f.meshes, &f.instances, &f.affine_instances).unwrap() as usize, want.len());
        assert_eq!(out.position() as usize, 6 + want.len());
        assert!(out.get_ref()[6..] == want[..]);
    }

    #[test]
    fn streaming_writer_checks_tables() {
        let mut sw = SamplesWriter::new(std::io::Cursor::new(Vec::new())).unwrap();
        sw.push(&many(5)).unwrap();
        let meshes = [MeshEntry { name: "m".into(), first: 0, count: 4, two_sided: false }];
        let instances = [SampleInstance { mesh: 0, transform: Similarity::IDENTITY }];
        assert!(matches!(sw.finish(&Generator::default(), &meshes, &instances, &[]), Err(Error::Misuse(_))));
    }

    /// Files written before chunks (one SMPL frame of whole columns) still read, and still
    /// have their tables checked.
    #[test]
    fn smpl_files_still_read() {
        for f in [file(), file_affine(), SamplesFile::single_mesh(Generator::default(), "m", many(CHUNK_SAMPLES + 3))] {
            assert_eq!(SamplesFile::read(&write_smpl(&f), &Limits::default()).unwrap(), f);
        }
        let mut bad = file();
        bad.meshes[0].count += 1;
        assert!(matches!(SamplesFile::read(&write_smpl(&bad), &Limits::default()), Err(Error::Malformed { .. })));
        // Files the SMPL writer made (fuzz seeds): read, and the same content once rewritten.
        for seed in [&include_bytes!("../../fuzz/seeds/samples_reader/cube.samples")[..], include_bytes!("../../fuzz/seeds/samples_reader/instancing.samples")] {
            let old = SamplesFile::read(seed, &Limits::default()).unwrap();
            assert!(!old.samples.is_empty());
            let mut new = Vec::new();
            old.write_to(&mut new).unwrap();
            assert_eq!(SamplesFile::read(&new, &Limits::default()).unwrap(), old);
        }
    }

    #[test]
    fn crc32_in_pieces_is_crc32() {
        let data: Vec<u8> = (0..9_000_017u32).map(|i| (i.wrapping_mul(2_654_435_761) >> 11) as u8).collect();
        for len in [0, 5, 4 << 20, (4 << 20) + 1, data.len()] {
            assert_eq!(crate::container::crc32(&data[..len]), crc32fast::hash(&data[..len]), "{len}");
        }
    }

    /// A samples file of one mesh of `mesh_count` samples whose samples section is `tag`
    /// (flags `flags`) with `section` as its bytes, plus `extra` sections.
    fn hostile(mesh_count: u64, tag: [u8; 4], section: Vec<u8>, flags: u32, extra: Vec<SectionOut>) -> Vec<u8> {
        let meshes = [MeshEntry { name: "m".into(), first: 0, count: mesh_count, two_sided: false }];
        let instances = [SampleInstance { mesh: 0, transform: Similarity::IDENTITY }];
        let (tables, _) = table_sections(&Generator::default(), &meshes, &instances, &[]).unwrap();
        let mut sections: Vec<SectionOut> = tables.into_iter().collect();
        let compressed = flags & SectionEntry::ZSTD != 0;
        let raw_len = if compressed { 1 << 20 } else { section.len() as u64 };
        sections.push(SectionOut { tag, required: true, stored: section, raw_len, compressed });
        sections.extend(extra);
        let mut out = Vec::new();
        crate::container::write_container(SAMPLES_MAGIC, &sections, &mut out).unwrap();
        out
    }

    fn chunk(n: u32, frame: &[u8]) -> Vec<u8> {
        let mut c = Vec::new();
        c.put_u32(n);
        c.put_u32(frame.len() as u32);
        c.extend_from_slice(frame);
        c
    }

    /// A chunk's frame in the layout of section `tag` (`SMPS` planes, else columns).
    fn frame_of(tag: [u8; 4], samples: &[Node], declare_size: bool) -> Vec<u8> {
        let mut raw = Vec::new();
        if tag == SMPS {
            put_planes(samples, &mut raw);
        } else {
            put_columns(samples, &mut raw);
        }
        let mut z = zstd::bulk::Compressor::new(ZSTD_LEVEL).unwrap();
        z.set_parameter(zstd::zstd_safe::CParameter::ContentSizeFlag(declare_size)).unwrap();
        z.compress(&raw).unwrap()
    }

    #[track_caller]
    fn malformed(bytes: &[u8], needle: &str) {
        match SamplesFile::read(bytes, &Limits::default()) {
            Err(Error::Malformed { what, .. }) => assert!(what.contains(needle), "{what:?} lacks {needle:?}"),
            other => panic!("{:?}", other.map(|f| f.samples.len())),
        }
    }

    /// Every check of a chunk, for both chunked sections.
    #[test]
    fn hostile_chunks_are_refused() {
        for tag in [SMPS, SMPC] {
            hostile_chunks_of(tag);
        }
    }

    fn hostile_chunks_of(tag: [u8; 4]) {
        let two = many(2);
        let good = frame_of(tag, &two, true);
        // The hand-made layout itself reads.
        let ok = SamplesFile::read(&hostile(2, tag, chunk(2, &good), 0, vec![]), &Limits::default()).unwrap();
        assert_eq!(ok.samples, two);
        malformed(&hostile(0, tag, chunk(0, &[]), 0, vec![]), "chunk sample count is 0");
        let n = CHUNK_SAMPLES as u32 + 1;
        malformed(&hostile(n as u64, tag, chunk(n, &frame_of(tag, &many(n as usize), true)), 0, vec![]), "must be 1 to");
        let mut long = chunk(2, &good);
        long[4..8].copy_from_slice(&(good.len() as u32 + 1).to_le_bytes());
        malformed(&hostile(2, tag, long, 0, vec![]), "chunk zstd frame");
        let mut cut = chunk(2, &good);
        cut.extend_from_slice(&[1, 0, 0, 0, 9]);
        malformed(&hostile(2, tag, cut, 0, vec![]), "chunk stored length");
        // The frame declares, or inflates to, the bytes of 3 or 1 samples, not 2.
        malformed(&hostile(2, tag, chunk(2, &frame_of(tag, &many(3), true)), 0, vec![]), "declares");
        malformed(&hostile(2, tag, chunk(2, &frame_of(tag, &many(3), false)), 0, vec![]), "");
        malformed(&hostile(2, tag, chunk(2, &frame_of(tag, &many(1), false)), 0, vec![]), "inflates to 36 bytes");
        malformed(&hostile(2, tag, chunk(2, b"definitely not a zstd frame"), 0, vec![]), "corrupt");
        let mut trailing = good.clone();
        trailing.push(0);
        malformed(&hostile(2, tag, chunk(2, &trailing), 0, vec![]), "follow");
        // Counts that disagree with the mesh table.
        malformed(&hostile(3, tag, chunk(2, &good), 0, vec![]), "meshes cover 3 samples, the file has 2");
        // More than one samples section, or none.
        let others = [SMPS, SMPC, tags::SMPL].into_iter().filter(|&t| t != tag);
        for other in others {
            let both = hostile(2, tag, chunk(2, &good), 0, vec![SectionOut::zstd(other, &[0; 8], 1).unwrap()]);
            malformed(&both, "more than one samples section");
        }
        let neither = hostile(0, *b"XTRA", vec![], 0, vec![]);
        assert!(matches!(SamplesFile::read(&neither, &Limits::default()), Err(Error::UnknownRequiredSection { .. })));
        let mut neither_known = neither.clone();
        // Mark XTRA optional (flags of its table entry, the last), fixing the table CRC.
        let c = Container::parse(&neither, SAMPLES_MAGIC, "SCT samples", &[*b"XTRA", tags::GENR, tags::MESH, tags::INST], &Limits::default()).unwrap();
        let t = c.header.section_table_offset as usize;
        let last = t + 3 * SECTION_ENTRY_LEN;
        neither_known[last + 4..last + 8].copy_from_slice(&0u32.to_le_bytes());
        let crc = crc32fast::hash(&neither_known[t..t + 4 * SECTION_ENTRY_LEN]);
        neither_known[40..44].copy_from_slice(&crc.to_le_bytes());
        let hcrc = crc32fast::hash(&neither_known[..60]);
        neither_known[60..64].copy_from_slice(&hcrc.to_le_bytes());
        malformed(&neither_known, "missing");
        // The section itself is not zstd-flagged.
        malformed(&hostile(2, tag, chunk(2, &good), SectionEntry::ZSTD, vec![]), "zstd-flagged");
    }

    #[test]
    fn chunk_totals_are_limited_before_decoding() {
        for tag in [SMPS, SMPC] {
            let mut section = Vec::new();
            let full = frame_of(tag, &many(CHUNK_SAMPLES), true);
            for _ in 0..3 {
                section.extend(chunk(CHUNK_SAMPLES as u32, &full));
            }
            let total = 3 * CHUNK_SAMPLES as u64;
            let bytes = hostile(total, tag, section, 0, vec![]);
            assert_eq!(SamplesFile::read(&bytes, &Limits::default()).unwrap().samples.len() as u64, total);
            let limits = Limits { max_samples: total - 1, ..Limits::default() };
            assert!(matches!(SamplesFile::read(&bytes, &limits), Err(Error::LimitExceeded { what: "sample count", .. })));
            let limits = Limits { max_decompressed_bytes: 36 * total - 1, ..Limits::default() };
            assert!(matches!(SamplesFile::read(&bytes, &limits), Err(Error::LimitExceeded { what: "decompressed size", .. })));
        }
    }

    /// Files written before SMPS (chunks of columns) still read: a hand-made one around the
    /// chunk size and the tile size, and the seed the SMPC writer made, whose content the
    /// SMPS writer keeps.
    #[test]
    fn smpc_files_still_read() {
        let samples = many(2 * CHUNK_SAMPLES + PLANE_TILE + 1);
        let section: Vec<u8> = samples.chunks(CHUNK_SAMPLES).flat_map(|c| chunk(c.len() as u32, &frame_of(SMPC, c, true))).collect();
        let f = SamplesFile::read(&hostile(samples.len() as u64, SMPC, section, 0, vec![]), &Limits::default()).unwrap();
        assert_eq!(f.samples, samples);
        let seed = include_bytes!("../../fuzz/seeds/samples_reader/cube_smpc.samples");
        let old = SamplesFile::read(seed, &Limits::default()).unwrap();
        assert!(!old.samples.is_empty());
        let mut new = Vec::new();
        old.write_to(&mut new).unwrap();
        assert_eq!(chunk_counts(&new).iter().sum::<usize>(), old.samples.len());
        assert_eq!(SamplesFile::read(&new, &Limits::default()).unwrap(), old);
    }

    /// The SMPS fuzz seed is the SMPC seed's content rewritten by the SMPS writer (made with
    /// `cargo run --release -p sct-format --example samples_encoding -- cube_smpc.samples rewrite=cube_smps.samples`).
    #[test]
    fn smps_seed_is_the_smpc_seed_rewritten() {
        let smps = include_bytes!("../../fuzz/seeds/samples_reader/cube_smps.samples");
        assert!(!chunk_counts(smps).is_empty());
        let old = SamplesFile::read(include_bytes!("../../fuzz/seeds/samples_reader/cube_smpc.samples"), &Limits::default()).unwrap();
        assert_eq!(SamplesFile::read(smps, &Limits::default()).unwrap(), old);
    }

    /// The planes as spec §8 lays them out, on two samples: byte k of sample i at k·n + i,
    /// centres as wrapping differences of their bits (the first from 0), the rest as is.
    #[test]
    fn plane_layout_is_the_spec() {
        let a = Node { center: [1.0, -2.0, 0.5], radius: 0.25, normal: [0.0, 0.6, 0.8], cone: 0.0, area: 3.0, color: [1, 2, 3, 4] };
        let b = Node { center: [1.5, -0.0, f32::MIN_POSITIVE], color: [5, 6, 7, 8], ..a };
        let record = |s: &Node, centre: [u32; 3]| -> Vec<u8> {
            let floats = [s.radius, s.normal[0], s.normal[1], s.normal[2], s.area].map(f32::to_bits);
            centre.iter().chain(&floats).flat_map(|v| v.to_le_bytes()).chain(s.color).collect()
        };
        let delta: [u32; 3] = std::array::from_fn(|c| b.center[c].to_bits().wrapping_sub(a.center[c].to_bits()));
        let (ra, rb) = (record(&a, a.center.map(f32::to_bits)), record(&b, delta));
        let want: Vec<u8> = (0..SAMPLE_BYTES).flat_map(|k| [ra[k], rb[k]]).collect();
        let mut got = Vec::new();
        put_planes(&[a, b], &mut got);
        assert_eq!(got, want);
    }

    /// A reused plane buffer (longer, equal or shorter, holding other bytes) ends up exactly
    /// as a fresh one: `put_planes` does not clear it, so every byte must be written.
    #[test]
    fn put_planes_overwrites_a_reused_buffer() {
        let samples = many(3 * PLANE_TILE + 5);
        let mut fresh = Vec::new();
        put_planes(&samples, &mut fresh);
        for stale_len in [0, 1, fresh.len() - 1, fresh.len(), fresh.len() + 1, 3 * fresh.len()] {
            let mut reused = vec![0xa5u8; stale_len];
            put_planes(&samples, &mut reused);
            assert_eq!(reused, fresh, "stale buffer of {stale_len} bytes");
        }
        // The same buffer chunk after chunk, as the writer's scratch is used.
        let mut scratch = Vec::new();
        for part in samples.chunks(PLANE_TILE + 7).rev() {
            put_planes(part, &mut scratch);
            let mut want = Vec::new();
            put_planes(part, &mut want);
            assert_eq!(scratch, want);
        }
    }

    /// Any bit patterns (NaN payloads, infinities, −0, subnormals) come back bit for bit,
    /// across tiles and at every tile remainder.
    #[test]
    fn planes_are_lossless() {
        let mut x = 0x9e37_79b9_7f4a_7c15u64;
        let mut bits = || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x as u32
        };
        let special = [f32::NAN.to_bits() | 0x1234, f32::INFINITY.to_bits(), (-0.0f32).to_bits(), 1, u32::MAX, 0];
        for n in [1, 2, PLANE_TILE - 1, PLANE_TILE, PLANE_TILE + 1, 3 * PLANE_TILE + 17] {
            let samples: Vec<Node> = (0..n)
                .map(|i| {
                    let mut f = || f32::from_bits(if i % 5 == 0 { special[i % special.len()] } else { bits() });
                    Node { center: [f(), f(), f()], radius: f(), normal: [f(), f(), f()], cone: 0.0, area: f(), color: f().to_bits().to_le_bytes() }
                })
                .collect();
            let mut raw = Vec::new();
            put_planes(&samples, &mut raw);
            assert_eq!(raw.len(), n * SAMPLE_BYTES);
            let mut back = vec![Node::default(); n];
            samples_from_planes(&raw, &mut back);
            let key = |s: &Node| (s.center.map(f32::to_bits), s.radius.to_bits(), s.normal.map(f32::to_bits), s.area.to_bits(), s.color, s.cone.to_bits());
            assert!(samples.iter().zip(&back).all(|(a, b)| key(a) == key(b)), "{n} samples");
        }
    }
}
