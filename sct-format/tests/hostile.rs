//! Hostile input: every error variant from a crafted file, truncation at every offset,
//! single-bit flips, unknown sections and newer versions. None may panic.

mod common;

use sct_format::container::{write_container, SectionOut};
use sct_format::raw::{tags, SCT_MAGIC};
use sct_format::read::SctReader;
use sct_format::{write_scene, Error, Generator, GraphNode, Limits, Profile, Scene, SceneGraph, SceneTree, WriteOptions};

fn scene(nodes: usize) -> Scene {
    Scene::single_tree(Generator { tool: "test".into(), ..Default::default() }, common::random_tree(1, nodes, false))
}

fn bytes_of(scene: &Scene, profile: Profile) -> Vec<u8> {
    let mut b = Vec::new();
    write_scene(scene, &WriteOptions { profile, block_nodes: 8, ..Default::default() }, &mut b).expect("write");
    b
}

/// Opens, verifies and fully decodes; the first error wins.
fn read_all(b: Vec<u8>, limits: &Limits) -> Result<Vec<SceneTree>, Error> {
    let r = SctReader::from_bytes(b, limits)?;
    r.verify_checksums()?;
    (0..r.trees().len()).map(|t| r.read_tree(t)).collect()
}

fn fix_header_crc(b: &mut [u8]) {
    let crc = crc32fast::hash(&b[..60]);
    b[60..64].copy_from_slice(&crc.to_le_bytes());
}

#[test]
fn valid_file_reads() {
    for p in [Profile::Raw, Profile::Canopy, Profile::Default] {
        assert_eq!(read_all(bytes_of(&scene(61), p), &Limits::default()).expect("valid").len(), 1);
    }
}

#[test]
fn truncation_at_every_offset_is_a_typed_error() {
    for p in [Profile::Raw, Profile::Canopy, Profile::Default] {
        let b = bytes_of(&scene(61), p);
        for len in 0..b.len() {
            let err = read_all(b[..len].to_vec(), &Limits::default()).expect_err("truncated file must fail");
            assert!(err.is_invalid_input(), "truncated at {len}: {err}");
        }
    }
}

#[test]
fn every_single_bit_flip_is_detected() {
    let b = bytes_of(&scene(61), Profile::Canopy);
    for i in 0..b.len() {
        for bit in 0..8 {
            let mut f = b.clone();
            f[i] ^= 1 << bit;
            match read_all(f, &Limits::default()) {
                Err(e) => assert!(e.is_invalid_input(), "flip {i}:{bit}: {e}"),
                Ok(_) => panic!("flip at byte {i} bit {bit} went unnoticed"),
            }
        }
    }
}

#[test]
fn bad_magic() {
    let mut b = bytes_of(&scene(9), Profile::Raw);
    b[1] = b'X';
    assert!(matches!(read_all(b, &Limits::default()), Err(Error::BadMagic { .. })));
    assert!(matches!(read_all(b"hello".to_vec(), &Limits::default()), Err(Error::BadMagic { .. })));
}

#[test]
fn newer_major_version_is_refused_with_a_clear_message() {
    let mut b = bytes_of(&scene(9), Profile::Raw);
    b[8..10].copy_from_slice(&2u16.to_le_bytes());
    fix_header_crc(&mut b);
    let err = read_all(b, &Limits::default()).expect_err("v2 must be refused");
    assert!(matches!(err, Error::UnsupportedVersion { major: 2, .. }), "{err}");
    assert!(err.to_string().contains("upgrade"), "{err}");
}

#[test]
fn newer_minor_version_is_read() {
    let mut b = bytes_of(&scene(9), Profile::Raw);
    b[10..12].copy_from_slice(&7u16.to_le_bytes());
    fix_header_crc(&mut b);
    read_all(b, &Limits::default()).expect("minor versions are compatible");
}

