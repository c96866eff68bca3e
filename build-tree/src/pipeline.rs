//! The whole `sct-build-tree` run: read samples, build and compose, write atomically.

use std::path::{Path, PathBuf};
use std::time::Instant;

use sct_format::graph::{Generator, SourceRef};
use sct_format::samples::{MeshEntry, SampleInstance, SamplesFile};
use sct_format::write::{write_scene_file_owned, Scene, WriteOptions};
use sct_format::{Limits, Profile};

use crate::error::BuildError;
use crate::scene::{read_scene_file, Composer};
use crate::tree::{BuildOptions, Weld};

/// What to build.
#[derive(Clone, Debug)]
pub struct Config {
    /// Samples file.
    pub samples: PathBuf,
    /// Output SCT file.
    pub output: PathBuf,
    /// Optional scene description.
    pub scene: Option<PathBuf>,
    /// Node profile.
    pub profile: Profile,
    /// zstd level override.
    pub compression_level: Option<i32>,
    /// Default profile: store centre offsets (spec 1.2) that put leaves back on their surface.
    pub centre_offsets: bool,
    /// Default profile: which trees store leaf refinement (spec 1.4).
    pub leaf_refinement: Refinement,
    /// Tree options.
    pub build: BuildOptions,
}

/// Which leaves store leaf refinement (spec 1.4: a leaf's centre and radius to within 1/256
/// of its own radius, about 2–3 bytes a leaf more).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Refinement {
    /// Every leaf of point clouds: each point is a measurement with its own colour, so a leaf
    /// drawn a fifth of its parent's radius away from its point moves that colour. In other
    /// trees the leaves the position grid moves off their piece of surface where that may
    /// leave the surface (past a face's edge or a crease).
    #[default]
    Auto,
    /// Every leaf of every tree.
    On,
    /// No tree (the file stays readable by 1.3 readers).
    Off,
}

/// Summary of a run (the `--json` output).
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct Report {
    /// Output path.
    pub output: String,
    /// Node profile.
    pub profile: String,
    /// Input samples over all meshes.
    pub samples: u64,
    /// Leaves over all geometry trees.
    pub leaves: u64,
    /// Nodes over all trees (geometry and group).
    pub nodes: u64,
    /// Deepest tree depth.
    pub depth: u32,
    /// Samples removed by welding.
    pub welded: u64,
    /// Trees written.
    pub trees: u64,
    /// Group trees among them.
    pub groups: u64,
    /// Instance graph nodes (similarity and affine).
    pub instances: u64,
    /// Affine instance graph nodes among them (spec §7).
    pub affine_instances: u64,
    /// Graph nodes.
    pub graph_nodes: u64,
    /// File size.
    pub bytes: u64,
    /// `bytes / leaves`.
    pub bytes_per_leaf: f64,
    /// Stored bytes per section tag.
    pub sections: Vec<(String, u64)>,
    /// Containers: our blocks (spec/SCT.md §6.2), runs of at most 16,384 consecutive nodes of
    /// one level, each compressed and checksummed on its own; summed over all trees.
    pub containers: u64,
    /// Containers of each level (index = depth; level 0, the root, lives in the tree header).
    pub containers_by_level: Vec<u64>,
    /// Containers by height, i.e. by the number of tree levels one spans: every SCT 1.0
    /// block holds nodes of a single level, so this is `{"1": containers}` (the thesis's
    /// containers are subtrees of several levels; see spec/build-tree-json.md).
    pub containers_by_height: std::collections::BTreeMap<u32, u64>,
    /// Stored links (child pointers) per leaf: 0, since children are addressed implicitly
    /// (breadth-first order plus one has-children bit per node).
    pub links_per_leaf: f64,
    /// Topology cost: stored bits of the has-children masks per geometry leaf.
    pub topology_bits_per_leaf: f64,
    /// Stored bytes per geometry leaf by stream: `topology`, `position_radius`, `normal`,
    /// `cone`, `color`, `area` (all trees' blocks), `index` (tree headers, level and block
    /// tables) and `file` (everything else: file header, section table, GENR, GRPH). They sum
    /// to `bytes_per_leaf`.
    pub bytes_per_leaf_by_stream: std::collections::BTreeMap<String, f64>,
    /// Seconds per phase.
    pub seconds: Phases,
    /// Peak resident memory (VmHWM) in bytes, when the OS reports it.
    pub peak_memory_bytes: Option<u64>,
    /// `peak_memory_bytes / samples`.
    pub peak_bytes_per_sample: Option<f64>,
}

