//! Node codec figures on a real tree: encode (+ zstd) and decode throughput and size per
//! profile, zstd level and block size.
//!
//! `cargo run --release -p sct-format --example codec -- TREE.sct [RUNS] [CONFIG...]`
//!
//! TREE.sct: any SCT file; its tree 0 is decoded and re-encoded (write it with
//! `sct-build-tree --profile raw` to start from the exact tree).
//!
//! CONFIG is `profile:level:block_nodes` (level `-` = the profile's default, 0 = none);
//! without any, a fixed sweep is run. Each figure is the median of RUNS (default 3) runs.
//! Encode = `sct_format::write::encode_tree` in memory (parallel blocks, current rayon pool);
//! decode = `SctReader::read_tree` of the file written with the same options, from memory.
//! CPU seconds (all threads) are given beside wall seconds: on a loaded machine they vary less.

use std::time::Instant;

use sct_format::graph::Generator;
use sct_format::write::{encode_tree, write_scene, Scene, WriteOptions};
use sct_format::{Limits, Profile, SctReader};

/// CPU seconds (user + system) of this process so far, from /proc (0 elsewhere): steadier than
/// wall time on a machine shared with other builds.
fn cpu_s() -> f64 {
    let s = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    // Fields after the parenthesised command name; utime and stime are the 12th and 13th.
    let rest = s.rsplit_once(')').map_or("", |r| r.1);
    let f: Vec<&str> = rest.split_whitespace().collect();
    let num = |i: usize| f.get(i).and_then(|x| x.parse::<f64>().ok()).unwrap_or(0.0);
    (num(11) + num(12)) / 100.0
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let path = args.first().ok_or("usage: codec TREE.sct [RUNS] [profile:level:block...]")?;
    let runs: usize = args.get(1).map(|s| s.parse()).transpose()?.unwrap_or(3);
    let mut configs: Vec<(Profile, Option<i32>, u32)> = Vec::new();
    for c in args.iter().skip(2) {
        let p: Vec<&str> = c.split(':').collect();
        if p.len() != 3 {
            return Err(format!("bad config {c:?}: expected profile:level:block_nodes").into());
        }
        let level = if p[1] == "-" { None } else { Some(p[1].parse()?) };
        configs.push((p[0].parse()?, level, p[2].parse()?));
    }
    if configs.is_empty() {
        configs = vec![
            (Profile::Raw, None, 16384),
            (Profile::Canopy, None, 16384),
            (Profile::Default, Some(0), 16384),
            (Profile::Default, Some(3), 16384),
            (Profile::Default, None, 16384),
            (Profile::Default, Some(19), 16384),
        ];
    }
    let tree = SctReader::open(std::path::Path::new(path), &Limits::default())?.read_tree(0)?;
    let leaves = tree.leaf_count();
    println!("{path}: {leaves} leaves, {} nodes, {} levels, {runs} runs, {} rayon threads", tree.len(), tree.level_count(), rayon::current_num_threads());
    println!("| profile | zstd | block nodes | bytes | B/leaf | encode s | encode cpu s | encode M nodes/s | decode s | decode cpu s | decode M nodes/s |");
    println!("|---|---|---|---|---|---|---|---|---|---|---|");
    let nodes = tree.len() as f64;
    let scene = Scene::single_tree(Generator::default(), tree);
    for (profile, level, block_nodes) in configs {
        let opts = WriteOptions { profile, compression_level: level, block_nodes, ..Default::default() };
        let mut enc = Vec::new();
        let mut enc_cpu = Vec::new();
        let mut dec_cpu = Vec::new();
        let mut bytes = 0;
        for _ in 0..runs {
            let (t, c) = (Instant::now(), cpu_s());
            let (b, _) = encode_tree(&scene.trees[0], &opts)?;
            enc.push(t.elapsed().as_secs_f64());
            enc_cpu.push(cpu_s() - c);
            bytes = b.len();
        }
        let mut buf = Vec::new();
        write_scene(&scene, &opts, &mut buf)?;
        let reader = SctReader::from_bytes(buf, &Limits::default())?;
        let mut dec = Vec::new();
        for _ in 0..runs {
            let (t, c) = (Instant::now(), cpu_s());
            let back = reader.read_tree(0)?;
            dec.push(t.elapsed().as_secs_f64());
            dec_cpu.push(cpu_s() - c);
            if back.len() != scene.trees[0].len() {
                return Err("decoded tree has a different node count".into());
            }
        }
        let (e, d, ec, dc) = (median(enc), median(dec), median(enc_cpu), median(dec_cpu));
        println!(
            "| {} | {} | {block_nodes} | {bytes} | {:.3} | {e:.3} | {ec:.2} | {:.2} | {d:.3} | {dc:.2} | {:.2} |",
            profile.name(),
            level.map_or("-".to_string(), |l| l.to_string()),
            bytes as f64 / leaves as f64,
            nodes / e / 1e6,
            nodes / d / 1e6
        );
    }
    Ok(())
}
