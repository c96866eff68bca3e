//! The default method's tiled frame against the whole-frame steps it replaced, on the
//! splats of shared models under several views and options: the images (and so the PNGs and
//! the `--json` metrics drawn from them) must not change by a byte.

mod common;

use render_preview::{collect_zbuffer_splats, render_file, zbuffer, Frame, RenderOptions, SceneFiles, ViewPreset};

/// Renders of `sct` worth comparing: the default 1280 × 720 front view, one and five
/// subpixels a side, and the iso view at a size of no whole number of tiles with a coarser
/// cut.
fn option_sets() -> Vec<RenderOptions> {
    let d = RenderOptions::default();
    vec![
        d.clone(),
        RenderOptions { supersample: 1, ..d.clone() },
        RenderOptions { supersample: 5, width: 400, height: 300, ..d.clone() },
        RenderOptions { width: 333, height: 197, view: ViewPreset::Iso, background: [200, 10, 90], pixel_error: 1.5, ..d },
    ]
}

fn check(rel: &str) {
    let dir = tempfile::tempdir().unwrap();
    let Some((_, sct)) = common::synth_shared(rel, dir.path()) else { return };
    let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
    for opts in option_sets() {
        let mut files = SceneFiles::open(&sct, &opts.limits).unwrap();
        let (splats, [w, h], s) = collect_zbuffer_splats(&mut files, &opts).unwrap();
        let [r, g, b] = opts.background;
        let bg = [r, g, b, 255];
        let want = zbuffer::zbuffer_frame(Frame::new(w, h, bg), &splats, s as usize, bg);
        assert!(want.covered() > 1000, "{rel}: a frame worth comparing");
        let tiled = zbuffer::zbuffer_tiled(w, h, &splats, s as usize, bg);
        assert!(tiled == want, "{rel}: the tiled frame differs ({}×{} at {s}×{s}, {:?})", opts.width, opts.height, opts.view);
        // The render itself, on one thread and on the default pool.
        let a = render_file(&sct, &opts).unwrap();
        let b = one.install(|| render_file(&sct, &opts)).unwrap();
        assert!(a.frame == want && b.frame == want, "{rel}: the render differs from the whole-frame steps ({:?})", opts.view);
        assert_eq!(a.stats.work.fragments, b.stats.work.fragments);
    }
}

#[test]
fn damaged_helmet_draws_as_before() {
    check("gltf/DamagedHelmet/glTF-Binary/DamagedHelmet.glb");
}

#[test]
fn alpha_blend_mode_test_draws_as_before() {
    check("gltf/AlphaBlendModeTest/glTF-Binary/AlphaBlendModeTest.glb");
}

#[test]
fn dragon_draws_as_before() {
    check("scans/stanford-dragon-100k/dragon.ply");
}