/// Seconds per phase.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct Phases {
    /// Reading and parsing the samples file.
    pub read: f64,
    /// Partitioning (all trees).
    pub partition: f64,
    /// Breadth-first layout (all trees).
    pub layout: f64,
    /// Hierarchical attributes (all trees).
    pub attributes: f64,
    /// Scene composition other than the above (instances, inlines).
    pub compose: f64,
    /// Encoding, compression and writing.
    pub write: f64,
    /// Wall clock of the whole run.
    pub total: f64,
}

/// Runs a build from the samples file `cfg.samples`; `phase` is told what is happening
/// (for a progress display).
pub fn run(cfg: &Config, phase: &mut dyn FnMut(&str)) -> Result<Report, BuildError> {
    let t0 = Instant::now();
    phase("reading samples");
    // A FIFO or device given as the samples file would block or never end in the reader's
    // open: refused here, by type, without blocking.
    ensure_regular(&cfg.samples)?;
    let (samples, blake3) = SamplesFile::read_file_hashed(&cfg.samples, &Limits::default()).map_err(|e| match e {
        sct_format::Error::Io { .. } => BuildError::Io(e.to_string()),
        other => BuildError::Input(format!("{}: {other}", cfg.samples.display())),
    })?;
    let source = SourceRef { path: cfg.samples.display().to_string(), blake3 };
    let upstream = Upstream::SamplesFile(source, Box::new(samples.generator.clone()));
    run_samples(cfg, samples, upstream, t0, phase)
}

/// Where the samples of a build came from (recorded in the generator's provenance).
#[derive(Clone, Debug)]
pub enum Upstream {
    /// A samples file on disk (path and hash) and its own generator record (the sampling
    /// step: tool, parameters, the meshes it read).
    SamplesFile(SourceRef, Box<Generator>),
    /// Sampled in this process from meshes (one-step conversion): the voxelizer's own
    /// generator record, whose sources are the meshes and resources it read.
    Sampled(Generator),
    /// No samples (a scene of inlines only).
    None,
}

/// Builds from samples already in memory (`cfg.samples` is not read). `t0` is when the
/// run started, so the read (or sampling) time counts in the report's phases.
pub fn run_samples(
    cfg: &Config,
    mut samples: SamplesFile,
    upstream: Upstream,
    t0: Instant,
    phase: &mut dyn FnMut(&str),
) -> Result<Report, BuildError> {
    let mut rep = Report { output: cfg.output.display().to_string(), profile: cfg.profile.name().into(), ..Default::default() };
    let limits = Limits::default();
    rep.samples = samples.samples.len() as u64;
    normalize_normals(&mut samples)?;
    bake_affine_instances(&mut samples, &limits, DEFAULT_MAX_BAKED_BYTES, cfg.build.bake_affine)?;
    if cfg.scene.is_none() {
        // Refused before any tree is built: the file would hold more trees than a reader
        // accepts (see `check_reader_limits`).
        let trees = source_tree_count(&samples);
        check_sections(trees, &limits)?;
    }
    rep.seconds.read = t0.elapsed().as_secs_f64();

    phase("building trees");
    let t1 = Instant::now();
    let out_dir = cfg.output.parent().map(Path::to_path_buf).unwrap_or_default();
    let composer = Composer::new(&mut samples, cfg.build, &out_dir, limits.clone());
    if let Some(scene) = &cfg.scene {
        ensure_regular(scene)?;
    }
    let scene_file = cfg.scene.as_deref().map(read_scene_file).transpose()?;
    let composed = match &scene_file {
        Some(s) => composer.compose_file(s)?,
        None => composer.compose_source()?,
    };
    let compose_total = t1.elapsed().as_secs_f64();
    for s in &composed.mesh_stats {
        rep.seconds.partition += s.partition_s;
        rep.seconds.layout += s.layout_s;
        rep.seconds.attributes += s.attributes_s;
        rep.depth = rep.depth.max(s.depth);
        rep.welded += s.welded;
    }
    rep.seconds.compose =
        (compose_total - rep.seconds.partition - rep.seconds.layout - rep.seconds.attributes).max(0.0);
    rep.trees = composed.trees.len() as u64;
    rep.groups = composed.groups;
    rep.instances = composed.instances;
    rep.affine_instances = composed.affine_instances;
    rep.graph_nodes = composed.graph.nodes.len() as u64;
    rep.nodes = composed.trees.iter().map(|t| t.len() as u64).sum();
    // Geometry leaves only: group-tree leaves are children's bounds, not samples.
    let group_trees: std::collections::HashSet<u32> = composed
        .graph
        .nodes
        .iter()
        .filter_map(|n| match n {
            sct_format::GraphNode::Group { tree, .. } => Some(*tree),
            _ => None,
        })
        .collect();
    rep.leaves = composed
        .trees
        .iter()
        .enumerate()
        .filter(|(i, _)| !group_trees.contains(&(*i as u32)))
        .map(|(_, t)| t.leaf_count() as u64)
        .sum();

    // The writer must never write what the reader refuses (a file of 5,003 sections that
    // every reader rejects was once written with exit status 0).
    check_reader_limits(&composed, &limits)?;

    phase("writing");
    let t2 = Instant::now();
    let generator = generator(cfg, &upstream, &composed.inlines)?;
    let point_cloud_trees = composed.point_cloud_trees;
    let scene = Scene { generator, graph: composed.graph, trees: composed.trees };
    drop(samples);
    let leaf_refinement = match cfg.leaf_refinement {
        Refinement::On => sct_format::LeafRefinement::All,
        Refinement::Off => sct_format::LeafRefinement::None,
        Refinement::Auto => sct_format::LeafRefinement::OffSurface(point_cloud_trees),
    };
    let wopts = WriteOptions { profile: cfg.profile, compression_level: cfg.compression_level, centre_offsets: cfg.centre_offsets, leaf_refinement, ..Default::default() };
    // Consumed: the trees' nodes are freed as their blocks are written.
    let ws = write_scene_file_owned(&cfg.output, scene, &wopts).map_err(|e| match e {
        sct_format::Error::Io { .. } => BuildError::Io(e.to_string()),
        other => BuildError::Format(other),
    })?;
    rep.seconds.write = t2.elapsed().as_secs_f64();
    rep.bytes = ws.bytes;
    rep.sections = ws.sections;
    rep.bytes_per_leaf = if rep.leaves > 0 { rep.bytes as f64 / rep.leaves as f64 } else { 0.0 };
    container_figures(&mut rep, &ws.trees);
    rep.seconds.total = t0.elapsed().as_secs_f64();
    rep.peak_memory_bytes = peak_memory();
    rep.peak_bytes_per_sample = rep.peak_memory_bytes.filter(|_| rep.samples > 0).map(|p| p as f64 / rep.samples as f64);
    Ok(rep)
}

