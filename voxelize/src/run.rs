//! The whole job of `sct-voxelize`: load inputs into one scene, sample, write atomically.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use sct_format::samples::{AffineInstance, MeshEntry, SampleInstance, SamplesFile, SamplesWriter};
use sct_format::{Generator, Node, Similarity, SourceRef};
use serde_json::json;

use crate::error::{Error, LoadError};
use crate::load::{load, load_and_hash, LoadOptions};
use crate::mesh::{Instance, LoadedScene};
use crate::sample::{sample_points_into, sample_scene_into, AreaMode, Density, SampleOptions, Sampled, Sink, StreamError, Streamed};

/// Options of a run.
#[derive(Clone, Debug)]
pub struct Options {
    /// Input mesh files; all are sampled in one grid.
    pub inputs: Vec<PathBuf>,
    /// Output samples file (`None`: sample but write nothing — a dry run).
    pub output: Option<PathBuf>,
    /// Loader options.
    pub load: LoadOptions,
    /// Sampler options.
    pub sample: SampleOptions,
}

/// What a run did (printed as JSON by `--json`).
#[derive(Clone, Debug, serde::Serialize)]
pub struct Summary {
    /// Input files with hashes (resources included).
    pub inputs: Vec<SourceRef>,
    /// Output path.
    pub output: Option<String>,
    /// Bytes written.
    pub output_bytes: u64,
    /// Sampler.
    pub method: String,
    /// Area mode.
    pub area_mode: String,
    /// Whether same-voxel samples were merged.
    pub merged: bool,
    /// Triangles read (once per mesh).
    pub triangles_read: u64,
    /// Zero-area triangles skipped.
    pub triangles_degenerate: u64,
    /// Polygons triangulated by CDT.
    pub polygons_triangulated: u64,
    /// Point/line primitives skipped.
    pub primitives_skipped: u64,
    /// Triangles in the scene counting every instance.
    pub triangles_instanced: u64,
    /// Meshes written.
    pub meshes: u64,
    /// Instances written (similarity and affine).
    pub instances: u64,
    /// Of those, affine (non-similarity) instances (samples-file `AFFI` section).
    pub affine_instances: u64,
    /// Samples before merging.
    pub samples_before_merge: u64,
    /// Samples written.
    pub samples: u64,
    /// Samples dropped by alpha.
    pub samples_dropped_alpha: u64,
    /// Point-cloud points turned into samples.
    pub point_samples: u64,
    /// Voxel edge length (world units).
    pub voxel_size: f64,
    /// How it was chosen.
    pub voxel_size_reason: String,
    /// Sum of sample areas over the scene (instances applied).
    pub sample_area: f64,
    /// Mesh surface area over the scene.
    pub mesh_area: f64,
    /// (sample_area − mesh_area) / mesh_area.
    pub area_relative_error: f64,
    /// Seconds spent loading.
    pub seconds_load: f64,
    /// Seconds spent sampling. With an output file this includes compressing and writing
    /// the samples, which overlap sampling; a dry run times the sampler alone.
    pub seconds_sample: f64,
    /// Seconds spent finishing the output after sampling (last chunk, tables, sync, rename).
    pub seconds_write: f64,
    /// Total seconds.
    pub seconds_total: f64,
    /// Samples (after merging) per second of `seconds_sample`.
    pub samples_per_second: f64,
    /// Non-fatal problems.
    pub warnings: Vec<String>,
    /// Files the inputs reference that were not found (a missing MTL or texture; see
    /// [`crate::mesh::LoadedScene::missing`]).
    pub missing_inputs: Vec<String>,
}

/// Loads every input into one scene (indices offset so meshes, materials and images stay
/// distinct).
pub fn load_all(inputs: &[PathBuf], opts: &LoadOptions) -> Result<LoadedScene, Error> {
    load_inputs(inputs, opts, false).map(|(scene, _)| scene)
}