#[test]
fn checksum_errors_name_the_section() {
    let b = bytes_of(&scene(61), Profile::Raw);
    let r = SctReader::from_bytes(b.clone(), &Limits::default()).expect("valid");
    let tree = r.sections().iter().find(|e| e.tag == tags::TREE).expect("tree").clone();
    let mut f = b;
    let last = (tree.offset + tree.stored_len - 1) as usize;
    f[last] ^= 0x10;
    match read_all(f, &Limits::default()) {
        Err(Error::Checksum { what, .. }) => assert!(what.contains("TREE") || what.contains("block"), "{what}"),
        other => panic!("expected a checksum error, got {other:?}"),
    }
}

/// Rebuilds a file from `scene` plus one extra section.
fn with_extra_section(required: bool) -> Vec<u8> {
    let b = bytes_of(&scene(9), Profile::Raw);
    let r = SctReader::from_bytes(b.clone(), &Limits::default()).expect("valid");
    let mut sections: Vec<SectionOut> = r
        .sections()
        .iter()
        .map(|e| SectionOut {
            tag: e.tag,
            required: e.required(),
            stored: b[e.offset as usize..(e.offset + e.stored_len) as usize].to_vec(),
            raw_len: e.raw_len,
            compressed: e.compressed(),
        })
        .collect();
    let mut extra = SectionOut::plain(*b"XTRA", b"future data".to_vec());
    extra.required = required;
    sections.push(extra);
    let mut out = Vec::new();
    write_container(SCT_MAGIC, &sections, &mut out).expect("container");
    out
}

#[test]
fn unknown_optional_section_is_skipped() {
    let r = SctReader::from_bytes(with_extra_section(false), &Limits::default()).expect("optional sections are skipped");
    assert_eq!(r.skipped_sections(), ["XTRA"]);
    r.read_tree(0).expect("tree still reads");
}

#[test]
fn unknown_required_section_is_rejected() {
    let err = SctReader::from_bytes(with_extra_section(true), &Limits::default()).expect_err("must refuse");
    assert!(matches!(err, Error::UnknownRequiredSection { ref tag, .. } if tag == "XTRA"), "{err}");
}

#[test]
fn limits_are_enforced_before_allocation() {
    let b = bytes_of(&scene(61), Profile::Raw);
    let limits = Limits { max_tree_nodes: 10, ..Limits::default() };
    assert!(matches!(read_all(b.clone(), &limits), Err(Error::LimitExceeded { what: "tree nodes", .. })));
    let limits = Limits { max_sections: 1, ..Limits::default() };
    assert!(matches!(read_all(b, &limits), Err(Error::LimitExceeded { .. })));
}

#[test]
fn huge_claimed_counts_do_not_allocate() {
    // A graph section claiming 2^60 nodes in a few bytes must fail on plausibility, not OOM.
    let mut graph = Vec::new();
    graph.extend_from_slice(&(1u64 << 60).to_le_bytes());
    graph.extend_from_slice(&0u32.to_le_bytes());
    let sections = vec![SectionOut::plain(tags::GENR, b"{\"tool\":\"x\",\"version\":\"0\"}".to_vec()), SectionOut::plain(tags::GRPH, graph)];
    let mut out = Vec::new();
    write_container(SCT_MAGIC, &sections, &mut out).expect("container");
    assert!(matches!(SctReader::from_bytes(out, &Limits::default()), Err(Error::Malformed { .. })));
}

#[test]
fn missing_file_is_an_io_error_with_its_path() {
    let err = SctReader::open(std::path::Path::new("/nonexistent/x.sct"), &Limits::default()).expect_err("missing");
    assert!(matches!(err, Error::Io { path: Some(_), .. }));
    assert!(err.to_string().contains("/nonexistent/x.sct"));
    assert!(!err.is_invalid_input());
}

#[test]
fn writer_rejects_misuse() {
    let mut s = scene(9);
    s.graph = SceneGraph { nodes: vec![GraphNode::Tree { tree: 5 }], root: 0 };
    assert!(matches!(write_scene(&s, &WriteOptions::default(), Vec::new()), Err(Error::Misuse(_))));
    let mut s = scene(9);
    s.graph = SceneGraph { nodes: vec![GraphNode::Tree { tree: 0 }, GraphNode::Group { children: vec![1], tree: 0 }], root: 1 };
    assert!(matches!(write_scene(&s, &WriteOptions::default(), Vec::new()), Err(Error::Misuse(_))));
}