/// Default of the bytes that baking affine instances may cost ([`bake_affine_instances`]):
/// 2 GiB, about 16.7 million baked samples at [`BAKED_BYTES_PER_SAMPLE`].
pub const DEFAULT_MAX_BAKED_BYTES: u64 = 2 << 30;

/// Peak bytes one baked sample costs through the build: the baked copy (40-byte node), the
/// copy handed to the tree builder and its tree (about two nodes per leaf) — about 120
/// bytes measured (1,000 placements of a 56 k-sample mesh: 6.8 GB), rounded up.
pub const BAKED_BYTES_PER_SAMPLE: u64 = 128;

/// Turns affine placements (spec §8) into baked meshes — the samples mapped through each
/// matrix — placed at the identity: all of them with `all` (`--bake-affine`), else only
/// those an affine instance node cannot hold (spec §7: a condition number above
/// [`sct_format::affine::MAX_CONDITION`], an entry beyond the f32 range); the others stay in
/// `samples.affine_instances` and become affine instances of their mesh's one tree. All
/// placements of one mesh are baked into one mesh `NAME#affine` (one tree, not one per
/// placement: 5,000 placements made 5,000 trees, more sections than a reader accepts).
/// Original meshes keep their indices and names (scene files refer to them); a mesh left
/// with no similarity instance is simply not built.
///
/// A few bytes of compressed `AFFI` entries can ask for billions of baked samples, so
/// before anything is allocated the baked total (placements × samples of their mesh) is
/// checked against `limits.max_samples` and its memory, at [`BAKED_BYTES_PER_SAMPLE`],
/// against `max_bytes`. A matrix that maps a sample to a non-finite node (finite but huge
/// entries) is refused.
pub fn bake_affine_instances(samples: &mut SamplesFile, limits: &Limits, max_bytes: u64, all: bool) -> Result<(), BuildError> {
    // Kept as instances: nothing to bake for them.
    let (bake, keep): (Vec<_>, Vec<_>) = std::mem::take(&mut samples.affine_instances).into_iter().partition(|a| all || !a.affine().is_valid());
    samples.affine_instances = bake;
    let kept = keep;
    let placements = samples.affine_instances.len();
    let mut baked = 0u64;
    for a in &samples.affine_instances {
        let count = samples.meshes.get(a.mesh as usize).map_or(0, |m| m.count);
        baked = baked.checked_add(count).ok_or_else(|| BuildError::Input(format!("baking {placements} affine placements overflows the sample count")))?;
    }
    let total = (samples.samples.len() as u64).checked_add(baked).filter(|&t| t <= limits.max_samples);
    let bytes = baked.checked_mul(BAKED_BYTES_PER_SAMPLE).filter(|&b| b <= max_bytes);
    if total.is_none() || bytes.is_none() {
        return Err(BuildError::Input(format!(
            "baking {placements} affine (non-similarity) placements needs {baked} samples, about {} bytes; the limits are {} bytes of baked samples ({} samples) and {} samples in all",
            baked.saturating_mul(BAKED_BYTES_PER_SAMPLE),
            max_bytes,
            max_bytes / BAKED_BYTES_PER_SAMPLE,
            limits.max_samples
        )));
    }
    // Checked above: the new samples fit in memory's budget, so reserve them exactly (a
    // growing vector could briefly need twice as much).
    samples.samples.reserve_exact(usize::try_from(baked).map_err(|_| BuildError::Input("baked samples exceed the address space".into()))?);
    let affine = std::mem::replace(&mut samples.affine_instances, kept);
    // The placements of each mesh, meshes in the order of their first placement (grouped
    // through a map: a hostile file may list a million placements of distinct meshes).
    let mut groups: Vec<(u32, Vec<usize>)> = Vec::new();
    let mut group_of: std::collections::HashMap<u32, usize> = std::collections::HashMap::new();
    for (k, a) in affine.iter().enumerate() {
        let g = *group_of.entry(a.mesh).or_insert_with(|| {
            groups.push((a.mesh, Vec::new()));
            groups.len() - 1
        });
        groups[g].1.push(k);
    }
    let finite = |n: &sct_format::Node| n.center.iter().chain(&n.normal).chain([&n.radius, &n.area]).all(|v| v.is_finite());
    for (mesh, placements) in groups {
        let Some(src) = samples.meshes.get(mesh as usize).cloned() else { continue };
        if src.count == 0 {
            continue; // nothing to bake, no tree to build
        }
        let first = samples.samples.len() as u64;
        for a in placements.iter().map(|&k| &affine[k]) {
            let stretch = a.max_stretch();
            let start = samples.samples.len();
            let (range_first, range_count) = (src.first as usize, src.count as usize);
            for i in range_first..range_first + range_count {
                let n = a.transform_node(&samples.samples[i], stretch);
                samples.samples.push(n);
            }
            if !samples.samples[start..].iter().all(finite) {
                return Err(BuildError::Input(format!("affine instance of mesh {:?} maps its samples outside the f32 range", src.name)));
            }
        }
        let count = samples.samples.len() as u64 - first;
        let idx = samples.meshes.len() as u32;
        samples.meshes.push(MeshEntry { name: format!("{}#affine", src.name), first, count, two_sided: src.two_sided });
        samples.instances.push(SampleInstance { mesh: idx, transform: sct_format::Similarity::IDENTITY });
    }
    Ok(())
}

