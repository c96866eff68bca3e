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
    for seed in [&include_bytes!("../../../fuzz/seeds/samples_reader/cube.samples")[..], include_bytes!("../../../fuzz/seeds/samples_reader/instancing.samples")] {
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
    let seed = include_bytes!("../../../fuzz/seeds/samples_reader/cube_smpc.samples");
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
    let smps = include_bytes!("../../../fuzz/seeds/samples_reader/cube_smps.samples");
    assert!(!chunk_counts(smps).is_empty());
    let old = SamplesFile::read(include_bytes!("../../../fuzz/seeds/samples_reader/cube_smpc.samples"), &Limits::default()).unwrap();
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
