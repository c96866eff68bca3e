//! The samples file (spec §8): what `sct-voxelize` writes and `sct-build-tree` reads.
//!
//! Samples are grouped by mesh (contiguous ranges); the scene is every instance's mesh
//! placed by its similarity transform, so a mesh used by many glTF nodes is sampled once.
//! Sections: `GENR` (provenance JSON), `MESH` (mesh table), `INST` (instances) and `SMPL`
//! (samples, column by column, zstd-compressed).

use std::io::Write;
use std::path::Path;

use crate::container::{write_container, Container, SectionOut};
use crate::error::{Error, Result};
use crate::graph::{Generator, Similarity};
use crate::limits::Limits;
use crate::node::Node;
use crate::raw::{cursor::Put, tags, Cursor, SAMPLES_MAGIC};

/// Bytes per sample in the `SMPL` section (centre 12, radius 4, normal 12, area 4, RGBA 4).
pub const SAMPLE_BYTES: usize = 36;
const MESH_ENTRY_MIN: usize = 20;
const INST_ENTRY_BYTES: usize = 68;
const ZSTD_LEVEL: i32 = 3;

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

/// A whole samples file in memory.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SamplesFile {
    /// Provenance.
    pub generator: Generator,
    /// Meshes, in sample order.
    pub meshes: Vec<MeshEntry>,
    /// Placements; every mesh appears at least once.
    pub instances: Vec<SampleInstance>,
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
            samples,
        }
    }

    /// Checks the invariants the reader enforces, so a writer cannot produce a file its own
    /// reader refuses.
    pub fn check(&self) -> Result<()> {
        check_tables(&self.meshes, &self.instances, self.samples.len() as u64, 0).map_err(|e| match e {
            Error::Malformed { what, .. } => Error::Misuse(what),
            other => other,
        })
    }

    /// Writes the file to `w`; returns the number of bytes written.
    pub fn write_to<W: Write>(&self, w: W) -> Result<u64> {
        self.check()?;
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
        let sections = [
            SectionOut::plain(tags::GENR, genr),
            SectionOut::plain(tags::MESH, mesh),
            SectionOut::zstd(tags::INST, &inst, ZSTD_LEVEL)?,
            SectionOut::zstd(tags::SMPL, &encode_samples(&self.samples), ZSTD_LEVEL)?,
        ];
        Ok(write_container(SAMPLES_MAGIC, &sections, w)?.0)
    }

    /// Writes the file atomically (temporary file + rename).
    pub fn write_file(&self, path: &Path) -> Result<u64> {
        crate::atomic::write_atomic(path, |w| self.write_to(w))
    }

    /// Parses a samples file from bytes.
    pub fn read(data: &[u8], limits: &Limits) -> Result<Self> {
        let known = [tags::GENR, tags::MESH, tags::INST, tags::SMPL];
        let c = Container::parse(data, SAMPLES_MAGIC, "SCT samples", &known, limits)?;
        if c.sections.first().map(|e| e.tag) != Some(tags::GENR) {
            return Err(Error::malformed(c.header.section_table_offset, "the first section must be the generator (GENR)"));
        }
        let genr = c.single(tags::GENR)?;
        let generator = parse_generator(&c.section_bytes(genr, limits)?, genr.offset, limits)?;

        let e = c.single(tags::SMPL)?;
        let bytes = c.section_bytes(e, limits)?;
        let samples = decode_samples(&bytes, e.offset, limits)?;

        let e = c.single(tags::MESH)?;
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
        check_tables(&meshes, &instances, samples.len() as u64, e.offset)?;
        Ok(SamplesFile { generator, meshes, instances, samples })
    }

    /// Reads a samples file from disk.
    pub fn read_file(path: &Path, limits: &Limits) -> Result<Self> {
        let data = std::fs::read(path).map_err(|e| Error::io(path, e))?;
        Self::read(&data, limits)
    }

    /// Samples of mesh `m`.
    pub fn mesh_samples(&self, m: usize) -> &[Node] {
        let e = &self.meshes[m];
        &self.samples[e.first as usize..(e.first + e.count) as usize]
    }
}

fn check_tables(meshes: &[MeshEntry], instances: &[SampleInstance], samples: u64, offset: u64) -> Result<()> {
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
    if let Some(m) = used.iter().position(|u| !u) {
        return Err(Error::malformed(offset, format!("mesh {m} has no instance")));
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

/// Column layout: count, then all centres, radii, normals, areas, colours.
fn encode_samples(samples: &[Node]) -> Vec<u8> {
    let mut out = Vec::with_capacity(8 + samples.len() * SAMPLE_BYTES);
    out.put_u64(samples.len() as u64);
    for s in samples {
        s.center.iter().for_each(|v| out.put_f32(*v));
    }
    samples.iter().for_each(|s| out.put_f32(s.radius));
    for s in samples {
        s.normal.iter().for_each(|v| out.put_f32(*v));
    }
    samples.iter().for_each(|s| out.put_f32(s.area));
    samples.iter().for_each(|s| out.extend_from_slice(&s.color));
    out
}

fn decode_samples(bytes: &[u8], offset: u64, limits: &Limits) -> Result<Vec<Node>> {
    let mut c = Cursor::new(bytes, offset);
    let n = c.count(SAMPLE_BYTES, "sample count")?;
    Limits::check("sample count", n as u64, limits.max_samples)?;
    let f32s = |b: &[u8]| -> Vec<f32> { b.chunks_exact(4).map(|x| f32::from_le_bytes([x[0], x[1], x[2], x[3]])).collect() };
    let centers = f32s(c.take(n * 12, "sample centres")?);
    let radii = f32s(c.take(n * 4, "sample radii")?);
    let normals = f32s(c.take(n * 12, "sample normals")?);
    let areas = f32s(c.take(n * 4, "sample areas")?);
    let colors = c.take(n * 4, "sample colours")?;
    c.finish("samples")?;
    Ok((0..n)
        .map(|i| Node {
            center: [centers[3 * i], centers[3 * i + 1], centers[3 * i + 2]],
            radius: radii[i],
            normal: [normals[3 * i], normals[3 * i + 1], normals[3 * i + 2]],
            cone: 0.0,
            area: areas[i],
            color: [colors[4 * i], colors[4 * i + 1], colors[4 * i + 2], colors[4 * i + 3]],
        })
        .collect())
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

    #[test]
    fn round_trip() {
        let f = file();
        let mut bytes = Vec::new();
        let n = f.write_to(&mut bytes).unwrap();
        assert_eq!(n as usize, bytes.len());
        assert_eq!(SamplesFile::read(&bytes, &Limits::default()).unwrap(), f);
    }

    #[test]
    fn every_truncation_is_an_error() {
        let mut bytes = Vec::new();
        file().write_to(&mut bytes).unwrap();
        for len in 0..bytes.len() {
            assert!(SamplesFile::read(&bytes[..len], &Limits::default()).is_err(), "truncated at {len}");
        }
    }

    #[test]
    fn every_bit_flip_is_detected() {
        let mut bytes = Vec::new();
        file().write_to(&mut bytes).unwrap();
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