/// Normalises every sample's normal to unit length (the spec's samples carry unit normals,
/// and a tree built from others fails its own validation: cone containment, non-unit axes).
/// Normals already unit within 2 f32 epsilons are left bit for bit. A zero, denormal-only
/// or non-finite normal has no direction: refused, naming the sample and its mesh.
pub fn normalize_normals(samples: &mut SamplesFile) -> Result<(), BuildError> {
    use rayon::prelude::*;
    let bad = samples
        .samples
        .par_iter_mut()
        .enumerate()
        .filter_map(|(i, n)| {
            let v = n.normal.map(f64::from);
            let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            if !(len > 0.0 && len.is_finite()) {
                return Some(i);
            }
            if (len - 1.0).abs() > 2.0 * f64::from(f32::EPSILON) {
                n.normal = v.map(|c| (c / len) as f32);
            }
            None
        })
        .min();
    if let Some(i) = bad {
        let mesh = samples.meshes.iter().find(|m| (m.first..m.first.saturating_add(m.count)).contains(&(i as u64)));
        let name = mesh.map_or_else(|| "no mesh".to_string(), |m| format!("mesh {:?}", m.name));
        return Err(BuildError::Input(format!(
            "sample {i} ({name}) has normal {:?}, which has no direction (zero or not finite); every sample needs a non-zero finite normal",
            samples.samples[i].normal
        )));
    }
    Ok(())
}

/// Sections of a file besides its trees: `GENR` and `GRPH` (spec §3).
const FIXED_SECTIONS: u64 = 2;

/// Trees a build without a scene file makes: one per mesh with an instance, plus the group
/// over them when there is more than one instance.
fn source_tree_count(samples: &SamplesFile) -> u64 {
    let mut meshes: Vec<u32> = samples.instances.iter().map(|i| i.mesh).chain(samples.affine_instances.iter().map(|a| a.mesh)).collect();
    meshes.sort_unstable();
    meshes.dedup();
    meshes.len() as u64 + u64::from(samples.instances.len() + samples.affine_instances.len() > 1)
}

