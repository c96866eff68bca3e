//! Samplers (thesis §5.2): the scan-line voxelization in one uniform grid and the QSplat
//! vertex-patch sampler, plus the density choice (EQ 15–17) and coverage helpers.
//!
//! ## Voxel method (default)
//! Every triangle is rasterized in its canonical orientation: the axis closest to its normal
//! is the depth axis, the other two index grid *columns*. For each column the triangle
//! overlaps, the triangle is clipped to the column and the depth range of the clipped polygon
//! gives the voxels it crosses — one voxel for most columns (the dominant axis keeps depth
//! slopes ≤ 1), up to three where the plane is steep (45°). Each piece of triangle ∩ voxel
//! becomes a sample at the piece's centroid — a point of the surface, whatever the voxel
//! size — with the radius that reaches the piece's farthest vertex, so the union of the
//! sample spheres contains every piece, and hence the surface: coverage is guaranteed by
//! construction, not just for points near column centres. (The thesis' EQ 15 puts samples
//! at voxel centres with half the voxel diagonal as radius: off the surface by up to half a
//! voxel.) The sample's area is the exact area of triangle ∩ voxel (the §5.2.3 "better
//! measurement"; the sum equals the mesh area to rounding), or EQ 17 (triangle area / sample
//! count) with [`AreaMode::Eq17`]. Attributes are interpolated at the piece's centroid.
//!
//! A piece whose colour varies (a texture or vertex colours) gets the mean colour of five
//! points of it; where those differ by more than a threshold (detail finer than the voxel:
//! lines, text), the piece is cut at its voxel's mid-planes across the projection plane and
//! each quarter becomes a sample of its own (centroid, reach and colour of the quarter): the
//! surface is sampled at half the voxel there, and only there.
//!
//! ## Scanline method (the thesis as written)
//! One sample per column whose centre falls inside the projected triangle, at the plane
//! point above that centre (keyed by the voxel that holds it), with the radius that reaches
//! the column's square lifted onto the plane; EQ 17 areas. A triangle that covers no column
//! centre gets one sample at its centroid reaching its corners (the thesis would drop it).
//! Coverage is *not* guaranteed near triangle edges (columns whose centres a triangle misses
//! have no sample of it); it is here to compare with the thesis' counts.
//!
//! ## Merging
//! Samples of the same mesh that fall in the same voxel (from neighbouring triangles) are
//! merged here (thesis Table 2, "after merging"): the voxel key exists only here, so
//! build-tree would need a spatial search to find duplicates. Areas add; the centre, colour
//! and normal are area-weighted means (the centre is the centroid of the merged pieces: on
//! the surface where they are coplanar, under it where they meet at a crease or curve); the
//! radius reaches every merged piece, and for the voxel method need not exceed the distance
//! to the voxel's farthest corner. Quarters of pieces sampled at half the voxel merge only
//! with quarters in the same octant of the voxel. `merge = false` keeps one sample per
//! triangle per voxel (and quarter).
//!
//! Radii are rounded up when stored, and grown by a bound on how far rounding the centre to
//! f32 moves it, so containment survives the f32 storage. A voxel wider than the model is clamped to
//! the model's largest extent (a warning in [`SampleStats::warnings`]).
//!
//! ## Modules
//! `density` chooses the voxel size, `plan` the units to sample; `prepare` readies their
//! primitives (`shade` and `texture` give attributes); `slabs` runs the voxel (`voxel`, with
//! `clip`) and scan-line (`scanline`) rasterizers slab by slab into `keys` records, which
//! `sort` orders and `merge` turns into samples. `vertex` and `points` are the other
//! samplers, `coverage` checks the result.

use sct_format::Node;

use crate::mesh::*;

mod clip;
mod coverage;
mod density;
mod in_order;
mod keys;
mod merge;
mod plan;
mod points;
mod prepare;
mod scanline;
mod shade;
mod slabs;
mod sort;
mod texture;
mod vertex;
mod voxel;

pub use coverage::{coverage, world_spheres, Grid};
pub use density::{choose_voxel_size, Density, VoxelChoice};
pub use points::{sample_points, sample_points_into};

use plan::{plan_sampling, unit_keys};
use prepare::{MatOwned, Prepared};
use slabs::sample_slabs;
use texture::{decode_textures, TexImage};
use vertex::vertex_patches;

