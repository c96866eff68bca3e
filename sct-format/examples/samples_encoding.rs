//! Measures candidate encodings of the samples file's chunks (spec §8) on a real file: CPU
//! time (this thread's, from /proc) to transform + compress and to decompress + untransform
//! every 65,536-sample chunk, and the compressed size.
//!
//! `cargo run --release -p sct-format --example samples_encoding -- FILE.samples [FILTER]`
//! (FILTER: variants whose name contains it, or `=NAME` for one); `… FILE extract=K:OUT`
//! writes every K-th chunk to OUT (a small file for callgrind); `… FILE rewrite=OUT` writes
//! FILE's content with today's writer (how the fuzz seeds are made); `… FILE read` only reads.

use std::time::Duration;

use sct_format::samples::{SamplesFile, CHUNK_SAMPLES, SAMPLE_BYTES};
use sct_format::{Limits, Node};
use zstd::zstd_safe::{CParameter, Strategy};

/// CPU time of the calling thread (Linux: first field of /proc/thread-self/schedstat, ns).
fn thread_cpu() -> Duration {
    let s = std::fs::read_to_string("/proc/thread-self/schedstat").unwrap_or_default();
    Duration::from_nanos(s.split_whitespace().next().and_then(|v| v.parse().ok()).unwrap_or(0))
}

/// The 36-byte record of a sample, as the columns hold it (centre, radius, normal, area, RGBA).
fn record(s: &Node) -> [u8; SAMPLE_BYTES] {
    let mut r = [0u8; SAMPLE_BYTES];
    let f = [s.center[0], s.center[1], s.center[2], s.radius, s.normal[0], s.normal[1], s.normal[2], s.area];
    for (i, v) in f.iter().enumerate() {
        r[4 * i..4 * i + 4].copy_from_slice(&v.to_le_bytes());
    }
    r[32..].copy_from_slice(&s.color);
    r
}

/// Today's layout: whole columns.
fn columns(samples: &[Node], out: &mut Vec<u8>) {
    out.clear();
    samples.iter().for_each(|s| s.center.iter().for_each(|v| out.extend_from_slice(&v.to_le_bytes())));
    samples.iter().for_each(|s| out.extend_from_slice(&s.radius.to_le_bytes()));
    samples.iter().for_each(|s| s.normal.iter().for_each(|v| out.extend_from_slice(&v.to_le_bytes())));
    samples.iter().for_each(|s| out.extend_from_slice(&s.area.to_le_bytes()));
    samples.iter().for_each(|s| out.extend_from_slice(&s.color));
}

/// How the eight f32 fields are predicted before their bytes are split into planes.
#[derive(Clone, Copy, Debug)]
enum Predict {
    None,
    /// Centres only: bits minus the previous sample's bits (wrapping).
    CentreSub,
    /// Centres only: bits XOR the previous sample's bits.
    CentreXor,
    /// Every f32 field: wrapping subtraction.
    AllSub,
    /// Centres and radius subtracted, other fields as they are.
    CentreRadiusSub,
}

/// Byte planes: plane k holds byte k of every sample's 36-byte record, after `p`.
fn planes(samples: &[Node], p: Predict, out: &mut Vec<u8>) {
    let n = samples.len();
    out.clear();
    out.resize(n * SAMPLE_BYTES, 0);
    let mut prev = [0u32; 8];
    for (i, s) in samples.iter().enumerate() {
        let r = record(s);
        for f in 0..8 {
            let bits = u32::from_le_bytes([r[4 * f], r[4 * f + 1], r[4 * f + 2], r[4 * f + 3]]);
            let v = match (p, f) {
                (Predict::CentreSub | Predict::AllSub, 0..3) | (Predict::AllSub, _) | (Predict::CentreRadiusSub, 0..4) => bits.wrapping_sub(prev[f]),
                (Predict::CentreXor, 0..3) => bits ^ prev[f],
                _ => bits,
            };
            prev[f] = bits;
            for (b, byte) in v.to_le_bytes().into_iter().enumerate() {
                out[(4 * f + b) * n + i] = byte;
            }
        }
        for b in 32..36 {
            out[b * n + i] = r[b];
        }
    }
}