fn check_sections(trees: u64, limits: &Limits) -> Result<(), BuildError> {
    let sections = trees.saturating_add(FIXED_SECTIONS);
    if sections > u64::from(limits.max_sections) {
        return Err(BuildError::Input(format!(
            "the scene needs {trees} trees, {sections} sections in all, more than the {} sections a reader accepts; use fewer distinct meshes or group them in a scene file",
            limits.max_sections
        )));
    }
    Ok(())
}

/// Checks what is about to be written against the reader's limits: sections, graph nodes,
/// nodes and levels per tree.
fn check_reader_limits(composed: &crate::scene::Composed, limits: &Limits) -> Result<(), BuildError> {
    check_sections(composed.trees.len() as u64, limits)?;
    let over = |what: &str, value: u64, limit: u64| {
        BuildError::Input(format!("the scene has {value} {what}, more than the {limit} a reader accepts"))
    };
    let nodes = composed.graph.nodes.len() as u64;
    if nodes > limits.max_graph_nodes {
        return Err(over("graph nodes", nodes, limits.max_graph_nodes));
    }
    for (i, t) in composed.trees.iter().enumerate() {
        if t.len() as u64 > limits.max_tree_nodes {
            return Err(over(&format!("nodes in tree {i}"), t.len() as u64, limits.max_tree_nodes));
        }
        if t.level_count() as u64 > u64::from(limits.max_tree_levels) {
            return Err(over(&format!("levels in tree {i}"), t.level_count() as u64, limits.max_tree_levels.into()));
        }
    }
    Ok(())
}

/// Refuses a path that is not a regular file (after symlinks) before it is opened: a FIFO
/// blocks `open` forever, a device never ends.
fn ensure_regular(path: &Path) -> Result<(), BuildError> {
    sct_format::fsio::open_regular(path).map(drop).map_err(|e| BuildError::Io(e.to_string()))
}

/// Fills the container, topology and per-stream figures from the writer's statistics.
fn container_figures(rep: &mut Report, trees: &[sct_format::write::TreeStats]) {
    let per_leaf = |b: u64| if rep.leaves > 0 { b as f64 / rep.leaves as f64 } else { 0.0 };
    let mut by_stream: std::collections::BTreeMap<String, u64> = Default::default();
    let mut in_trees = 0;
    for t in trees {
        rep.containers += t.blocks as u64;
        if rep.containers_by_level.len() < t.blocks_per_level.len() {
            rep.containers_by_level.resize(t.blocks_per_level.len(), 0);
        }
        for (c, &b) in rep.containers_by_level.iter_mut().zip(&t.blocks_per_level) {
            *c += b as u64;
        }
        for (name, b) in &t.attribute_bytes {
            *by_stream.entry(name.clone()).or_default() += b;
        }
        *by_stream.entry("index".into()).or_default() += t.index_bytes;
        in_trees += t.section_bytes;
    }
    by_stream.insert("file".into(), rep.bytes.saturating_sub(in_trees));
    if rep.containers > 0 {
        rep.containers_by_height.insert(1, rep.containers);
    }
    rep.links_per_leaf = 0.0;
    rep.topology_bits_per_leaf = 8.0 * per_leaf(by_stream.get("topology").copied().unwrap_or(0));
    rep.bytes_per_leaf_by_stream = by_stream.into_iter().map(|(k, v)| (k, per_leaf(v))).collect();
}

fn generator(cfg: &Config, upstream: &Upstream, inlines: &[(String, String)]) -> Result<Generator, BuildError> {
    let (mut sources, sampling) = match upstream {
        Upstream::SamplesFile(s, g) => (
            vec![s.clone()],
            serde_json::json!({ "tool": g.tool, "version": g.version, "parameters": g.parameters, "sources": g.sources }),
        ),
        Upstream::None => (Vec::new(), serde_json::Value::Null),
        Upstream::Sampled(g) => (
            g.sources.clone(),
            serde_json::json!({ "tool": g.tool, "version": g.version, "parameters": g.parameters }),
        ),
    };
    if let Some(s) = &cfg.scene {
        sources.push(source(s)?);
    }
    sources.extend(inlines.iter().map(|(path, blake3)| SourceRef { path: path.clone(), blake3: blake3.clone() }));
    let weld = match cfg.build.weld {
        Weld::Off => serde_json::json!("off"),
        Weld::Absolute(t) => serde_json::json!({ "absolute": t }),
        Weld::RelativeToMeanRadius(f) => serde_json::json!({ "relative_to_mean_radius": f }),
    };
    let mut parameters = serde_json::json!({
        "profile": cfg.profile.name(),
        "compression_level": cfg.compression_level,
        "centre_offsets": cfg.centre_offsets,
        "leaf_refinement": cfg.leaf_refinement,
        "weld": weld,
        "depth_slack": cfg.build.depth_slack,
        "splitter": "centre of largest extent",
    });
    if let (true, Some(map)) = (cfg.build.bake_affine, parameters.as_object_mut()) {
        map.insert("bake_affine".into(), serde_json::json!(true));
    }
    // The sampling step: the voxelizer's record (a two-step build also keeps the samples
    // file's sources here, so the meshes stay known behind the samples file).
    if let (false, Some(map)) = (sampling.is_null(), parameters.as_object_mut()) {
        map.insert("sampling".into(), sampling);
    }
    Ok(Generator {
        tool: "sct-build-tree".into(),
        version: env!("CARGO_PKG_VERSION").into(),
        parameters,
        sources,
    })
}