/// Which sampler.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Method {
    /// Conservative scan-line voxelization (exact triangle ∩ voxel).
    Voxel,
    /// The thesis' scan-line: one sample per covered column centre.
    Scanline,
    /// QSplat vertex patches (§5.2.1): one sample per vertex, radius = longest incident edge.
    Vertex,
}

impl Method {
    /// The name used on the command line and in JSON.
    pub fn name(self) -> &'static str {
        match self {
            Method::Voxel => "voxel",
            Method::Scanline => "scanline",
            Method::Vertex => "vertex",
        }
    }
}

/// How voxel samples get their area.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AreaMode {
    /// Area of triangle ∩ voxel.
    Exact,
    /// EQ 17: triangle area / number of samples of the triangle.
    Eq17,
}

/// Sampler options.
#[derive(Clone, Debug)]
pub struct SampleOptions {
    /// Sampler.
    pub method: Method,
    /// Density.
    pub density: Density,
    /// Area mode (voxel method).
    pub area: AreaMode,
    /// Merge samples of one mesh that share a voxel.
    pub merge: bool,
    /// Crease angle for computed normals, degrees.
    pub crease_deg: f32,
    /// Refuse to make more samples than this (estimated before sampling).
    pub max_samples: u64,
    /// Coarsen the voxel, when the density rule would make more, to about this many samples
    /// (estimated before merging).
    pub budget: Option<u64>,
}

impl Default for SampleOptions {
    fn default() -> Self {
        SampleOptions {
            method: Method::Voxel,
            density: Density::View { pixels: Density::VIEW_PIXELS },
            area: AreaMode::Exact,
            merge: true,
            crease_deg: 60.0,
            max_samples: 400_000_000,
            budget: None,
        }
    }
}

/// One sampled mesh: its samples (in its frame) and where it is placed.
#[derive(Clone, Debug)]
pub struct SampledMesh {
    /// Name.
    pub name: String,
    /// Samples in the mesh's frame.
    pub samples: Vec<Node>,
    /// Similarity placements (identity for meshes baked into world space).
    pub instances: Vec<sct_format::Similarity>,
    /// Affine placements (non-uniform scale, shear, mirror) as row-major 3 × 4 matrices;
    /// written to the samples file's `AFFI` section (spec §8).
    pub affine: Vec<[[f64; 4]; 3]>,
    /// Seen from both sides ([`LoadedScene::mesh_two_sided`]).
    pub two_sided: bool,
}

/// Counters of a sampling run.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SampleStats {
    /// Samples before merging.
    pub samples_before_merge: u64,
    /// Samples after merging (= written), over meshes (not instances).
    pub samples: u64,
    /// Samples dropped by alpha (MASK cutoff or alpha 0).
    pub dropped_alpha: u64,
    /// Triangles sampled (once per sampled mesh, not per instance).
    pub triangles: u64,
    /// Meshes instanced (sampled once, placed several times).
    pub instanced_meshes: u64,
    /// Placements baked into world space because they were neither a similarity nor an
    /// invertible affine map (projective or singular matrices).
    pub baked_non_similar: u64,
    /// Affine (non-similarity) placements kept as instances.
    pub affine_instances: u64,
    /// Sum of sample areas over the scene (instances included, scaled).
    pub sample_area: f64,
    /// Mesh area over the scene (instances included).
    pub mesh_area: f64,
    /// Non-fatal problems of the sampling (the run report adds them to its own).
    pub warnings: Vec<String>,
}

/// Result of [`sample_scene`].
#[derive(Clone, Debug)]
pub struct Sampled {
    /// Sampled meshes.
    pub meshes: Vec<SampledMesh>,
    /// The voxel size.
    pub voxel: VoxelChoice,
    /// Counters.
    pub stats: SampleStats,
}

/// One mesh of [`sample_scene_into`]: a [`SampledMesh`] whose samples went to the sink.
#[derive(Clone, Debug)]
pub struct StreamedMesh {
    /// Name.
    pub name: String,
    /// Samples handed to the sink for this mesh.
    pub count: u64,
    /// Similarity placements (identity for meshes baked into world space).
    pub instances: Vec<sct_format::Similarity>,
    /// Affine placements, row-major 3 × 4.
    pub affine: Vec<[[f64; 4]; 3]>,
    /// Seen from both sides ([`LoadedScene::mesh_two_sided`]).
    pub two_sided: bool,
}

