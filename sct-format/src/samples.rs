//! The samples file (spec §8): what `sct-voxelize` writes and `sct-build-tree` reads.
//!
//! Samples are grouped by mesh (contiguous ranges); the scene is every instance's mesh
//! placed by its similarity transform, so a mesh used by many glTF nodes is sampled once.
//! Sections: `GENR` (provenance JSON), `MESH` (mesh table), `INST` (instances), `SMPL`
//! (samples, column by column, zstd-compressed) and, only when some placement is not a
//! similarity, `AFFI` (affine instances, flagged required so that a reader that predates it
//! refuses the file instead of silently dropping those placements).

use std::borrow::Cow;
use std::io::{Seek, SeekFrom, Write};
use std::path::Path;

use rayon::prelude::*;

use crate::container::{header_and_table, Container, SectionOut};
use crate::error::{Error, Result};
use crate::graph::{Generator, Similarity};
use crate::limits::Limits;
use crate::node::Node;
use crate::raw::{cursor::Put, tags, Cursor, SectionEntry, FILE_HEADER_LEN, SAMPLES_MAGIC, SECTION_ENTRY_LEN};

/// Bytes per sample in the `SMPL` section (centre 12, radius 4, normal 12, area 4, RGBA 4).
pub const SAMPLE_BYTES: usize = 36;
const MESH_ENTRY_MIN: usize = 20;
const INST_ENTRY_BYTES: usize = 68;
const AFFI_ENTRY_BYTES: usize = 100;
/// Section tag of the affine instances (spec §8); local to the samples file.
pub const AFFI: [u8; 4] = *b"AFFI";
/// zstd level of the samples file's sections. The file is an intermediate between the
/// toolchain's own tools, so speed wins: level 1 writes the bunny's 2.34 M samples in 0.24 s
/// instead of level 3's 0.35 s for a 2.6 % larger file, and reads as fast.
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
            meshes: vec![MeshEntry { name: name.to_string(), first: 0, count: samples.len() as u64 }],
            instances: vec![SampleInstance { mesh: 0, transform: Similarity::IDENTITY }],
            affine_instances: Vec::new(),
            samples,
        }
    }

    /// Checks the invariants the reader enforces, so a writer cannot produce a file its own
    /// reader refuses.
    pub fn check(&self) -> Result<()> {
        check_tables(&self.meshes, &self.instances, &self.affine_instances, self.samples.len() as u64, &TableOffsets { mesh: 0, inst: 0, affi: 0 }).map_err(|e| match e {
            Error::Malformed { what, .. } => Error::Misuse(what),
            other => other,
        })
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

    /// Writes the sections in table order, streaming `SMPL` ([`stream_samples`]); the header
    /// and section table, reserved as zeros, are filled in last by seeking back.
    fn write_seekable<W: Write + Seek>(&self, w: &mut W) -> Result<u64> {
        let genr = serde_json::to_vec(&self.generator).map_err(|e| Error::Misuse(format!("generator: {e}")))?;
        let mut mesh = Vec::new();
        mesh.put_u64(self.meshes.len() as u64);
        for m in &self.meshes {
            mesh.put_u64(m.first);
            mesh.put_u64(m.count);
            mesh.put_str(&m.name);
        }
        let mut inst = Vec::with_capacity(8 + self.instances.len() * INST_ENTRY_BYTES);
        inst.put_u64(self.instances.len() as u64);
        for i in &self.instances {
            inst.put_u32(i.mesh);
            put_similarity(&mut inst, &i.transform);
        }
        let before = [SectionOut::plain(tags::GENR, genr), SectionOut::plain(tags::MESH, mesh), SectionOut::zstd(tags::INST, &inst, ZSTD_LEVEL)?];
        // Only when needed, so files without such placements stay readable by 1.0 readers.
        let affi = if self.affine_instances.is_empty() {
            None
        } else {
            let mut affi = Vec::with_capacity(8 + self.affine_instances.len() * AFFI_ENTRY_BYTES);
            affi.put_u64(self.affine_instances.len() as u64);
            for a in &self.affine_instances {
                affi.put_u32(a.mesh);
                a.matrix.iter().flatten().for_each(|v| affi.put_f64(*v));
            }
            Some(SectionOut::zstd(AFFI, &affi, ZSTD_LEVEL)?)
        };
        let count = before.len() + 1 + affi.iter().len();
        let start = w.stream_position()?;
        let head_len = FILE_HEADER_LEN + count * SECTION_ENTRY_LEN;
        w.write_all(&vec![0u8; head_len])?;
        let mut offset = head_len as u64;
        let mut entries = Vec::with_capacity(count);
        for s in &before {
            w.write_all(&s.stored)?;
            entries.push(s.entry(offset));
            offset += s.stored.len() as u64;
        }
        // Each zstd worker holds about two jobs' buffers (2 MiB of input each at level 1):
        // more than a few cost memory and outrun the disk.
        let workers = rayon::current_num_threads().clamp(1, MAX_ZSTD_WORKERS) as u32;
        let smpl = SectionEntry { offset, ..stream_samples(&self.samples, workers, w)? };
        offset += smpl.stored_len;
        entries.push(smpl);
        if let Some(s) = &affi {
            w.write_all(&s.stored)?;
            entries.push(s.entry(offset));
            offset += s.stored.len() as u64;
        }
        w.seek(SeekFrom::Start(start))?;
        w.write_all(&header_and_table(SAMPLES_MAGIC, &entries, offset))?;
        w.seek(SeekFrom::Start(start + offset))?;
        Ok(offset)
    }

    /// Parses a samples file from bytes.
    pub fn read(data: &[u8], limits: &Limits) -> Result<Self> {
        let (mut file, smpl, offset, at) = Self::read_tables(data, limits)?;
        file.samples = decode_samples(&smpl, offset, limits)?;
        file.check_tables(&at)?;
        Ok(file)
    }

    /// Everything but the samples, which come back as the `SMPL` section's bytes (after the
    /// CRC check and decompression) with the section's offset, and the offsets the table
    /// checks report.
    fn read_tables<'a>(data: &'a [u8], limits: &Limits) -> Result<(Self, Cow<'a, [u8]>, u64, TableOffsets)> {
        let known = [tags::GENR, tags::MESH, tags::INST, tags::SMPL, AFFI];
        let c = Container::parse(data, SAMPLES_MAGIC, "SCT samples", &known, limits)?;
        if c.sections.first().map(|e| e.tag) != Some(tags::GENR) {
            return Err(Error::malformed(c.header.section_table_offset, "the first section must be the generator (GENR)"));
        }
        let genr = c.single(tags::GENR)?;
        let generator = parse_generator(&c.section_bytes(genr, limits)?, genr.offset, limits)?;

        let e = c.single(tags::SMPL)?;
        let smpl = c.section_bytes(e, limits)?;
        let smpl_offset = e.offset;

        let e = c.single(tags::MESH)?;
        let mesh_offset = e.offset;
        let bytes = c.section_bytes(e, limits)?;
        let mut cur = Cursor::new(&bytes, e.offset);
        let n = cur.count(MESH_ENTRY_MIN, "mesh count")?;
        let mut meshes = Vec::with_capacity(n);
        for _ in 0..n {
            let first = cur.u64("mesh first sample")?;
            let count = cur.u64("mesh sample count")?;
            let name = cur.string(limits.max_string_bytes, "mesh name")?;
            meshes.push(MeshEntry { name, first, count });
        }
        cur.finish("mesh table")?;

        let e = c.single(tags::INST)?;
        let bytes = c.section_bytes(e, limits)?;
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
            let bytes = c.section_bytes(e, limits)?;
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
        // The tables are checked against the sample count once the samples are decoded.
        let file = SamplesFile { generator, meshes, instances, affine_instances, samples: Vec::new() };
        Ok((file, smpl, smpl_offset, offsets))
    }

    /// The table checks that need the samples (see [`check_tables`]).
    fn check_tables(&self, at: &TableOffsets) -> Result<()> {
        check_tables(&self.meshes, &self.instances, &self.affine_instances, self.samples.len() as u64, at)
    }

    /// Reads a samples file from disk. The file's bytes are freed before the samples are
    /// decoded from the (decompressed) column section, so the peak is columns + samples
    /// (76 bytes a sample), not file + columns + samples (92).
    pub fn read_file(path: &Path, limits: &Limits) -> Result<Self> {
        Ok(Self::read_file_impl(path, limits, false)?.0)
    }

    /// [`Self::read_file`], also returning the BLAKE3 hash (lowercase hex) of the bytes read,
    /// computed while the samples are decompressed: provenance without reading the file
    /// twice, and of exactly the bytes the samples came from.
    pub fn read_file_hashed(path: &Path, limits: &Limits) -> Result<(Self, String)> {
        let (file, hash) = Self::read_file_impl(path, limits, true)?;
        Ok((file, hash.unwrap_or_default()))
    }

    fn read_file_impl(path: &Path, limits: &Limits, hash: bool) -> Result<(Self, Option<String>)> {
        let data = std::fs::read(path).map_err(|e| Error::io(path, e))?;
        let (hash, tables) = rayon::join(|| hash.then(|| blake3::hash(&data).to_hex().to_string()), || Self::read_tables(&data, limits));
        let (mut file, smpl, offset, at) = tables?;
        file.samples = match smpl {
            Cow::Borrowed(b) => decode_samples(b, offset, limits)?,
            Cow::Owned(columns) => {
                drop(data);
                decode_samples(&columns, offset, limits)?
            }
        };
        file.check_tables(&at)?;
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

/// Most zstd threads compressing the column section.
const MAX_ZSTD_WORKERS: usize = 4;
/// Samples laid out per chunk of the column section before compression.
const CHUNK_SAMPLES: usize = 1 << 16;

/// Streams the `SMPL` section to `w`: one zstd frame of the column layout (count, then all
/// centres, radii, normals, areas, colours). The columns are laid out a chunk at a time and
/// compressed by `workers` zstd threads while this thread lays out the next chunk and
/// writes what is done, so neither the columns (36 bytes a sample) nor the compressed
/// section is ever held whole. zstd's multithreaded frames are the same bytes for every
/// worker count ≥ 1 (it cuts jobs by size, not by workers; a section smaller than one job
/// is compressed on this thread, also for every count). Returns the section's entry (at
/// offset 0).
fn stream_samples(samples: &[Node], workers: u32, w: &mut dyn Write) -> Result<SectionEntry> {
    use zstd::stream::raw::{Encoder, InBuffer, Operation, OutBuffer};
    let raw_len = 8 + samples.len() as u64 * SAMPLE_BYTES as u64;
    let mut enc = Encoder::new(ZSTD_LEVEL)?;
    enc.set_parameter(zstd::zstd_safe::CParameter::NbWorkers(workers.max(1)))?;
    enc.set_pledged_src_size(Some(raw_len))?;
    let mut out = vec![0u8; zstd::zstd_safe::CCtx::out_size()];
    let mut crc = crc32fast::Hasher::new();
    let mut stored = 0u64;
    let mut put = |b: &[u8]| -> Result<()> {
        crc.update(b);
        stored += b.len() as u64;
        Ok(w.write_all(b)?)
    };
    // Feeds bytes to the encoder, passing on what comes out.
    let mut feed = |enc: &mut Encoder, data: &[u8]| -> Result<()> {
        let mut inb = InBuffer::around(data);
        while inb.pos() < data.len() {
            let mut ob = OutBuffer::around(&mut out[..]);
            enc.run(&mut inb, &mut ob)?;
            put(ob.as_slice())?;
        }
        Ok(())
    };
    feed(&mut enc, &(samples.len() as u64).to_le_bytes())?;
    let columns: [fn(&Node, &mut Vec<u8>); 5] = [
        |s, c| s.center.iter().for_each(|v| c.put_f32(*v)),
        |s, c| c.put_f32(s.radius),
        |s, c| s.normal.iter().for_each(|v| c.put_f32(*v)),
        |s, c| c.put_f32(s.area),
        |s, c| c.extend_from_slice(&s.color),
    ];
    let mut chunk: Vec<u8> = Vec::with_capacity(CHUNK_SAMPLES * 12);
    let mut fed = 8u64;
    for column in columns {
        for part in samples.chunks(CHUNK_SAMPLES) {
            chunk.clear();
            part.iter().for_each(|s| column(s, &mut chunk));
            feed(&mut enc, &chunk)?;
            fed += chunk.len() as u64;
        }
    }
    loop {
        let mut ob = OutBuffer::around(&mut out[..]);
        let left = enc.finish(&mut ob, true)?;
        put(ob.as_slice())?;
        if left == 0 {
            break;
        }
    }
    if fed != raw_len {
        return Err(Error::Misuse(format!("sample columns are {fed} bytes, {raw_len} expected (bug)")));
    }
    Ok(SectionEntry { tag: tags::SMPL, flags: SectionEntry::REQUIRED | SectionEntry::ZSTD, offset: 0, stored_len: stored, raw_len, crc: crc.finalize() })
}

fn decode_samples(bytes: &[u8], offset: u64, limits: &Limits) -> Result<Vec<Node>> {
    let mut c = Cursor::new(bytes, offset);
    let n = c.count(SAMPLE_BYTES, "sample count")?;
    Limits::check("sample count", n as u64, limits.max_samples)?;
    let centers = c.take(n * 12, "sample centres")?;
    let radii = c.take(n * 4, "sample radii")?;
    let normals = c.take(n * 12, "sample normals")?;
    let areas = c.take(n * 4, "sample areas")?;
    let colors = c.take(n * 4, "sample colours")?;
    c.finish("samples")?;
    // Straight from the column bytes: no intermediate f32 columns (36 bytes a sample at the
    // reader's peak). In parallel, zipping fixed-size records of the five columns (no
    // per-value bounds checks), collected straight into the output.
    Ok(centers
        .par_chunks_exact(12)
        .zip(radii.par_chunks_exact(4))
        .zip(normals.par_chunks_exact(12))
        .zip(areas.par_chunks_exact(4))
        .zip(colors.par_chunks_exact(4))
        .with_min_len(4096)
        .map(|((((c, r), nm), ar), co)| Node {
            center: f3(c),
            radius: f1(r),
            normal: f3(nm),
            cone: 0.0,
            area: f1(ar),
            color: [co[0], co[1], co[2], co[3]],
        })
        .collect())
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
        f.meshes.push(MeshEntry { name: "second".into(), first: 100, count: 2 });
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

    /// Table errors point at the table holding the bad entry, also when AFFI is present.
    #[test]
    fn table_errors_point_at_their_section() {
        let offset_of = |bytes: &[u8], tag: [u8; 4]| {
            let known = [tags::GENR, tags::MESH, tags::INST, tags::SMPL, AFFI];
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
        let old_known = [tags::GENR, tags::MESH, tags::INST, tags::SMPL];
        // A reader that predates AFFI still reads files without it …
        assert!(Container::parse(&plain, SAMPLES_MAGIC, "SCT samples", &old_known, &Limits::default()).is_ok());
        // … and refuses files with it rather than silently dropping placements.
        let e = Container::parse(&with, SAMPLES_MAGIC, "SCT samples", &old_known, &Limits::default()).unwrap_err();
        assert!(e.to_string().contains("AFFI"), "{e}");
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

    /// The column section is the same bytes for every zstd worker count, over several of
    /// zstd's jobs (2 MiB of input each at level 1), and decodes to the samples.
    #[test]
    fn samples_section_does_not_depend_on_workers() {
        let samples: Vec<Node> = (0..600_000u32).map(|i| Node { radius: (i as f32).sqrt(), ..sample(i) }).collect();
        let mut first: Option<Vec<u8>> = None;
        for workers in [1, 2, 3] {
            let mut out = Vec::new();
            let e = stream_samples(&samples, workers, &mut out).unwrap();
            assert_eq!((e.stored_len as usize, e.crc), (out.len(), crc32fast::hash(&out)));
            assert_eq!(e.raw_len, 8 + 36 * samples.len() as u64);
            match &first {
                None => first = Some(out),
                Some(f) => assert!(*f == out, "{workers} workers"),
            }
        }
        let raw = zstd::stream::decode_all(&first.unwrap()[..]).unwrap();
        assert_eq!(decode_samples(&raw, 0, &Limits::default()).unwrap(), samples);
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
}