fn source(path: &Path) -> Result<SourceRef, BuildError> {
    // Streamed, so hashing a large samples file costs no extra memory.
    let blake3 = sct_format::atomic::hash_file(path).map_err(|e| BuildError::Io(e.to_string()))?;
    Ok(SourceRef { path: path.display().to_string(), blake3 })
}

/// Peak resident set size of this process (Linux `VmHWM`), in bytes.
pub fn peak_memory() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

#[cfg(test)]
mod tests {
    use super::*;
    use sct_format::samples::AffineInstance;
    use sct_format::Node;
    use crate::tree::BuildOptions;

    /// A non-similarity instance becomes its own baked tree whose leaves contain the image
    /// of every original sample sphere (points on each sphere mapped by the matrix).
    #[test]
    fn baked_affine_tree_covers_transformed_samples() {
        let samples: Vec<Node> = (0..400)
            .map(|i| {
                let (t, z) = (i as f32 * 0.37, (i % 20) as f32 * 0.05);
                Node { center: [t.cos(), t.sin(), z], radius: 0.04, normal: [t.cos(), t.sin(), 0.0], cone: 0.0, area: 0.003, color: [200, 10, 10, 255] }
            })
            .collect();
        let mut f = SamplesFile::single_mesh(Generator::default(), "m", samples.clone());
        let a = AffineInstance { mesh: 0, matrix: [[1.0, 0.4, 0.0, 3.0], [0.0, 2.5, 0.0, 0.0], [0.0, 0.0, 0.5, -1.0]] };
        f.affine_instances.push(a);
        let mut huge = f.clone();
        bake_affine_instances(&mut f, &Limits::default(), DEFAULT_MAX_BAKED_BYTES, true).expect("bake");
        assert!(f.affine_instances.is_empty());
        assert_eq!(f.meshes.len(), 2);
        assert_eq!(f.instances.len(), 2);
        assert_eq!(f.instances[1].transform, sct_format::Similarity::IDENTITY);
        let (tree, _) = crate::tree::build_tree(f.mesh_samples(1), &crate::tree::BuildOptions::default()).unwrap();
        let leaves: Vec<&Node> = tree.nodes().iter().enumerate().filter(|(i, _)| tree.children(*i).is_none()).map(|(_, n)| n).collect();
        assert!(!leaves.is_empty());
        for s in &samples {
            let c = s.center.map(f64::from);
            for k in 0..26 {
                let (th, ph) = (k as f64 * 0.9, k as f64 * 0.45);
                let d = [ph.sin() * th.cos(), ph.sin() * th.sin(), ph.cos()];
                let q = a.apply_point(std::array::from_fn(|j| c[j] + f64::from(s.radius) * d[j]));
                let inside = leaves.iter().any(|l| {
                    let dist2: f64 = (0..3).map(|j| (q[j] - f64::from(l.center[j])).powi(2)).sum();
                    dist2 <= f64::from(l.radius).powi(2)
                });
                assert!(inside, "mapped point {q:?} of sample {:?} is outside every baked leaf", s.center);
            }
        }
        // Colour is unchanged by baking.
        assert!(leaves.iter().all(|l| l.color == [200, 10, 10, 255]));

        // Hostile AFFI: many entries need more samples than allowed — refused before baking.
        huge.affine_instances = vec![a; 1000];
        let small = Limits { max_samples: 100 * samples.len() as u64, ..Limits::default() };
        assert!(matches!(bake_affine_instances(&mut huge.clone(), &small, DEFAULT_MAX_BAKED_BYTES, true), Err(BuildError::Input(_))));
        // Finite but huge entries overflow f32: refused, not baked into infinities.
        huge.affine_instances = vec![AffineInstance { mesh: 0, matrix: [[1e300, 0.0, 0.0, 0.0], [0.0, 1e-300, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]] }];
        assert!(matches!(bake_affine_instances(&mut huge, &Limits::default(), DEFAULT_MAX_BAKED_BYTES, true), Err(BuildError::Input(_))));
    }