/// Result of [`sample_scene_into`]: everything but the samples.
#[derive(Clone, Debug)]
pub struct Streamed {
    /// Sampled meshes, in the order their samples reached the sink.
    pub meshes: Vec<StreamedMesh>,
    /// The voxel size.
    pub voxel: VoxelChoice,
    /// Counters.
    pub stats: SampleStats,
}

/// Why [`sample_scene_into`] stopped.
#[derive(Debug)]
pub enum StreamError<E> {
    /// Sampling is impossible (bad density, too many samples, grid too large).
    Sampling(String),
    /// The sink failed; sampling stopped there.
    Sink(E),
}

/// A sink that never fails (collecting in memory, counting).
pub type Never = std::convert::Infallible;

/// Where samples go as they are made, in runs, in their final order. `Send`: a sink works
/// on any thread while the others make later slabs.
pub type Sink<'a, E> = dyn FnMut(&[Node]) -> Result<(), E> + Send + 'a;

/// A [`Sink`] told which mesh (index into [`Streamed::meshes`]) each run belongs to.
pub type MeshSink<'a, E> = dyn FnMut(usize, &[Node]) -> Result<(), E> + Send + 'a;

/// How far past its sample budget a scene may end before a warning says so: the estimate
/// itself lands within a few per cent (BENCHMARKS.md, "Sample budget").
const BUDGET_OVERSHOOT: f64 = 1.1;

/// Samples a loaded scene into memory: [`sample_scene_into`] collecting each mesh's samples.
pub fn sample_scene(scene: &LoadedScene, opts: &SampleOptions, progress: &(dyn Fn(u64, u64) + Sync)) -> Result<Sampled, String> {
    let mut samples: Vec<Vec<Node>> = Vec::new();
    let streamed = sample_scene_into(scene, opts, progress, &mut |mesh, nodes| {
        if samples.len() <= mesh {
            samples.resize_with(mesh + 1, Vec::new);
        }
        samples[mesh].extend_from_slice(nodes);
        Ok::<(), Never>(())
    })
    .map_err(|e| match e {
        StreamError::Sampling(msg) => msg,
        StreamError::Sink(never) => match never {},
    })?;
    samples.resize_with(streamed.meshes.len(), Vec::new);
    let meshes = streamed
        .meshes
        .into_iter()
        .zip(samples)
        .map(|(m, samples)| SampledMesh { name: m.name, samples, instances: m.instances, affine: m.affine, two_sided: m.two_sided })
        .collect();
    Ok(Sampled { meshes, voxel: streamed.voxel, stats: streamed.stats })
}

