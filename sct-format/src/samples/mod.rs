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

mod chunks;
#[cfg(test)]
mod tests;
mod writer;

use std::io::{Seek, SeekFrom, Write};
use std::path::Path;

use rayon::prelude::*;

use crate::container::{header_and_table_at, inflate_into, Container, SectionOut};
use crate::error::{Error, Result};
use crate::graph::{Generator, Similarity};
use crate::limits::Limits;
use crate::node::Node;
use crate::raw::{cursor::Put, tags, Cursor, SectionEntry, FILE_HEADER_LEN, SAMPLES_MAGIC, SECTION_ENTRY_LEN};
use chunks::*;
pub use writer::SamplesWriter;
use writer::*;

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

/// The name a writer gives the mesh holding a point cloud's samples (points of a
/// measurement, not samples of a surface; spec §8). A consumer may store such samples more
/// precisely (SCT 1.4 leaf refinement).
pub const POINT_CLOUD_MESH: &str = "points";

impl MeshEntry {
    /// Whether this mesh holds a point cloud's samples ([`POINT_CLOUD_MESH`]).
    pub fn is_point_cloud(&self) -> bool {
        self.name == POINT_CLOUD_MESH
    }
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
    /// The map as a scene-file affine transform ([`crate::affine::Affine`]).
    pub fn affine(&self) -> crate::affine::Affine {
        crate::affine::Affine { matrix: self.matrix }
    }

    /// Applies the map to a point.
    pub fn apply_point(&self, p: [f64; 3]) -> [f64; 3] {
        self.affine().apply_point(p)
    }

    /// Determinant of the linear part.
    pub fn determinant(&self) -> f64 {
        self.affine().determinant()
    }

    /// Finite entries and an invertible linear part (what the reader requires).
    pub fn is_valid(&self) -> bool {
        self.matrix.iter().flatten().all(|v| v.is_finite()) && self.determinant().is_normal()
    }

    /// The largest singular value of the linear part: the most it stretches any length, so a
    /// sphere of radius r maps into a sphere of radius r × this around the mapped centre.
    pub fn max_stretch(&self) -> f64 {
        self.affine().max_stretch()
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