/// [`load_all`], and with `hash` the BLAKE3 of each input's bytes as they were loaded.
fn load_inputs(inputs: &[PathBuf], opts: &LoadOptions, hash: bool) -> Result<(LoadedScene, HashMap<PathBuf, String>), Error> {
    let mut all = LoadedScene::default();
    let mut hashes = HashMap::new();
    for path in inputs {
        let s = if hash {
            let (s, h) = load_and_hash(path, opts)?;
            hashes.insert(path.clone(), h);
            s
        } else {
            load(path, opts)?
        };
        let (mo, mato, io) = (all.meshes.len(), all.materials.len(), all.images.len());
        for mut m in s.meshes {
            for p in &mut m.primitives {
                p.material = p.material.map(|x| x + mato);
            }
            all.meshes.push(m);
        }
        for mut mat in s.materials {
            if let Some(t) = &mut mat.texture {
                t.image += io;
            }
            if let Some(t) = &mut mat.alpha_texture {
                t.image += io;
            }
            all.materials.push(mat);
        }
        all.images.extend(s.images);
        all.instances.extend(s.instances.into_iter().map(|i| Instance { mesh: i.mesh + mo, transform: i.transform }));
        match (&mut all.points, s.points) {
            (Some(a), Some(b)) => {
                let (na, nb) = (a.positions.len(), b.positions.len());
                a.normals = match (a.normals.take(), b.normals) {
                    (Some(mut x), Some(y)) => {
                        x.extend(y);
                        Some(x)
                    }
                    (x, y) => {
                        let x = x.unwrap_or_else(|| vec![[0.0; 3]; na]);
                        let y = y.unwrap_or_else(|| vec![[0.0; 3]; nb]);
                        Some(x.into_iter().chain(y).collect())
                    }
                };
                a.colors = match (a.colors.take(), b.colors) {
                    (None, None) => None,
                    (x, y) => Some(
                        x.unwrap_or_else(|| vec![[0.8, 0.8, 0.8, 1.0]; na]).into_iter().chain(y.unwrap_or_else(|| vec![[0.8, 0.8, 0.8, 1.0]; nb])).collect(),
                    ),
                };
                a.positions.extend(b.positions);
            }
            (a @ None, b) => *a = b,
            _ => {}
        }
        all.warnings.extend(s.warnings);
        all.stats.triangles_read += s.stats.triangles_read;
        all.stats.degenerate_triangles += s.stats.degenerate_triangles;
        all.stats.polygons_triangulated += s.stats.polygons_triangulated;
        all.stats.skipped_primitives += s.stats.skipped_primitives;
        all.files.extend(s.files);
        all.missing.extend(s.missing);
    }
    all.missing.sort();
    all.missing.dedup();
    Ok((all, hashes))
}

/// A samples file's tables: everything but its samples, which [`sample_into`]'s sink received
/// in file order.
#[derive(Clone, Debug)]
pub struct Tables {
    /// Provenance.
    pub generator: Generator,
    /// Meshes, in sample order.
    pub meshes: Vec<MeshEntry>,
    /// Similarity placements.
    pub instances: Vec<SampleInstance>,
    /// Affine placements.
    pub affine_instances: Vec<AffineInstance>,
}

impl Tables {
    /// The samples file of these tables with their samples.
    pub fn with_samples(self, samples: Vec<Node>) -> SamplesFile {
        let Tables { generator, meshes, instances, affine_instances } = self;
        SamplesFile { generator, meshes, instances, affine_instances, samples }
    }

    /// Samples the tables describe.
    pub fn sample_count(&self) -> u64 {
        self.meshes.iter().map(|m| m.count).sum()
    }
}

/// One sampled mesh as the tables see it: name, sample count, similarity and affine
/// placements, two-sidedness.
type MeshRow<'a> = (&'a str, u64, &'a [Similarity], &'a [[[f64; 4]; 3]], bool);