/// Samples a loaded scene, handing the samples to `sink(mesh, samples)` in runs, mesh after
/// mesh (`mesh` indexes the result's meshes) and in each mesh's final (voxel) order, as they
/// are made: no result is held, only a window of slabs made ahead of the sink (8 per thread;
/// the sink works on one while the other threads make later ones). A sink error stops
/// sampling and is returned.
pub fn sample_scene_into<E: Send>(
    scene: &LoadedScene,
    opts: &SampleOptions,
    progress: &(dyn Fn(u64, u64) + Sync),
    sink: &mut MeshSink<'_, E>,
) -> Result<Streamed, StreamError<E>> {
    // Which meshes are seen from both sides, and the scene's area, do not depend on the
    // sampling: found while it is planned. Their serial stretches (the weld's and the edges'
    // passes) then overlap the planner's parallel ones, at a time when little else is held
    // (their arrays, about 16 bytes a triangle, would add to the sampling's peak).
    let (planned, (two_sided, mesh_area)) = rayon::join(
        || plan_sampling(scene, opts),
        || {
            let placed = |m: usize| scene.instances.iter().any(|i| i.mesh == m);
            let sides: Vec<bool> = (0..scene.meshes.len()).map(|m| placed(m) && scene.mesh_two_sided(m)).collect();
            (sides, scene.world_area())
        },
    );
    let (voxel, mut stats, units) = planned.map_err(StreamError::Sampling)?;
    let total_tris: u64 = units.iter().map(|u| scene.meshes[u.mesh].triangle_count() as u64).sum();
    let done = std::sync::atomic::AtomicU64::new(0);
    let linear = decode_textures(scene);
    let mut out = Vec::new();
    for (ui, u) in units.iter().enumerate() {
        let mesh = &scene.meshes[u.mesh];
        let kp = unit_keys(mesh, u).map_err(StreamError::Sampling)?;
        let prepared: Vec<Prepared> = mesh
            .primitives
            .iter()
            .map(|prim| {
                let material = scene.material(prim);
                let tex_of = |t: &Option<TextureRef>| -> Option<(TexImage, TextureRef)> {
                    t.as_ref().and_then(|t| {
                        let linear = linear.get(t.image).and_then(|l| l.as_deref());
                        scene.images.get(t.image).map(|img| (TexImage { img, linear }, t.clone()))
                    })
                };
                let mat = MatOwned {
                    base: material.base_color,
                    tex: tex_of(&material.texture),
                    alpha_tex: tex_of(&material.alpha_texture),
                    alpha: material.alpha_mode,
                };
                Prepared::new(prim, u, mat, opts.crease_deg)
            })
            .collect();
        let mut tally = AreaTally::new(&u.affine);
        let mut emit = |nodes: &[Node]| {
            tally.add(nodes);
            sink(ui, nodes)
        };
        let (before, dropped) = if opts.method == Method::Vertex {
            let mut dropped = 0;
            for pp in &prepared {
                let (v, d) = vertex_patches(pp.prim, &pp.pos, &pp.nrm, pp.computed.as_deref(), &pp.mat.view(), u.h);
                emit(&v).map_err(StreamError::Sink)?;
                dropped += d;
            }
            let n = mesh.triangle_count() as u64;
            progress(done.fetch_add(n, std::sync::atomic::Ordering::Relaxed) + n, total_tris);
            (tally.count, dropped)
        } else {
            let progress = |n| progress((done.fetch_add(n, std::sync::atomic::Ordering::Relaxed) + n).min(total_tris), total_tris);
            sample_slabs(&prepared, &kp, u.h, opts, &progress, &mut emit).map_err(StreamError::Sink)?
        };
        stats.triangles += mesh.triangle_count() as u64;
        stats.dropped_alpha += dropped;
        stats.samples_before_merge += before;
        stats.samples += tally.count;
        stats.sample_area = tally.add_placed_area(stats.sample_area, &u.instances);
        let two_sided = two_sided.get(u.mesh).copied().unwrap_or(false);
        out.push(StreamedMesh { name: u.name.clone(), count: tally.count, instances: u.instances.clone(), affine: u.affine.clone(), two_sided });
    }
    stats.mesh_area = mesh_area;
    // The budget's estimate is made before sampling and counts no colour quarters (pieces
    // whose colour varies are sampled at half the voxel, up to 4 samples each): say so when
    // they took the count past it.
    if let (Some(budget), false) = (opts.budget, opts.method == Method::Vertex) {
        if stats.samples as f64 > budget as f64 * BUDGET_OVERSHOOT {
            stats.warnings.push(format!(
                "{} samples, {:.2}× the sample budget of {budget}: pieces whose colour varies were sampled by quarters, which the budget's estimate does not count (a smaller --sample-budget or a larger --voxel-size makes fewer)",
                stats.samples,
                stats.samples as f64 / budget as f64
            ));
        }
    }
    Ok(Streamed { meshes: out, voxel, stats })
}

/// A mesh's sample count and area sums, added run by run as its samples stream past, each
/// sum in sample order (the order, hence the bits, of summing the whole mesh at once).
struct AreaTally {
    count: u64,
    /// Σ area in the mesh's frame.
    area: f64,
    /// Per affine placement: the map, its stretch and Σ placed area.
    affine: Vec<(sct_format::samples::AffineInstance, f64, f64)>,
}

impl AreaTally {
    fn new(affine: &[[[f64; 4]; 3]]) -> Self {
        let affine = affine
            .iter()
            .map(|m| {
                let a = sct_format::samples::AffineInstance { mesh: 0, matrix: *m };
                (a, a.max_stretch(), 0.0)
            })
            .collect();
        AreaTally { count: 0, area: 0.0, affine }
    }