    /// Without `--bake-affine`, a placement an affine instance can hold stays a placement
    /// (and becomes an affine instance node of the mesh's one tree); one beyond the
    /// condition limit (spec §7) is baked as before.
    #[test]
    fn affine_placements_are_kept_unless_ill_conditioned() {
        let stretch = AffineInstance { mesh: 0, matrix: [[1.0, 0.4, 0.0, 3.0], [0.0, 2.5, 0.0, 0.0], [0.0, 0.0, 0.5, -1.0]] };
        let flat = AffineInstance { mesh: 0, matrix: [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1e-7, 5.0]] };
        let mut f = SamplesFile::single_mesh(Generator::default(), "m", ring(400));
        f.affine_instances = vec![stretch, flat];
        let g = f.clone();
        bake_affine_instances(&mut f, &Limits::default(), DEFAULT_MAX_BAKED_BYTES, false).expect("bake");
        assert_eq!(f.affine_instances, vec![stretch]);
        assert_eq!((f.meshes.len(), f.instances.len(), f.samples.len()), (2, 2, 800));
        let dir = tempfile::tempdir().expect("tempdir");
        let out = dir.path().join("kept.sct");
        let rep = build(g, &out).expect("build");
        // The mesh's tree, the flat placement's baked tree, the group.
        assert_eq!((rep.trees, rep.instances, rep.affine_instances), (3, 1, 1));
        let r = sct_format::SctReader::open(&out, &Limits::default()).expect("open");
        assert_eq!(r.header().minor, 3);
        assert!(r.graph().nodes.iter().any(|n| matches!(n, sct_format::GraphNode::Affine { transform, .. } if transform.matrix == stretch.matrix)));
    }

    fn ring(n: usize) -> Vec<Node> {
        (0..n)
            .map(|i| {
                let t = i as f32 * 0.37;
                Node { center: [t.cos(), t.sin(), (i % 7) as f32 * 0.1], radius: 0.05, normal: [t.cos(), t.sin(), 0.0], cone: 0.0, area: 0.004, color: [90, 120, 200, 255] }
            })
            .collect()
    }

    fn config(out: &Path) -> Config {
        Config {
            samples: PathBuf::new(),
            output: out.to_path_buf(),
            scene: None,
            profile: sct_format::Profile::Raw,
            compression_level: None,
            centre_offsets: true,
            leaf_refinement: Default::default(),
            build: BuildOptions::default(),
        }
    }

    fn build(f: SamplesFile, out: &Path) -> Result<Report, BuildError> {
        run_samples(&config(out), f, Upstream::None, Instant::now(), &mut |_| {})
    }

    /// Item 13: a 10 KB samples file can ask for 10⁶ placements of one mesh, or 1,000 of a
    /// 56 k-sample mesh: refused by the baked-bytes limit before anything is allocated
    /// (the sample-count limit alone let 3.6–6.8 GB through).
    #[test]
    fn baking_is_bounded_in_bytes_before_allocating() {
        let stretch = AffineInstance { mesh: 0, matrix: [[1.0, 0.0, 0.0, 0.0], [0.0, 3.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]] };
        for (samples, placements) in [(64usize, 1_000_000usize), (56_000, 1_000)] {
            let mut f = SamplesFile::single_mesh(Generator::default(), "m", ring(samples));
            f.affine_instances = vec![stretch; placements];
            let e = bake_affine_instances(&mut f, &Limits::default(), DEFAULT_MAX_BAKED_BYTES, true).expect_err("refused");
            assert!(matches!(&e, BuildError::Input(m) if m.contains("bytes")), "{e}");
            // Nothing was baked or reserved for it.
            assert_eq!((f.meshes.len(), f.samples.len()), (1, samples));
            assert!(f.samples.capacity() < 2 * samples);
        }
        // Under the limit: baked.
        let mut f = SamplesFile::single_mesh(Generator::default(), "m", ring(400));
        f.affine_instances = vec![stretch; 100];
        bake_affine_instances(&mut f, &Limits::default(), DEFAULT_MAX_BAKED_BYTES, true).expect("baked");
        assert_eq!(f.samples.len(), 400 * 101);
    }

    /// Item 15: 5,000 non-uniformly scaled placements of one mesh (a realistic glTF) build
    /// one tree (the mesh's, under 5,000 affine instances; baked: one tree of all copies),
    /// and the file opens with the reader's default limits. A samples file
    /// whose instances need more trees than a reader accepts sections is refused before any
    /// tree is built, with a clear error.
    #[test]
    fn the_writer_never_writes_more_sections_than_a_reader_accepts() {
        let dir = tempfile::tempdir().expect("tempdir");
        let out = dir.path().join("many.sct");
        let mut f = SamplesFile::single_mesh(Generator::default(), "m", ring(20));
        f.affine_instances = (0..5000)
            .map(|i| AffineInstance { mesh: 0, matrix: [[1.0, 0.0, 0.0, i as f64 * 3.0], [0.0, 2.0, 0.0, 0.0], [0.0, 0.0, 0.5, 0.0]] })
            .collect();
        // The similarity placement of the source goes too: only the affine ones remain.
        f.instances.clear();
        let rep = build(f, &out).expect("builds");
        assert_eq!((rep.trees, rep.affine_instances), (2, 5000), "the mesh's tree and the group's");
        let reader = sct_format::read::SctReader::open(&out, &Limits::default()).expect("a reader accepts it");
        assert!(reader.sections().len() as u64 <= u64::from(Limits::default().max_sections));

        let n = Limits::default().max_sections as usize;
        let samples: Vec<Node> = (0..n).flat_map(|m| ring(2).into_iter().map(move |mut s| {
            s.center[0] += m as f32 * 4.0;
            s
        })).collect();
        let meshes = (0..n).map(|m| MeshEntry { name: format!("m{m}"), first: 2 * m as u64, count: 2, two_sided: false }).collect();
        let instances = (0..n as u32).map(|m| SampleInstance { mesh: m, transform: sct_format::Similarity::IDENTITY }).collect();
        let f = SamplesFile { generator: Generator::default(), meshes, instances, affine_instances: Vec::new(), samples };
        let out = dir.path().join("refused.sct");
        let e = build(f, &out).expect_err("too many sections");
        assert!(matches!(&e, BuildError::Input(m) if m.contains("sections")), "{e}");
        assert!(!out.exists());
    }

    /// Item 18: normals scaled by 1000, tiny, denormal or of a slightly wrong length are
    /// normalised at input, so the written file passes the deep validation (cone
    /// containment, unit axes); a zero or non-finite normal is refused naming the sample.
    #[test]
    fn normals_are_normalised_or_refused() {
        let dir = tempfile::tempdir().expect("tempdir");
        let mut s = ring(300);
        for (i, n) in s.iter_mut().enumerate() {
            let k = [1000.0, 1e-20, 1e-40 / n.normal.iter().map(|c| c.abs()).fold(0.0, f32::max).max(1e-3), 1.01, 1.0][i % 5];
            n.normal = n.normal.map(|c| c * k);
        }
        assert!(s[2].normal.iter().any(|c| *c != 0.0 && c.abs() < f32::MIN_POSITIVE), "a denormal normal is tested");
        let out = dir.path().join("n.sct");
        build(SamplesFile::single_mesh(Generator::default(), "m", s.clone()), &out).expect("builds");
        let opts = sct_format::validate::ValidateOptions { deep: true, ..Default::default() };
        let report = sct_format::validate::validate_file(&out, &opts).expect("validate");
        assert!(report.is_valid(), "{:?}", report.issues);

        for bad in [[0.0; 3], [f32::NAN, 0.0, 1.0], [f32::INFINITY, 0.0, 0.0]] {
            let mut s = s.clone();
            s[7].normal = bad;
            let e = build(SamplesFile::single_mesh(Generator::default(), "m", s), &dir.path().join("bad.sct")).expect_err("refused");
            assert!(matches!(&e, BuildError::Input(m) if m.contains("sample 7") && m.contains("\"m\"")), "{e}");
        }
    }

    /// Item 5: a samples file or scene file that is a FIFO is refused at once (opening it
    /// for reading would block forever), naming it.
    #[cfg(unix)]
    #[test]
    fn fifo_inputs_are_refused_without_blocking() {
        let dir = tempfile::tempdir().expect("tempdir");
        let fifo = dir.path().join("in.samples");
        assert!(std::process::Command::new("mkfifo").arg(&fifo).status().expect("mkfifo").success());
        let mut cfg = config(&dir.path().join("o.sct"));
        cfg.samples = fifo.clone();
        let e = run(&cfg, &mut |_| {}).expect_err("refused");
        assert!(matches!(&e, BuildError::Io(m) if m.contains("in.samples") && m.contains("FIFO")), "{e}");
        cfg.scene = Some(fifo);
        let e = run_samples(&cfg, SamplesFile::single_mesh(Generator::default(), "m", ring(10)), Upstream::None, Instant::now(), &mut |_| {}).expect_err("refused");
        assert!(matches!(&e, BuildError::Io(m) if m.contains("FIFO")), "{e}");
    }
}
