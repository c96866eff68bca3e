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

/// A shared model made into an SCT file in `dir` by the synthetic builder, leaves at 1/200
/// of its bounding radius: the mesh and the file, or `None` when the model is not there.
pub fn synth_shared(rel: &str, dir: &Path) -> Option<(WorldMesh, PathBuf)> {
    let mesh = WorldMesh::load(&shared(rel)?).unwrap();
    let sct = dir.join("m.sct");
    let (_, r) = mesh.bound().unwrap();
    render_preview::synth::write_mesh_sct(&mesh, (r / 200.0) as f32, &sct, &sct_format::write::WriteOptions::default()).unwrap();
    Some((mesh, sct))
}