/// Inverse of [`planes`], into samples.
fn unplanes(bytes: &[u8], p: Predict, out: &mut [Node]) {
    let n = out.len();
    let mut prev = [0u32; 8];
    for (i, o) in out.iter_mut().enumerate() {
        let mut f32s = [0f32; 8];
        for f in 0..8 {
            let v = u32::from_le_bytes(std::array::from_fn(|b| bytes[(4 * f + b) * n + i]));
            let bits = match (p, f) {
                (Predict::CentreSub | Predict::AllSub, 0..3) | (Predict::AllSub, _) | (Predict::CentreRadiusSub, 0..4) => v.wrapping_add(prev[f]),
                (Predict::CentreXor, 0..3) => v ^ prev[f],
                _ => v,
            };
            prev[f] = bits;
            f32s[f] = f32::from_bits(bits);
        }
        *o = Node {
            center: [f32s[0], f32s[1], f32s[2]],
            radius: f32s[3],
            normal: [f32s[4], f32s[5], f32s[6]],
            cone: 0.0,
            area: f32s[7],
            color: std::array::from_fn(|b| bytes[(32 + b) * n + i]),
        };
    }
}

fn uncolumns(bytes: &[u8], out: &mut [Node]) {
    let n = out.len();
    let f = |at: usize| f32::from_le_bytes([bytes[at], bytes[at + 1], bytes[at + 2], bytes[at + 3]]);
    for (i, o) in out.iter_mut().enumerate() {
        *o = Node {
            center: [f(12 * i), f(12 * i + 4), f(12 * i + 8)],
            radius: f(12 * n + 4 * i),
            normal: [f(16 * n + 12 * i), f(16 * n + 12 * i + 4), f(16 * n + 12 * i + 8)],
            cone: 0.0,
            area: f(28 * n + 4 * i),
            color: std::array::from_fn(|b| bytes[32 * n + 4 * i + b]),
        };
    }
}

/// The eight f32 fields of a sample, in record order.
fn field(s: &Node, f: usize) -> f32 {
    match f {
        0..3 => s.center[f],
        3 => s.radius,
        4..7 => s.normal[f - 4],
        _ => s.area,
    }
}

fn set_field(s: &mut Node, f: usize, v: f32) {
    match f {
        0..3 => s.center[f] = v,
        3 => s.radius = v,
        4..7 => s.normal[f - 4] = v,
        _ => s.area = v,
    }
}

const T: usize = 1024;

fn put_field<const F: usize>(tile: &[Node], p: &mut [&mut [u8]], delta: bool, prev: &mut u32) {
    let [p0, p1, p2, p3] = p else { unreachable!() };
    let mut pr = *prev;
    if delta {
        for ((((s, b0), b1), b2), b3) in tile.iter().zip(p0.iter_mut()).zip(p1.iter_mut()).zip(p2.iter_mut()).zip(p3.iter_mut()) {
            let bits = field(s, F).to_bits();
            [*b0, *b1, *b2, *b3] = bits.wrapping_sub(pr).to_le_bytes();
            pr = bits;
        }
    } else {
        for ((((s, b0), b1), b2), b3) in tile.iter().zip(p0.iter_mut()).zip(p1.iter_mut()).zip(p2.iter_mut()).zip(p3.iter_mut()) {
            [*b0, *b1, *b2, *b3] = field(s, F).to_bits().to_le_bytes();
        }
    }
    *prev = pr;
}

/// [`planes`] a tile and a field at a time (`delta`: which fields are predicted by subtraction).
fn planes_fast(samples: &[Node], delta: [bool; 8], out: &mut Vec<u8>) {
    let n = samples.len();
    out.clear();
    out.resize(n * SAMPLE_BYTES, 0);
    let mut planes: Vec<&mut [u8]> = out.chunks_exact_mut(n.max(1)).collect();
    let mut prev = [0u32; 8];
    for (t, tile) in samples.chunks(T).enumerate() {
        let r = t * T..t * T + tile.len();
        let mut p: Vec<&mut [u8]> = planes.iter_mut().map(|p| &mut p[r.clone()]).collect();
        put_field::<0>(tile, &mut p[0..4], delta[0], &mut prev[0]);
        put_field::<1>(tile, &mut p[4..8], delta[1], &mut prev[1]);
        put_field::<2>(tile, &mut p[8..12], delta[2], &mut prev[2]);
        put_field::<3>(tile, &mut p[12..16], delta[3], &mut prev[3]);
        put_field::<4>(tile, &mut p[16..20], delta[4], &mut prev[4]);
        put_field::<5>(tile, &mut p[20..24], delta[5], &mut prev[5]);
        put_field::<6>(tile, &mut p[24..28], delta[6], &mut prev[6]);
        put_field::<7>(tile, &mut p[28..32], delta[7], &mut prev[7]);
        let [c0, c1, c2, c3] = &mut p[32..36] else { unreachable!() };
        for ((((s, b0), b1), b2), b3) in tile.iter().zip(c0.iter_mut()).zip(c1.iter_mut()).zip(c2.iter_mut()).zip(c3.iter_mut()) {
            [*b0, *b1, *b2, *b3] = s.color;
        }
    }
}