/// The tables of sampled meshes, in sample order, followed by `points` point-cloud samples.
/// A mesh without samples (only points/lines, or fully transparent) has nothing to build a
/// tree from; it is left out (and reported by [`sample_into`]).
fn tables<'a>(meshes: impl Iterator<Item = MeshRow<'a>>, points: (u64, bool), generator: Generator) -> Tables {
    let mut t = Tables { generator, meshes: Vec::new(), instances: Vec::new(), affine_instances: Vec::new() };
    let mut first = 0u64;
    for (name, count, sims, affine, two_sided) in meshes.filter(|m| m.1 > 0) {
        let idx = t.meshes.len() as u32;
        t.meshes.push(MeshEntry { name: name.to_string(), first, count, two_sided });
        first += count;
        t.instances.extend(sims.iter().map(|s| SampleInstance { mesh: idx, transform: *s }));
        t.affine_instances.extend(affine.iter().map(|a| AffineInstance { mesh: idx, matrix: *a }));
    }
    let (points, points_two_sided) = points;
    if points > 0 {
        let idx = t.meshes.len() as u32;
        t.meshes.push(MeshEntry { name: sct_format::samples::POINT_CLOUD_MESH.into(), first, count: points, two_sided: points_two_sided });
        t.instances.push(SampleInstance { mesh: idx, transform: Similarity::IDENTITY });
    }
    t
}

/// Assembles the samples file of a sampled scene (plus an optional point cloud, two-sided
/// when it has no normals).
pub fn to_samples_file(sampled: &Sampled, points: Vec<Node>, points_two_sided: bool, generator: Generator) -> SamplesFile {
    let rows = sampled.meshes.iter().map(|m| (m.name.as_str(), m.samples.len() as u64, &m.instances[..], &m.affine[..], m.two_sided));
    let t = tables(rows, (points.len() as u64, points_two_sided), generator);
    let mut samples = Vec::with_capacity(t.sample_count() as usize);
    for m in &sampled.meshes {
        samples.extend_from_slice(&m.samples);
    }
    samples.extend(points);
    t.with_samples(samples)
}

/// BLAKE3 of a source, streamed (no second copy of a big GLB in memory). A resource that
/// vanished since it was loaded is an error: provenance that leaves it out would let batch
/// mode call the output up to date forever.
fn hash_source(f: &Path) -> Result<String, Error> {
    sct_format::atomic::hash_file(f).map_err(|e| {
        let source = match e {
            sct_format::Error::Io { source, .. } => source,
            other => std::io::Error::other(other.to_string()),
        };
        Error::Load(LoadError::Io { path: f.to_path_buf(), source })
    })
}

/// Whether `f` was modified after `started` (and not dated in the future, which says
/// nothing about this run: archives can carry such dates).
fn changed_since(f: &Path, started: std::time::SystemTime) -> bool {
    let now = std::time::SystemTime::now();
    std::fs::metadata(f).and_then(|m| m.modified()).is_ok_and(|t| t > started && t <= now)
}

/// Runs the whole job: samples `opts.inputs` into `opts.output`, written atomically; a dry
/// run (no output) discards the samples as they are made. `progress(done, total)` reports
/// sampled triangles.
pub fn run(opts: &Options, progress: &(dyn Fn(u64, u64) + Sync)) -> Result<Summary, Error> {
    let t0 = Instant::now();
    let mut summary = match &opts.output {
        Some(path) => sample_to_file(opts, path, progress)?,
        None => sample_into(opts, progress, &mut |_| Ok(()))?.1,
    };
    summary.output = opts.output.as_ref().map(|p| p.display().to_string());
    summary.seconds_total = t0.elapsed().as_secs_f64();
    Ok(summary)
}

