//! Build-tree benchmark (plain binary, no harness).
//!
//! `cargo bench -p build-tree --bench build -- [N] [PLY] [OUT.samples]`
//!
//! Synthetic samples (for real voxelized samples and the CLI figures see BENCHMARKS.md,
//! "Build tree"): drawn uniformly on the triangles of an ASCII PLY
//! mesh (default: the Stanford bunny), N of them (default 1,401,494 as in thesis Table 8).
//! Writes the samples file (for the end-to-end CLI measurement), then times the library
//! phases in process: partition, layout, attributes, encode+write, and reports leaf
//! samples/s and bytes per leaf. Peak memory of a build is measured by the CLI's `--json`
//! (a separate process, so sample generation does not count).

use std::path::PathBuf;
use std::time::Instant;

use build_tree::{build_tree, BuildOptions};
use sct_format::graph::Generator;
use sct_format::samples::SamplesFile;
use sct_format::write::{write_scene_file, Scene, WriteOptions};
use sct_format::{Node, Profile};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).filter(|a| !a.starts_with("--")).collect();
    let n: usize = args.first().map(|s| s.parse()).transpose()?.unwrap_or(1_401_494);
    let ply = PathBuf::from(
        args.get(1).cloned().unwrap_or("/work/shared/models/scans/stanford-bunny-original-ply/bun_zipper.ply".into()),
    );
    let out = PathBuf::from(args.get(2).cloned().unwrap_or(format!("/tmp/bench-{n}.samples")));
    let (verts, faces) = read_ascii_ply(&ply)?;
    let samples = sample_surface(&verts, &faces, n);
    let file = SamplesFile::single_mesh(Generator { tool: "build-tree bench".into(), ..Default::default() }, "bunny", samples);
    file.write_file(&out)?;
    println!("samples: {n} from {} ({} triangles) -> {}", ply.display(), faces.len(), out.display());

    for threads in [1, 2] {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build()?;
        let (tree, st) = pool.install(|| build_tree(&file.samples, &BuildOptions::default()))?;
        let build_s = st.partition_s + st.layout_s + st.attributes_s;
        println!(
            "threads {threads}: leaves {} nodes {} depth {} welded {} forced {} | partition {:.3}s layout {:.3}s attributes {:.3}s | tree {:.2} M leaves/s",
            st.leaves, st.nodes, st.depth, st.welded, st.forced_splits, st.partition_s, st.layout_s, st.attributes_s,
            st.leaves as f64 / build_s / 1e6
        );
        let m = tightness(&tree);
        println!("  mean parent/child radius ratio {:.4}, sum of internal radii / root radius {:.1}", m.0, m.1);
        for profile in [Profile::Default, Profile::Canopy] {
            let path = std::env::temp_dir().join(format!("bench-{n}-{}.sct", profile.name()));
            let t = Instant::now();
            let scene = Scene::single_tree(Generator::default(), tree.clone());
            let ws = pool.install(|| write_scene_file(&path, &scene, &WriteOptions { profile, ..Default::default() }))?;
            let w = t.elapsed().as_secs_f64();
            println!(
                "  {}: write {:.3}s, {} bytes, {:.2} B/leaf; end-to-end (build + write) {:.2} M leaves/s",
                profile.name(), w, ws.bytes, ws.bytes as f64 / st.leaves as f64, st.leaves as f64 / (build_s + w) / 1e6
            );
        }
    }
    Ok(())
}

/// Mean ratio of parent radius to the larger child radius, and summed internal radii
/// relative to the root: lower is tighter.
fn tightness(t: &sct_format::SceneTree) -> (f64, f64) {
    let (mut ratio, mut count, mut sum) = (0f64, 0u64, 0f64);
    let nodes = t.nodes();
    for i in 0..t.len() {
        if let Some([a, b]) = t.children(i) {
            let m = nodes[a].radius.max(nodes[b].radius) as f64;
            if m > 0.0 {
                ratio += nodes[i].radius as f64 / m;
                count += 1;
            }
            sum += nodes[i].radius as f64;
        }
    }
    (ratio / count.max(1) as f64, sum / nodes[0].radius.max(f32::MIN_POSITIVE) as f64)
}

/// Vertices and triangles of a mesh.
type Mesh = (Vec<[f64; 3]>, Vec<[usize; 3]>);

fn read_ascii_ply(path: &std::path::Path) -> Result<Mesh, Box<dyn std::error::Error>> {
    let text = std::fs::read_to_string(path)?;
    let mut lines = text.lines();
    let (mut nv, mut nf) = (0usize, 0usize);
    for l in lines.by_ref() {
        let w: Vec<&str> = l.split_whitespace().collect();
        match w.as_slice() {
            ["element", "vertex", n] => nv = n.parse()?,
            ["element", "face", n] => nf = n.parse()?,
            ["format", f, ..] if *f != "ascii" => return Err(format!("{f} PLY: only ASCII is supported here").into()),
            ["end_header"] => break,
            _ => {}
        }
    }
    let mut verts = Vec::with_capacity(nv);
    for _ in 0..nv {
        let w: Vec<f64> = lines.next().ok_or("short vertex list")?.split_whitespace().take(3).map(str::parse).collect::<Result<_, _>>()?;
        verts.push([w[0], w[1], w[2]]);
    }
    let mut faces = Vec::with_capacity(nf);
    for _ in 0..nf {
        let w: Vec<usize> = lines.next().ok_or("short face list")?.split_whitespace().map(str::parse).collect::<Result<_, _>>()?;
        for k in 2..w[0] {
            faces.push([w[1], w[k], w[k + 1]]);
        }
    }
    Ok((verts, faces))
}

/// `n` samples uniformly distributed over the surface (deterministic).
fn sample_surface(v: &[[f64; 3]], f: &[[usize; 3]], n: usize) -> Vec<Node> {
    let sub = |a: [f64; 3], b: [f64; 3]| [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    let cross = |a: [f64; 3], b: [f64; 3]| [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
    let mut cdf = Vec::with_capacity(f.len());
    let mut normals = Vec::with_capacity(f.len());
    let mut total = 0.0;
    for t in f {
        let c = cross(sub(v[t[1]], v[t[0]]), sub(v[t[2]], v[t[0]]));
        let l = (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt();
        total += 0.5 * l;
        cdf.push(total);
        normals.push(if l > 0.0 { [c[0] / l, c[1] / l, c[2] / l] } else { [0.0, 0.0, 1.0] });
    }
    let area = total / n as f64;
    let radius = 1.5 * (area / std::f64::consts::PI).sqrt();
    let mut s = 0x1234_5678_9abc_def0u64;
    let mut rnd = move || {
        s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    (0..n)
        .map(|_| {
            let x = rnd() * total;
            let i = cdf.partition_point(|&c| c < x).min(f.len() - 1);
            let (mut a, mut b) = (rnd(), rnd());
            if a + b > 1.0 {
                (a, b) = (1.0 - a, 1.0 - b);
            }
            let t = f[i];
            let p: [f64; 3] = std::array::from_fn(|k| v[t[0]][k] + a * (v[t[1]][k] - v[t[0]][k]) + b * (v[t[2]][k] - v[t[0]][k]));
            let nn = normals[i];
            Node {
                center: p.map(|x| x as f32),
                radius: radius as f32,
                normal: nn.map(|x| x as f32),
                cone: 0.0,
                area: area as f32,
                color: [(127.5 + 127.5 * nn[0]) as u8, (127.5 + 127.5 * nn[1]) as u8, (127.5 + 127.5 * nn[2]) as u8, 255],
            }
        })
        .collect()
}