fn get_field<const F: usize>(tile: &mut [Node], p: &[&[u8]], delta: bool, prev: &mut u32) {
    let [p0, p1, p2, p3] = p else { unreachable!() };
    let mut pr = *prev;
    if delta {
        for ((((o, b0), b1), b2), b3) in tile.iter_mut().zip(*p0).zip(*p1).zip(*p2).zip(*p3) {
            pr = u32::from_le_bytes([*b0, *b1, *b2, *b3]).wrapping_add(pr);
            set_field(o, F, f32::from_bits(pr));
        }
    } else {
        for ((((o, b0), b1), b2), b3) in tile.iter_mut().zip(*p0).zip(*p1).zip(*p2).zip(*p3) {
            set_field(o, F, f32::from_bits(u32::from_le_bytes([*b0, *b1, *b2, *b3])));
        }
    }
    *prev = pr;
}

fn unplanes_fast(bytes: &[u8], delta: [bool; 8], out: &mut [Node]) {
    let n = out.len();
    let planes: Vec<&[u8]> = bytes.chunks_exact(n.max(1)).collect();
    let mut prev = [0u32; 8];
    for (t, tile) in out.chunks_mut(T).enumerate() {
        let r = t * T..t * T + tile.len();
        let p: Vec<&[u8]> = planes.iter().map(|p| &p[r.clone()]).collect();
        get_field::<0>(tile, &p[0..4], delta[0], &mut prev[0]);
        get_field::<1>(tile, &p[4..8], delta[1], &mut prev[1]);
        get_field::<2>(tile, &p[8..12], delta[2], &mut prev[2]);
        get_field::<3>(tile, &p[12..16], delta[3], &mut prev[3]);
        get_field::<4>(tile, &p[16..20], delta[4], &mut prev[4]);
        get_field::<5>(tile, &p[20..24], delta[5], &mut prev[5]);
        get_field::<6>(tile, &p[24..28], delta[6], &mut prev[6]);
        get_field::<7>(tile, &p[28..32], delta[7], &mut prev[7]);
        let [c0, c1, c2, c3] = &p[32..36] else { unreachable!() };
        for ((((o, b0), b1), b2), b3) in tile.iter_mut().zip(*c0).zip(*c1).zip(*c2).zip(*c3) {
            o.color = [*b0, *b1, *b2, *b3];
            o.cone = 0.0;
        }
    }
}

#[derive(Clone, Copy, Debug)]
enum Layout {
    Columns,
    Planes(Predict),
    Fast([bool; 8]),
}

struct Variant {
    name: String,
    layout: Layout,
    level: i32,
    params: Vec<CParameter>,
}