/// Samples into the samples file at `path`, written atomically as the samples are made
/// ([`SamplesWriter`]: chunks are compressed and written while the sampler makes later
/// slabs, so no run holds all its samples). `seconds_write` is the finishing step alone.
fn sample_to_file(opts: &Options, path: &Path, progress: &(dyn Fn(u64, u64) + Sync)) -> Result<Summary, Error> {
    let write_error = |source| Error::Write { path: path.to_path_buf(), source };
    let written = sct_format::atomic::write_atomic_with(path, |w| -> Result<Summary, ToFile> {
        let mut out = SamplesWriter::new(w)?;
        let (tables, mut summary) = sample_into(opts, progress, &mut |nodes| out.push(nodes).map_err(write_error)).map_err(ToFile::Run)?;
        let t = Instant::now();
        summary.output_bytes = out.finish(&tables.generator, &tables.meshes, &tables.instances, &tables.affine_instances)?;
        summary.seconds_write = t.elapsed().as_secs_f64();
        Ok(summary)
    });
    written.map_err(|e| match e {
        ToFile::Run(e) => e,
        ToFile::Format(source) => write_error(source),
    })
}

/// How writing a samples file while sampling fails: the run's own error, or the file's.
enum ToFile {
    Run(Error),
    Format(sct_format::Error),
}

impl From<sct_format::Error> for ToFile {
    fn from(e: sct_format::Error) -> Self {
        ToFile::Format(e)
    }
}

/// Loads and samples `opts.inputs` into a samples file in memory (`opts.output` is
/// ignored): what `sct-build-tree` uses to convert a mesh in one step.
pub fn sample_in_memory(opts: &Options, progress: &(dyn Fn(u64, u64) + Sync)) -> Result<(SamplesFile, Summary), Error> {
    let mut samples = Vec::new();
    let (tables, summary) = sample_into(opts, progress, &mut |nodes| {
        samples.extend_from_slice(nodes);
        Ok(())
    })?;
    Ok((tables.with_samples(samples), summary))
}