    fn add(&mut self, nodes: &[Node]) {
        self.count += nodes.len() as u64;
        self.area = nodes.iter().fold(self.area, |s, n| s + f64::from(n.area));
        for (a, stretch, sum) in &mut self.affine {
            *sum = nodes.iter().fold(*sum, |s, n| s + f64::from(a.transform_node(n, *stretch).area));
        }
    }

    /// `scene_area` plus the area over every placement (similarities scale areas by s²,
    /// affine maps per sample), added in the order the whole-mesh sums were.
    fn add_placed_area(&self, mut scene_area: f64, instances: &[sct_format::Similarity]) -> f64 {
        scene_area += instances.iter().map(|s| self.area * s.scale * s.scale).sum::<f64>();
        for (_, _, sum) in &self.affine {
            scene_area += sum;
        }
        scene_area
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use super::slabs::SLAB_TARGET;

    /// An n × n grid of unit size, bumped in z (2 n² triangles).
    fn bumpy_sheet(n: u32) -> Primitive {
        let mut positions = Vec::new();
        for y in 0..=n {
            for x in 0..=n {
                let (fx, fy) = (x as f32 / n as f32, y as f32 / n as f32);
                positions.push([fx, fy, 0.15 * (7.0 * fx).sin() * (5.0 * fy).cos()]);
            }
        }
        let mut triangles = Vec::new();
        for y in 0..n {
            for x in 0..n {
                let i = y * (n + 1) + x;
                triangles.push([i, i + 1, i + n + 2]);
                triangles.push([i, i + n + 2, i + n + 1]);
            }
        }
        Primitive { positions, triangles, ..Default::default() }
    }

    /// Two meshes: a sheet placed by a similarity and two affine maps (sampled once in its
    /// frame), and a smaller sheet baked into world space.
    fn instanced_scene() -> LoadedScene {
        let scale = |s: [f64; 3], t: [f64; 3]| -> Mat4 { [[s[0], 0.0, 0.0, 0.0], [0.0, s[1], 0.0, 0.0], [0.0, 0.0, s[2], 0.0], [t[0], t[1], t[2], 1.0]] };
        LoadedScene {
            meshes: vec![
                Mesh { name: "sheet".into(), primitives: vec![bumpy_sheet(40)] },
                Mesh { name: "small".into(), primitives: vec![bumpy_sheet(8), bumpy_sheet(5)] },
            ],
            instances: vec![
                Instance { mesh: 0, transform: scale([1.5; 3], [0.0; 3]) },
                Instance { mesh: 0, transform: scale([1.0, 2.0, 0.5], [3.0, 0.0, 0.0]) },
                Instance { mesh: 0, transform: scale([0.7, 1.0, 1.3], [0.0, 3.0, 0.0]) },
                Instance { mesh: 1, transform: scale([0.5; 3], [-1.0, 0.0, 0.0]) },
            ],
            materials: vec![Material { base_color: [0.8, 0.5, 0.2, 1.0], ..Default::default() }],
            ..Default::default()
        }
    }

    /// The sink gets each mesh's samples in runs (more slabs than the window made ahead), mesh after
    /// mesh, in the order and with the counters of the collected result, and the areas summed
    /// run by run equal, bit for bit, the sums over whole meshes (instances applied).
    #[test]
    fn sink_runs_equal_the_collected_result() {
        SLAB_TARGET.store(300, std::sync::atomic::Ordering::Relaxed);
        let scene = instanced_scene();
        for method in [Method::Voxel, Method::Scanline, Method::Vertex] {
            let opts = SampleOptions { method, density: Density::VoxelSize(0.004), ..Default::default() };
            let collected = sample_scene(&scene, &opts, &|_, _| {}).expect("samples");
            let mut runs: Vec<(usize, Vec<Node>)> = Vec::new();
            let streamed = sample_scene_into(&scene, &opts, &|_, _| {}, &mut |mesh, nodes| {
                runs.push((mesh, nodes.to_vec()));
                Ok::<(), Never>(())
            })
            .expect("samples");
            assert!(runs.windows(2).all(|w| w[0].0 <= w[1].0), "{method:?}: meshes interleaved");
            assert_eq!(streamed.meshes.len(), 2);
            assert_eq!(streamed.stats, collected.stats, "{method:?}");
            if method != Method::Vertex {
                assert!(runs.len() > 8 * rayon::current_num_threads(), "{method:?}: {} runs, not more than the window", runs.len());
            }
            for (mi, (m, c)) in streamed.meshes.iter().zip(&collected.meshes).enumerate() {
                let got: Vec<Node> = runs.iter().filter(|r| r.0 == mi).flat_map(|r| r.1.iter().copied()).collect();
                assert_eq!((m.count, &m.name, &m.instances, &m.affine), (c.samples.len() as u64, &c.name, &c.instances, &c.affine));
                let bits = |n: &Node| (n.center.map(f32::to_bits), n.radius.to_bits(), n.normal.map(f32::to_bits), n.area.to_bits(), n.color);
                assert!(got.iter().map(bits).eq(c.samples.iter().map(bits)), "{method:?}: mesh {mi} differs");
            }
            assert_eq!(collected.meshes[0].affine.len(), 2);
            // The whole-mesh sums the tally replaces (same order of additions).
            let mut want = 0.0f64;
            for m in &collected.meshes {
                let area: f64 = m.samples.iter().map(|n| f64::from(n.area)).sum();
                want += m.instances.iter().map(|s| area * s.scale * s.scale).sum::<f64>();
                for mat in &m.affine {
                    let a = sct_format::samples::AffineInstance { mesh: 0, matrix: *mat };
                    let st = a.max_stretch();
                    want += m.samples.iter().map(|n| f64::from(a.transform_node(n, st).area)).sum::<f64>();
                }
            }
            assert_eq!(streamed.stats.sample_area.to_bits(), want.to_bits(), "{method:?}");
            let rel = (want - scene.world_area()) / scene.world_area();
            assert!(rel.abs() < 0.02, "{method:?}: area error {rel:e}");
        }
    }

    /// A sink error stops sampling at once (no further runs) and comes back as the error.
    #[test]
    fn sink_error_stops_sampling() {
        SLAB_TARGET.store(300, std::sync::atomic::Ordering::Relaxed);
        let scene = instanced_scene();
        for method in [Method::Voxel, Method::Vertex] {
            let opts = SampleOptions { method, density: Density::VoxelSize(0.004), ..Default::default() };
            let mut calls = 0;
            let r = sample_scene_into(&scene, &opts, &|_, _| {}, &mut |_, _| {
                calls += 1;
                if calls == 2 { Err("disk full") } else { Ok(()) }
            });
            assert!(matches!(r, Err(StreamError::Sink("disk full"))), "{method:?}: {r:?}");
            assert_eq!(calls, 2, "{method:?}");
        }
        // A sampling error is told apart from a sink error.
        let opts = SampleOptions { density: Density::VoxelSize(1e-9), ..Default::default() };
        let r = sample_scene_into(&scene, &opts, &|_, _| {}, &mut |_, _| Ok::<(), Never>(()));
        assert!(matches!(r, Err(StreamError::Sampling(_))));
    }

    /// A bumpy sheet over many slabs (small slab target: more slabs than the window made ahead):
    /// 1 and 2 threads give the same samples for every method; progress counts each triangle
    /// once; EQ 17 and scan-line areas still divide each triangle's area by its whole sample
    /// count (they sum to the mesh area) although multi-slab triangles are shaded per slab.
    #[test]
    fn slabs_batches_progress_and_per_triangle_areas() {
        SLAB_TARGET.store(300, std::sync::atomic::Ordering::Relaxed);
        let prim = bumpy_sheet(40);
        let ntris = prim.triangles.len() as u64;
        let scene = LoadedScene {
            meshes: vec![Mesh { name: "sheet".into(), primitives: vec![prim] }],
            instances: vec![Instance { mesh: 0, transform: IDENTITY }],
            materials: vec![Material { base_color: [0.8, 0.5, 0.2, 1.0], ..Default::default() }],
            ..Default::default()
        };
        let area = scene.world_area();
        for (method, area_mode) in [(Method::Voxel, AreaMode::Exact), (Method::Voxel, AreaMode::Eq17), (Method::Scanline, AreaMode::Eq17)] {
            let opts = SampleOptions { method, area: area_mode, density: Density::VoxelSize(0.004), merge: false, ..Default::default() };
            let run = |threads: usize| {
                let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
                let calls = std::sync::Mutex::new(Vec::new());
                let s = pool.install(|| {
                    sample_scene(&scene, &opts, &|done, total| {
                        assert_eq!(total, ntris);
                        calls.lock().expect("lock").push(done);
                    })
                });
                (s.expect("samples"), calls.into_inner().expect("lock"))
            };
            let (a, pa) = run(1);
            let (b, pb) = run(2);
            for p in [pa, pb] {
                // Reaches the total, and only at the end (the slabs after the last one where
                // a triangle starts add nothing); counting a triangle in every slab it spans
                // would saturate after a fraction of the slabs.
                assert_eq!(p.iter().max(), Some(&ntris), "{method:?}");
                let at_total = p.iter().filter(|&&d| d == ntris).count();
                assert!(p.len() > 100 && at_total * 10 < p.len(), "{method:?}: {at_total} of {} calls at the total", p.len());
            }
            assert!(a.stats.samples > 40_000, "{method:?}: {} samples", a.stats.samples);
            let (na, nb) = (&a.meshes[0].samples, &b.meshes[0].samples);
            // Slab outputs are placed in slab order across batches: voxels x-major throughout.
            // Samples lie in their voxels (up to rounding: a centre on a face may be counted in
            // either voxel), so their x layers of voxels can be chosen non-decreasing.
            let mut layer = f64::NEG_INFINITY;
            for n in na {
                let x = f64::from(n.center[0]) / 0.004;
                assert!((x + 1e-4).floor() >= layer, "{method:?}: nodes out of voxel order");
                layer = layer.max((x - 1e-4).floor());
            }
            assert_eq!(na.len(), nb.len());
            for (x, y) in na.iter().zip(nb) {
                assert_eq!((x.center, x.area.to_bits(), x.normal, x.color), (y.center, y.area.to_bits(), y.normal, y.color), "{method:?}");
            }
            let rel = (a.stats.sample_area - area) / area;
            assert!(rel.abs() < 1e-5, "{method:?}: area error {rel:e}");
        }
    }

    /// The unit quad in the z = 0 plane, its UVs its x and y, textured with `image` (clamped,
    /// base colour white) under `alpha_mode`.
    fn textured_unit_quad(image: Image, alpha_mode: AlphaMode) -> LoadedScene {
        let quad = Primitive {
            positions: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]],
            uvs: vec![vec![[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]],
            triangles: vec![[0, 1, 2], [0, 2, 3]],
            material: Some(0),
            ..Default::default()
        };
        let tex = TextureRef { image: 0, tex_coord: 0, transform: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], wrap_s: Wrap::ClampToEdge, wrap_t: Wrap::ClampToEdge };
        LoadedScene {
            meshes: vec![Mesh { name: "quad".into(), primitives: vec![quad] }],
            instances: vec![Instance { mesh: 0, transform: [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]] }],
            materials: vec![Material { base_color: [1.0; 4], texture: Some(tex), alpha_mode, ..Default::default() }],
            images: vec![image],
            ..Default::default()
        }
    }

    /// A texture with lines one texel wide, a quarter of a voxel: the voxels the lines cross
    /// are sampled at half the voxel (up to four samples each, whose colours keep the lines'
    /// contrast), the voxels of plain black keep one sample; every sample stays on the
    /// surface, in its voxel, and the areas still add up to the quad's.
    #[test]
    fn colour_detail_finer_than_the_voxel_is_sampled_at_half_the_voxel() {
        // 64 × 64 texels, black with a white column every 16 texels (texels 5, 21, 37, 53).
        let (w, h) = (64u32, 64u32);
        let rgba: Vec<[u8; 4]> = (0..w * h).map(|i| if (i % w) % 16 == 5 { [255; 4] } else { [0, 0, 0, 255] }).collect();
        let scene = textured_unit_quad(Image { width: w, height: h, rgba, source: "lines".into() }, AlphaMode::Opaque);
        // Voxels of 4 texels: 16 × 16 voxels over the quad, 4 columns of them crossed by a line.
        let voxel = 1.0 / 16.0;
        let opts = SampleOptions { density: Density::VoxelSize(voxel), ..Default::default() };
        let s = sample_scene(&scene, &opts, &|_, _| {}).expect("samples");
        let nodes = &s.meshes[0].samples;
        let mut per_voxel = std::collections::BTreeMap::<(i64, i64), Vec<&Node>>::new();
        for n in nodes {
            assert!(n.center[2].abs() < 1e-6, "{n:?} off the quad");
            let v = (f64::from(n.center[0]) / voxel).floor() as i64;
            let u = (f64::from(n.center[1]) / voxel).floor() as i64;
            per_voxel.entry((v, u)).or_default().push(n);
        }
        assert_eq!(per_voxel.len(), 256);
        let lines = |x: i64| x % 4 == 1; // voxel columns holding texel 5 + 16k
        for (&(x, y), ns) in &per_voxel {
            if lines(x) {
                assert!((2..=4).contains(&ns.len()), "voxel {x},{y}: {} samples", ns.len());
                // One quarter holds the line: brighter than the voxel's mean (a quarter of white).
                let brightest = ns.iter().map(|n| n.color[0]).max().unwrap_or(0);
                assert!(brightest >= 170, "voxel {x},{y}: brightest sample {brightest}");
            } else {
                assert_eq!(ns.len(), 1, "voxel {x},{y}: plain black sampled finer");
            }
        }
        let area: f64 = nodes.iter().map(|n| f64::from(n.area)).sum();
        assert!((area - 1.0).abs() < 1e-5, "area {area}");
        assert!(nodes.iter().all(|n| n.area > 0.0));
        // The samples' spheres still hold the surface: random points of the quad, and the
        // corners of the texels next to the lines, each lie in some sample's sphere.
        let mut rng = sct_format::rng::SplitMix64(5);
        let mut pts: Vec<[f64; 2]> = (0..3000).map(|_| [rng.next_f64(), rng.next_f64()]).collect();
        pts.extend((0..=64).flat_map(|i| [4.0, 5.0, 6.0, 20.0, 21.0, 22.0].map(|t| [t / 64.0, f64::from(i) / 64.0])));
        for p in pts {
            let held = nodes.iter().any(|n| {
                let d = [p[0] - f64::from(n.center[0]), p[1] - f64::from(n.center[1]), f64::from(n.center[2])];
                (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt() <= f64::from(n.radius)
            });
            assert!(held, "point {p:?} of the quad in no sample's sphere");
        }
    }

    /// A decal: a transparent (BLEND) quad with opaque black lines one texel wide, a quarter
    /// of a voxel, on the left edge of every fourth voxel column. The voxels' centroids lie
    /// on transparent texels, so one decision at the centroid dropped every line; the pieces
    /// a line crosses are sampled by quarters instead, and only the lines' quarters are kept.
    #[test]
    fn a_decal_line_off_the_voxel_centroid_is_kept() {
        let (w, h) = (64u32, 64u32);
        let rgba: Vec<[u8; 4]> = (0..w * h).map(|i| if (i % w) % 16 == 4 { [0, 0, 0, 255] } else { [255, 255, 255, 0] }).collect();
        let scene = textured_unit_quad(Image { width: w, height: h, rgba, source: "decal".into() }, AlphaMode::Blend);
        let voxel = 1.0 / 16.0;
        let opts = SampleOptions { density: Density::VoxelSize(voxel), ..Default::default() };
        let s = sample_scene(&scene, &opts, &|_, _| {}).expect("samples");
        // Per line voxel: its darkest sample. Bilinear lookups mix the white of the
        // transparent texels into a line one texel wide (about half and half at the
        // quarters' centroids), but a line's sample is never the white alone.
        let mut darkest = std::collections::BTreeMap::<(i64, i64), u8>::new();
        for n in &s.meshes[0].samples {
            let x = f64::from(n.center[0]) / voxel;
            let (v, u) = (x.floor() as i64, (f64::from(n.center[1]) / voxel).floor() as i64);
            assert_eq!(v % 4, 1, "{n:?}: a sample off the lines");
            assert!(x - (v as f64) < 0.5, "{n:?}: not in the line's half of its voxel");
            let d = darkest.entry((v, u)).or_insert(255);
            *d = (*d).min(n.color[0]);
        }
        for v in [1, 5, 9, 13] {
            for u in 0..16 {
                let d = darkest.get(&(v, u)).copied();
                assert!(d.is_some_and(|d| d < 192), "line at voxel {v},{u}: darkest sample {d:?}");
            }
        }
    }
}