#[inline(never)]
fn run(samples: &[Node], v: &Variant) {
    let mut z = zstd::bulk::Compressor::new(v.level).unwrap();
    for p in &v.params {
        z.set_parameter(*p).unwrap();
    }
    let mut d = zstd::bulk::Decompressor::new().unwrap();
    let (mut raw, mut back) = (Vec::new(), Vec::new());
    let mut out = vec![Node::default(); CHUNK_SAMPLES];
    let (mut t_lay, mut t_z, mut t_unz, mut t_unlay) = (Duration::ZERO, Duration::ZERO, Duration::ZERO, Duration::ZERO);
    let mut stored = 0usize;
    for chunk in samples.chunks(CHUNK_SAMPLES) {
        let t0 = thread_cpu();
        match v.layout {
            Layout::Columns => columns(chunk, &mut raw),
            Layout::Planes(p) => planes(chunk, p, &mut raw),
            Layout::Fast(d) => planes_fast(chunk, d, &mut raw),
        }
        let t1 = thread_cpu();
        let frame = z.compress(&raw).unwrap();
        let t2 = thread_cpu();
        back.clear();
        back.reserve(raw.len());
        d.decompress_to_buffer(&frame, &mut back).unwrap();
        let t3 = thread_cpu();
        let o = &mut out[..chunk.len()];
        match v.layout {
            Layout::Columns => uncolumns(&back, o),
            Layout::Planes(p) => unplanes(&back, p, o),
            Layout::Fast(d) => unplanes_fast(&back, d, o),
        }
        let t4 = thread_cpu();
        assert!(o.iter().zip(chunk).all(|(a, b)| record(a) == record(b)), "{} not lossless", v.name);
        stored += frame.len() + 8;
        t_lay += t1 - t0;
        t_z += t2 - t1;
        t_unz += t3 - t2;
        t_unlay += t4 - t3;
    }
    let ms = |d: Duration| d.as_secs_f64() * 1e3;
    println!(
        "{:<34} {:>12} {:>6.2} B/s | write {:>7.0} ms (layout {:>5.0} + zstd {:>6.0}) | read {:>6.0} ms (zstd {:>5.0} + layout {:>5.0})",
        v.name,
        stored,
        stored as f64 / samples.len() as f64,
        ms(t_lay + t_z),
        ms(t_lay),
        ms(t_z),
        ms(t_unz + t_unlay),
        ms(t_unz),
        ms(t_unlay)
    );
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let path = args.get(1).expect("usage: samples_encoding FILE.samples [FILTER]");
    let filter = args.get(2).cloned().unwrap_or_default();
    let f = SamplesFile::read_file(std::path::Path::new(path), &Limits::default()).unwrap();
    if filter == "read" {
        // Just the reader (for callgrind, old against new files).
        return;
    }
    if let Some(out) = filter.strip_prefix("rewrite=") {
        // The same content through today's writer (fuzz seeds).
        f.write_file(std::path::Path::new(out)).unwrap();
        return;
    }
    if let Some(stride) = filter.strip_prefix("extract=") {
        // Every stride-th chunk into a small file (for callgrind).
        let (stride, out) = stride.split_once(':').unwrap();
        let stride: usize = stride.parse().unwrap();
        let samples: Vec<Node> = f.samples.chunks(CHUNK_SAMPLES).step_by(stride).flatten().copied().collect();
        SamplesFile::single_mesh(f.generator.clone(), "subset", samples).write_file(std::path::Path::new(out)).unwrap();
        return;
    }
    println!("{}: {} samples", path, f.samples.len());
    let mut variants = Vec::new();
    for level in [1, -1, -3] {
        variants.push(Variant { name: format!("columns L{level}"), layout: Layout::Columns, level, params: vec![] });
    }
    for p in [Predict::None, Predict::CentreSub, Predict::CentreXor, Predict::AllSub, Predict::CentreRadiusSub] {
        for level in [1, -1, -3] {
            variants.push(Variant { name: format!("planes {p:?} L{level}"), layout: Layout::Planes(p), level, params: vec![] });
        }
    }
    let none = [false; 8];
    let centre = [true, true, true, false, false, false, false, false];
    let all = [true; 8];
    for (name, d) in [("none", none), ("centre", centre), ("all", all)] {
        for level in [1, -1] {
            variants.push(Variant { name: format!("fast {name} L{level}"), layout: Layout::Fast(d), level, params: vec![] });
        }
    }
    let sub = Layout::Planes(Predict::CentreSub);
    for (name, params) in [
        ("minmatch7", vec![CParameter::MinMatch(7)]),
        ("minmatch4", vec![CParameter::MinMatch(4)]),
        ("hashlog12", vec![CParameter::HashLog(12)]),
        ("hashlog16", vec![CParameter::HashLog(16)]),
        ("dfast", vec![CParameter::Strategy(Strategy::ZSTD_dfast)]),
        ("wlog17", vec![CParameter::WindowLog(17)]),
        ("tlen1", vec![CParameter::TargetLength(1)]),
    ] {
        variants.push(Variant { name: format!("planes CentreSub L1 {name}"), layout: sub, level: 1, params: params.clone() });
        variants.push(Variant { name: format!("columns L1 {name}"), layout: Layout::Columns, level: 1, params });
    }
    let exact = filter.starts_with('=');
    for v in variants.iter().filter(|v| if exact { v.name == filter[1..] } else { v.name.contains(&filter) }) {
        run(&f.samples, v);
    }
}