/// Loads and samples `opts.inputs` (`opts.output` is ignored), handing the samples to `sink`
/// in runs, in the order of the samples file whose tables it returns; a sink error stops it
/// and is returned.
pub fn sample_into(
    opts: &Options,
    progress: &(dyn Fn(u64, u64) + Sync),
    sink: &mut Sink<'_, Error>,
) -> Result<(Tables, Summary), Error> {
    let t0 = Instant::now();
    if opts.inputs.is_empty() {
        return Err(Error::Usage("no input file".into()));
    }
    if let Density::VoxelSize(h) = opts.sample.density {
        if !(h.is_finite() && h > 0.0) {
            return Err(Error::Usage(format!("--voxel-size must be a positive number, got {h}")));
        }
    }
    // The inputs are hashed as they are loaded (the hash of the very bytes the samples are
    // made from), and the resources they name (MTL, textures, buffers), hashed afterwards,
    // are checked for changes made while we ran: a hash that described other bytes than
    // those sampled would let batch mode call a stale output up to date forever.
    let started = std::time::SystemTime::now();
    let (scene, hashes) = load_inputs(&opts.inputs, &opts.load, true)?;
    let t_load = t0.elapsed().as_secs_f64();
    let t1 = Instant::now();
    let has_tris = scene.meshes.iter().any(|m| m.triangle_count() > 0);
    let sampled = if has_tris || scene.points.is_none() {
        sample_scene_into(&scene, &opts.sample, progress, &mut |_, nodes| sink(nodes)).map_err(|e| match e {
            StreamError::Sampling(msg) => Error::Sampling(msg),
            StreamError::Sink(e) => e,
        })?
    } else {
        Streamed {
            meshes: Vec::new(),
            voxel: crate::sample::VoxelChoice { size: 0.0, reason: "point cloud: no voxelization".into() },
            stats: Default::default(),
        }
    };
    let mut n_points = 0u64;
    if let Some(pc) = &scene.points {
        sample_points_into(pc, &mut |nodes| {
            n_points += nodes.len() as u64;
            sink(nodes)
        })?;
    }
    let t_sample = t1.elapsed().as_secs_f64();
    let mut sources = Vec::new();
    let mut seen = std::collections::HashSet::new();
    for f in &scene.files {
        if !seen.insert(f.clone()) {
            continue;
        }
        let blake3 = match hashes.get(f) {
            Some(h) => h.clone(),
            None => {
                let h = hash_source(f)?;
                if changed_since(f, started) {
                    let msg = "changed while it was being read; run again";
                    return Err(Error::Load(LoadError::Io { path: f.clone(), source: std::io::Error::other(msg) }));
                }
                h
            }
        };
        sources.push(SourceRef { path: f.display().to_string(), blake3 });
    }
    let s = &opts.sample;
    let density = match s.density {
        Density::VoxelSize(h) => json!({"voxel_size": h}),
        Density::View { pixels } => json!({"view": {"pixels": pixels}}),
        Density::Auto { k, gamma, min_base } => json!({"auto": {"k": k, "gamma": gamma, "min_base": min_base}}),
        Density::Screen { pixels, resolution, distance, fov_deg } => {
            json!({"screen": {"pixels": pixels, "resolution": resolution, "distance": distance, "fov_deg": fov_deg}})
        }
    };
    let mut generator = Generator {
        tool: "sct-voxelize".into(),
        version: env!("CARGO_PKG_VERSION").into(),
        parameters: json!({
            "method": s.method.name(),
            "density": density,
            "voxel_size": sampled.voxel.size,
            "area": match s.area { AreaMode::Exact => "exact", AreaMode::Eq17 => "eq17" },
            "merge": s.merge,
            "crease_deg": s.crease_deg,
            "texture_override": opts.load.texture_override.as_ref().map(|p| p.display().to_string()),
        }),
        sources: sources.clone(),
    };
    if let (Some(b), Some(map)) = (s.budget, generator.parameters.as_object_mut()) {
        map.insert("sample_budget".into(), json!(b));
    }
    let mut warnings = scene.warnings.clone();
    for m in sampled.meshes.iter().filter(|m| m.count == 0) {
        warnings.push(format!("mesh {:?} produced no samples (no triangles, or every sample transparent) and is left out", m.name));
    }
    let rows = sampled.meshes.iter().map(|m| (m.name.as_str(), m.count, &m.instances[..], &m.affine[..], m.two_sided));
    let tables = tables(rows, (n_points, scene.points_two_sided()), generator);
    let n_samples = tables.sample_count();
    let st = &sampled.stats;
    let rel = if st.mesh_area > 0.0 { (st.sample_area - st.mesh_area) / st.mesh_area } else { 0.0 };
    warnings.extend(st.warnings.iter().cloned());
    if st.baked_non_similar > 0 {
        warnings.push(format!("{} placement(s) of reused meshes had a projective or singular transform and were baked into world space", st.baked_non_similar));
    }
    let summary = Summary {
        inputs: sources,
        output: None,
        output_bytes: 0,
        method: s.method.name().into(),
        area_mode: match s.area { AreaMode::Exact => "exact", AreaMode::Eq17 => "eq17" }.into(),
        merged: s.merge,
        triangles_read: scene.stats.triangles_read,
        triangles_degenerate: scene.stats.degenerate_triangles,
        polygons_triangulated: scene.stats.polygons_triangulated,
        primitives_skipped: scene.stats.skipped_primitives,
        triangles_instanced: scene.instanced_triangle_count(),
        meshes: tables.meshes.len() as u64,
        instances: (tables.instances.len() + tables.affine_instances.len()) as u64,
        affine_instances: tables.affine_instances.len() as u64,
        samples_before_merge: st.samples_before_merge + n_points,
        samples: n_samples,
        samples_dropped_alpha: st.dropped_alpha,
        point_samples: n_points,
        voxel_size: sampled.voxel.size,
        voxel_size_reason: sampled.voxel.reason.clone(),
        sample_area: st.sample_area,
        mesh_area: st.mesh_area,
        area_relative_error: rel,
        seconds_load: t_load,
        seconds_sample: t_sample,
        seconds_write: 0.0,
        seconds_total: t0.elapsed().as_secs_f64(),
        samples_per_second: if t_sample > 0.0 { n_samples as f64 / t_sample } else { 0.0 },
        warnings,
        missing_inputs: scene.missing.iter().map(|p| p.display().to_string()).collect(),
    };
    Ok((tables, summary))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::{Duration, SystemTime};

    /// An OBJ of two objects (a bumpy strip and a triangle) and a PLY point cloud in `dir`.
    fn write_inputs(dir: &Path) -> Vec<PathBuf> {
        let mut obj = String::from("o strip\n");
        for i in 0..=20 {
            let x = f64::from(i) / 20.0;
            obj += &format!("v {x} 0 {}\nv {x} 0.3 {}\n", 0.1 * (9.0 * x).sin(), 0.1 * (7.0 * x).cos());
        }
        for i in 0..20 {
            let (a, b, c, d) = (2 * i + 1, 2 * i + 2, 2 * i + 3, 2 * i + 4);
            obj += &format!("f {a} {c} {d}\nf {a} {d} {b}\n");
        }
        obj += "o tri\nv 0 1 0\nv 1 1 0\nv 0 2 0.5\nf 43 44 45\n";
        let mut ply = String::from("ply\nformat ascii 1.0\nelement vertex 300\nproperty float x\nproperty float y\nproperty float z\nend_header\n");
        for i in 0..300 {
            ply += &format!("{} {} 2\n", f64::from(i % 20) * 0.05, f64::from(i / 20) * 0.05);
        }
        let (o, p) = (dir.join("strip.obj"), dir.join("cloud.ply"));
        std::fs::write(&o, obj).expect("write obj");
        std::fs::write(&p, ply).expect("write ply");
        vec![o, p]
    }

    /// The sink gets the samples of the in-memory file in its order (meshes, then points); a
    /// dry run reports the same counts and writes nothing; a sink error ends the run with it.
    #[test]
    fn sink_gets_the_file_samples_and_its_error_stops_the_run() {
        let dir = tempfile::tempdir().expect("tempdir");
        let opts = Options {
            inputs: write_inputs(dir.path()),
            output: None,
            load: LoadOptions::default(),
            sample: SampleOptions { density: Density::VoxelSize(0.01), ..Default::default() },
        };
        let (file, summary) = sample_in_memory(&opts, &|_, _| {}).expect("samples");
        assert_eq!(file.meshes.iter().map(|m| m.name.as_str()).collect::<Vec<_>>(), ["strip", "tri", "points"]);
        assert_eq!(summary.point_samples, 300);
        let (mut runs, mut got) = (0, Vec::new());
        let (tables, streamed) = sample_into(&opts, &|_, _| {}, &mut |nodes| {
            runs += 1;
            got.extend_from_slice(nodes);
            Ok(())
        })
        .expect("samples");
        assert!(runs >= 3, "{runs} runs");
        assert_eq!(tables.sample_count(), file.samples.len() as u64);
        assert_eq!(tables.with_samples(got), file);
        assert_eq!((streamed.samples, streamed.meshes, streamed.sample_area.to_bits()), (summary.samples, 3, summary.sample_area.to_bits()));
        let dry = run(&opts, &|_, _| {}).expect("dry run");
        assert_eq!((dry.samples, dry.output_bytes, dry.output), (file.samples.len() as u64, 0, None));
        let mut calls = 0;
        let r = sample_into(&opts, &|_, _| {}, &mut |_| {
            calls += 1;
            Err(Error::Usage("sink full".into()))
        });
        assert!(matches!(r, Err(Error::Usage(m)) if m == "sink full"));
        assert_eq!(calls, 1);
    }

    /// The file written while sampling is the in-memory file's bytes; a run that fails after
    /// sampling began (a mesh whose grid cannot be indexed comes after good ones) leaves
    /// neither the output nor a temporary file behind.
    #[test]
    fn streamed_file_equals_the_in_memory_file_and_a_failed_run_leaves_nothing() {
        let dir = tempfile::tempdir().expect("tempdir");
        let out = dir.path().join("out").join("x.samples");
        std::fs::create_dir(dir.path().join("out")).expect("mkdir");
        let mut opts = Options {
            inputs: write_inputs(dir.path()),
            output: Some(out.clone()),
            load: LoadOptions::default(),
            sample: SampleOptions { density: Density::VoxelSize(0.01), ..Default::default() },
        };
        let summary = run(&opts, &|_, _| {}).expect("run");
        let (file, _) = sample_in_memory(&opts, &|_, _| {}).expect("samples");
        let mut bytes = std::io::Cursor::new(Vec::new());
        file.write_to(&mut bytes).expect("write");
        assert_eq!(std::fs::read(&out).expect("read"), bytes.into_inner());
        assert_eq!(summary.output_bytes, std::fs::metadata(&out).expect("metadata").len());

        let huge = dir.path().join("huge.obj");
        // A sliver: few samples, but 2^23 voxels along each axis, too many for 64-bit keys,
        // which only the sampling loop finds (after the other meshes were streamed).
        std::fs::write(&huge, "v 0 0 0\nv 50000 50000 50000\nv 50000 50000.01 50000\nf 1 2 3\n").expect("write obj");
        opts.inputs.push(huge);
        opts.output = Some(dir.path().join("out").join("y.samples"));
        let err = run(&opts, &|_, _| {}).expect_err("an unindexable grid");
        assert!(err.to_string().contains("64-bit voxel keys"), "{err}");
        let left: Vec<_> = std::fs::read_dir(dir.path().join("out")).expect("read dir").map(|e| e.expect("entry").file_name()).collect();
        assert_eq!(left, [std::ffi::OsString::from("x.samples")]);
    }

    /// The provenance hash of each input is the BLAKE3 of its bytes, on 1 and 2 threads, also
    /// for an input large enough (over 1 MiB) to be hashed in parallel subtrees while it is
    /// parsed.
    #[test]
    fn input_hashes_are_the_files_blake3() {
        let dir = tempfile::tempdir().expect("tempdir");
        let mut inputs = write_inputs(dir.path());
        let big = dir.path().join("big.obj");
        let mut text = std::fs::read_to_string(&inputs[0]).expect("read obj");
        while text.len() < 3 << 19 {
            text += "# a comment line that pads the file past the parallel hashing threshold\n";
        }
        std::fs::write(&big, text).expect("write big obj");
        inputs.push(big);
        let opts = Options { inputs, output: None, load: LoadOptions::default(), sample: SampleOptions { density: Density::VoxelSize(0.05), ..Default::default() } };
        for threads in [1, 2] {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
            let summary = pool.install(|| run(&opts, &|_, _| {})).expect("run");
            let got: Vec<_> = summary.inputs.iter().map(|s| (s.path.clone(), s.blake3.clone())).collect();
            let want: Vec<_> = opts.inputs.iter().map(|p| (p.display().to_string(), blake3::hash(&std::fs::read(p).expect("read")).to_hex().to_string())).collect();
            assert_eq!(got, want, "{threads} threads");
        }
    }

    #[test]
    fn changes_during_a_run_are_seen_but_future_dates_are_not() {
        let dir = tempfile::tempdir().expect("tempdir");
        let f = dir.path().join("texture.png");
        std::fs::write(&f, b"x").expect("write");
        let file = std::fs::File::options().write(true).open(&f).expect("open");
        let started = SystemTime::now() - Duration::from_secs(10);
        file.set_modified(started - Duration::from_secs(60)).expect("set mtime");
        assert!(!changed_since(&f, started), "modified before the run");
        file.set_modified(started + Duration::from_secs(5)).expect("set mtime");
        assert!(changed_since(&f, started), "modified during the run");
        file.set_modified(SystemTime::now() + Duration::from_secs(3600)).expect("set mtime");
        assert!(!changed_since(&f, started), "a future date says nothing about this run");
        assert!(!changed_since(&dir.path().join("missing"), started));
    }
}
