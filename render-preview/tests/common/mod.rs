//! Helpers shared by the render-preview integration tests: the shared models and the mesh
//! reference of a render.
#![allow(dead_code)] // each test binary uses a different part

use std::path::{Path, PathBuf};

use render_preview::reference::{render_reference, WorldMesh};
use render_preview::{Frame, RenderOptions, View};

/// A file of the shared model library (`../shared/models` beside the repository), or `None`
/// (and a note on stderr) when it is not there: such tests skip.
pub fn shared(rel: &str) -> Option<PathBuf> {
    let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/models").join(rel);
    p.exists().then_some(p).or_else(|| {
        eprintln!("skipping: {rel} not found");
        None
    })
}

/// The mesh reference of render `out` made with `opts` (same camera, shading, background).
pub fn reference_for(mesh: &WorldMesh, out: &render_preview::Rendered, opts: &RenderOptions) -> Frame {
    render_reference(mesh, &View::new(&out.camera, out.near).unwrap(), opts.shading, opts.background)
}
