//! The whole chain through the libraries: mesh → samples → SCT → validation → preview.

use std::path::{Path, PathBuf};

use sct_format::validate::{validate_file, ValidateOptions};
use sct_format::{Limits, Profile, SctReader};

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().expect("workspace root").to_path_buf()
}

fn voxelize(model: &Path, out: &Path) -> voxelize::Summary {
    let opts = voxelize::Options {
        inputs: vec![model.to_path_buf()],
        output: Some(out.to_path_buf()),
        load: Default::default(),
        sample: Default::default(),
    };
    voxelize::run(&opts, &|_, _| {}).expect("voxelize")
}

fn build(samples: &Path, out: &Path, profile: Profile) -> build_tree::pipeline::Report {
    let cfg = build_tree::pipeline::Config {
        samples: samples.to_path_buf(),
        output: out.to_path_buf(),
        scene: None,
        profile,
        compression_level: None,
        build: Default::default(),
    };
    build_tree::pipeline::run(&cfg, &mut |_| {}).expect("build")
}

#[test]
fn embedded_demo_model_goes_through_every_tool() {
    let dir = tempfile::tempdir().expect("tempdir");
    let samples = dir.path().join("fuze.samples");
    let vox = voxelize(&repo().join("assets/fuze/fuze.obj"), &samples);
    assert!(vox.samples > 10_000, "{} samples", vox.samples);

    for profile in [Profile::Default, Profile::Canopy, Profile::Raw] {
        let sct = dir.path().join(format!("fuze-{}.sct", profile.name()));
        build(&samples, &sct, profile);

        // Every sample is a leaf (welding only merges exact near-duplicates).
        let r = SctReader::open(&sct, &Limits::default()).expect("open");
        let tree = r.read_tree(0).expect("decode");
        assert!(tree.leaf_count() as u64 <= vox.samples && tree.leaf_count() as u64 * 100 >= vox.samples * 99);
        assert_eq!(tree.len(), 2 * tree.leaf_count() - 1);

        let report = validate_file(&sct, &ValidateOptions { deep: true, limits: Limits::default(), ..Default::default() }).expect("validate");
        assert!(report.issues.is_empty(), "{profile:?}: {:?}", &report.issues[..report.issues.len().min(5)]);

        let opts = render_preview::RenderOptions { width: 160, height: 120, ..Default::default() };
        let out = render_preview::render_file(&sct, &opts).expect("render");
        let lit = out.frame.depth.iter().filter(|d| d.is_finite()).count();
        assert!(lit > 160 * 120 / 50, "{profile:?}: preview nearly blank ({lit} pixels drawn)");
    }
}

/// glTF files whose meshes are placed by several nodes become groups over instances; in
/// every profile the group leaves must carry their children's areas within the profile's
/// bound. Regression: the default profile's coarse area codes (within its documented bound)
/// made deep validation report every group leaf of these files.
#[test]
fn instanced_gltf_scenes_validate_deep_in_every_profile() {
    let dir = tempfile::tempdir().expect("tempdir");
    let models = repo().join("../shared/models/gltf");
    for name in ["VertexColorTest/glTF-Binary/VertexColorTest.glb", "SimpleInstancing/glTF-Binary/SimpleInstancing.glb"] {
        let samples = dir.path().join("m.samples");
        voxelize(&models.join(name), &samples);
        for profile in [Profile::Default, Profile::Canopy, Profile::Raw] {
            let sct = dir.path().join(format!("m-{}.sct", profile.name()));
            build(&samples, &sct, profile);
            let report = validate_file(&sct, &ValidateOptions { deep: true, limits: Limits::default(), ..Default::default() }).expect("validate");
            assert!(report.issues.is_empty(), "{name} {profile:?}: {:?}", &report.issues[..report.issues.len().min(3)]);
        }
    }
}
