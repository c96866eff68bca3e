//! Mesh loaders: OBJ (our own parser; MTL by tobj), glTF/GLB (gltf), PLY (ply-rs-bw). Entry point [`load`].
//! Every file is read through [`sct_format::fsio`]: regular files only (a FIFO would block
//! `open` forever, a device such as `/dev/zero` reports length 0 and never ends), opened
//! without blocking, read up to the size they had when opened and at most the limit.

mod gltf_load;
mod obj;
mod obj_text;
mod ply;
pub mod sniff;

use std::path::{Path, PathBuf};

use crate::error::LoadError;
use crate::mesh::{is_degenerate, Image, LoadStats, LoadedScene, Primitive};

/// Options for [`load`].
#[derive(Clone, Debug)]
pub struct LoadOptions {
    /// Bind this image as the base-colour texture of the primitives that have UVs but no
    /// texture of their own (for OBJ files shipped without an MTL, such as spot); a texture
    /// the model brings is kept.
    pub texture_override: Option<PathBuf>,
    /// Decode textures (false: colours come from factors and vertex colours only).
    pub load_textures: bool,
    /// Largest input file accepted, in bytes (a guard against reading a device or a
    /// runaway file into memory).
    pub max_file_bytes: u64,
    /// Let glTF buffer and image URIs name files outside the model's directory (absolute
    /// paths, `file:` URIs, `..`, symlinks leading out). Off by default: a downloaded model
    /// should not make the tool read arbitrary files of the machine it runs on.
    pub allow_outside_uris: bool,
    /// Most corners one polygon (OBJ or PLY face) may have; a larger face is refused
    /// ([`LoadError::Limit`]). Triangulation time grows with the corner count (see
    /// [`crate::polygon`]), so one hostile face must not stall the load.
    pub max_face_corners: usize,
}

/// Default of [`LoadOptions::max_face_corners`]: 1,048,576 corners.
pub const DEFAULT_MAX_FACE_CORNERS: usize = 1 << 20;

impl Default for LoadOptions {
    fn default() -> Self {
        LoadOptions {
            texture_override: None,
            load_textures: true,
            max_file_bytes: 8 << 30,
            allow_outside_uris: false,
            max_face_corners: DEFAULT_MAX_FACE_CORNERS,
        }
    }
}

/// Loads a mesh file, choosing the loader by extension (.obj, .gltf, .glb, .ply; the glTF
/// binary magic and the `ply` magic are also recognised).
pub fn load(path: &Path, opts: &LoadOptions) -> Result<LoadedScene, LoadError> {
    let bytes = read_file(path, opts.max_file_bytes)?;
    load_bytes(path, &bytes, opts)
}

/// [`load`], and the BLAKE3 of the bytes it read (lowercase hex, the value of
/// [`sct_format::atomic::hash_file`] on the same bytes): the hash describes exactly what
/// was loaded, and is computed on every thread while the file is parsed rather than in a
/// pass of its own.
pub fn load_and_hash(path: &Path, opts: &LoadOptions) -> Result<(LoadedScene, String), LoadError> {
    let bytes = read_file(path, opts.max_file_bytes)?;
    let (hash, scene) = rayon::join(|| sct_format::atomic::hash_bytes(&bytes), || load_bytes(path, &bytes, opts));
    Ok((scene?, hash))
}

/// [`load`] of the bytes read from `path`.
fn load_bytes(path: &Path, bytes: &[u8], opts: &LoadOptions) -> Result<LoadedScene, LoadError> {
    let ext = path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase);
    let sniffed = sniff::sniff(&bytes[..bytes.len().min(sniff::SNIFF_BYTES)], bytes.len() as u64);
    // The content wins over a misleading extension only where it is unambiguous (a GLB
    // named .gltf); a text file is read by its extension.
    let kind = match (ext.as_deref(), sniffed) {
        (_, sniff::FileKind::GltfBinary) => Kind::Gltf,
        (Some("obj"), _) => Kind::Obj,
        (Some("gltf") | Some("glb"), _) => Kind::Gltf,
        (Some("ply"), _) => Kind::Ply,
        (_, sniff::FileKind::GltfJson) => Kind::Gltf,
        (_, sniff::FileKind::Ply) => Kind::Ply,
        (_, sniff::FileKind::Obj) => Kind::Obj,
        (_, found) => {
            return Err(LoadError::UnsupportedFormat {
                path: path.to_path_buf(),
                found: found.describe(),
                hint: found.unsupported_mesh_hint().unwrap_or(match found {
                    sniff::FileKind::SctScene => "it is an output of sct-build-tree, not a mesh; view it with sct-render-preview or inspect it with sct-inspect",
                    sniff::FileKind::SctSamples => "it is an output of sct-voxelize, not a mesh; build a tree from it with sct-build-tree",
                    _ => "the supported meshes are OBJ (.obj), glTF (.gltf, .glb) and PLY (.ply)",
                }),
            })
        }
    };
    // Third-party parsers are not all panic-free on hostile input; a panic becomes a typed
    // error naming the file instead of aborting the tool.
    let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| match kind {
        Kind::Obj => obj::load(path, bytes, opts),
        Kind::Gltf => gltf_load::load(path, bytes, opts),
        Kind::Ply => ply::load(path, bytes, opts),
    }));
    let mut scene = match result {
        Ok(r) => r?,
        Err(panic) => {
            let message = panic
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| panic.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "unknown panic".into());
            return Err(LoadError::ParserPanic { path: path.to_path_buf(), format: kind.name(), message });
        }
    };
    if let Some(tex) = &opts.texture_override {
        bind_texture_override(&mut scene, tex, opts)?;
    }
    // Finite but huge coordinates (±3·10³⁸) make infinite areas downstream: refused here,
    // naming the mesh, rather than written as samples no reader can use.
    if let Some((m, mesh)) = crate::mesh::max_world_coordinate(&scene) {
        if !(m <= crate::mesh::MAX_WORLD_COORDINATE) {
            return Err(LoadError::Limit {
                path: path.to_path_buf(),
                what: format!(
                    "mesh {mesh:?} reaches a world coordinate of {m:e}, beyond the limit of ±{:e} (areas and edge products would overflow f32)",
                    crate::mesh::MAX_WORLD_COORDINATE
                ),
            });
        }
    }
    scene.files.insert(0, path.to_path_buf());
    Ok(scene)
}

#[derive(Clone, Copy)]
enum Kind {
    Obj,
    Gltf,
    Ply,
}

impl Kind {
    fn name(self) -> &'static str {
        match self {
            Kind::Obj => "OBJ",
            Kind::Gltf => "glTF",
            Kind::Ply => "PLY",
        }
    }
}

pub(crate) fn read_file(path: &Path, max: u64) -> Result<Vec<u8>, LoadError> {
    sct_format::fsio::read_regular(path, max).map_err(|e| load_error(path, e))
}

/// The loader's error for a read of `path` refused or failed by [`sct_format::fsio`].
fn load_error(path: &Path, e: sct_format::Error) -> LoadError {
    let path = path.to_path_buf();
    if let Some(kind) = sct_format::fsio::not_regular_kind(&e) {
        return LoadError::NotRegularFile { path, kind };
    }
    match e {
        sct_format::Error::LimitExceeded { value, limit, .. } => LoadError::Limit { path, what: format!("file is {value} bytes, more than the limit of {limit}") },
        sct_format::Error::Io { source, .. } => LoadError::Io { path, source },
        // Reading a file fails only in the two ways above; anything else is reported as is.
        other => LoadError::Io { path, source: std::io::Error::other(other.to_string()) },
    }
}

/// Decodes an image file to 8-bit RGBA (any format the `image` crate was built with).
pub(crate) fn decode_image(bytes: &[u8], source: String) -> Result<Image, String> {
    let img = image::load_from_memory(bytes).map_err(|e| e.to_string())?;
    Ok(from_dynamic(img, source))
}

pub(crate) fn from_dynamic(img: image::DynamicImage, source: String) -> Image {
    let rgba = img.into_rgba8();
    let (width, height) = rgba.dimensions();
    let rgba = rgba.pixels().map(|p| p.0).collect();
    Image { width, height, rgba, source }
}

fn bind_texture_override(scene: &mut LoadedScene, tex: &Path, opts: &LoadOptions) -> Result<(), LoadError> {
    let bytes = read_file(tex, opts.max_file_bytes)?;
    let img = decode_image(&bytes, tex.display().to_string()).map_err(|m| {
        LoadError::parse(tex, "image", "file", m)
    })?;
    scene.images.push(img);
    scene.files.push(tex.to_path_buf());
    let image = scene.images.len() - 1;
    let tref = crate::mesh::TextureRef {
        image,
        tex_coord: 0,
        transform: crate::mesh::UV_IDENTITY,
        wrap_s: crate::mesh::Wrap::Repeat,
        wrap_t: crate::mesh::Wrap::Repeat,
    };
    // Every primitive with UVs and no texture of its own gets a textured material: its own
    // with the texture bound, or a white one (the texture alone decides the colour, as the
    // model's author intended). A texture the model brings is never replaced.
    let mut rebound = std::collections::HashMap::new();
    let (mut bound, mut kept) = (0usize, 0usize);
    for mesh in &mut scene.meshes {
        for p in &mut mesh.primitives {
            if p.uvs.is_empty() {
                continue;
            }
            if p.material.and_then(|k| scene.materials.get(k)).is_some_and(|m| m.texture.is_some()) {
                kept += 1;
                continue;
            }
            bound += 1;
            let key = p.material;
            let new = *rebound.entry(key).or_insert_with(|| {
                let mut m = key
                    .and_then(|k| scene.materials.get(k).cloned())
                    .unwrap_or_else(|| crate::mesh::Material { base_color: [1.0; 4], ..Default::default() });
                m.texture = Some(tref.clone());
                scene.materials.push(m);
                scene.materials.len() - 1
            });
            p.material = Some(new);
        }
    }
    if bound == 0 {
        let why = if kept > 0 { "every primitive with texture coordinates has a texture of its own" } else { "no primitive has texture coordinates" };
        scene.warnings.push(format!("--texture {} was not used: {why}", tex.display()));
    }
    Ok(())
}

/// Checks a primitive's data (finite values; indices were checked by the loader) and drops
/// zero-area triangles, counting them.
pub(crate) fn finish_primitive(
    path: &Path,
    what: &str,
    p: &mut Primitive,
    stats: &mut LoadStats,
) -> Result<(), LoadError> {
    use rayon::prelude::*;
    // Checked in parallel; `position_first` finds the first fault, the one a serial scan
    // would report.
    if let Some(i) = p.positions.par_iter().position_first(|v| !v.iter().all(|c| c.is_finite())) {
        return Err(LoadError::NonFinite { path: path.to_path_buf(), element: format!("position of {what}"), index: i as u64 });
    }
    if let Some(n) = &mut p.normals {
        // Bad normals are not worth refusing a file for: zero or non-finite ones are
        // replaced by computed normals at sampling time (zeroed here).
        n.par_iter_mut().filter(|v| !v.iter().all(|c| c.is_finite())).for_each(|v| *v = [0.0; 3]);
    }
    for (k, set) in p.uvs.iter_mut().enumerate() {
        if let Some(i) = set.par_iter().position_first(|v| !v.iter().all(|c| c.is_finite())) {
            return Err(LoadError::NonFinite { path: path.to_path_buf(), element: format!("TEXCOORD_{k} of {what}"), index: i as u64 });
        }
    }
    if let Some(c) = &p.colors {
        if let Some(i) = c.par_iter().position_first(|v| !v.iter().all(|c| c.is_finite())) {
            return Err(LoadError::NonFinite { path: path.to_path_buf(), element: format!("colour of {what}"), index: i as u64 });
        }
    }
    let n = p.positions.len() as u64;
    if let Some(i) = p.triangles.par_iter().position_first(|t| t.iter().any(|&v| u64::from(v) >= n)) {
        let value = p.triangles[i].iter().map(|&v| u64::from(v)).find(|&v| v >= n).unwrap_or(n);
        return Err(LoadError::IndexOutOfRange { path: path.to_path_buf(), element: format!("triangle of {what}"), index: i as u64, value, count: n });
    }
    stats.triangles_read += p.triangles.len() as u64;
    let pos = &p.positions;
    let degenerate = |t: &[u32; 3]| is_degenerate(pos[t[0] as usize], pos[t[1] as usize], pos[t[2] as usize]);
    // Most meshes have none: looked for in parallel, removed (in order) only when found.
    if p.triangles.par_iter().any(degenerate) {
        let before = p.triangles.len();
        p.triangles.retain(|t| !degenerate(t));
        stats.degenerate_triangles += (before - p.triangles.len()) as u64;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A regular file reads; a FIFO is refused at once (not blocked on), named in the error;
    /// a directory and a device are refused by type; a read stops at the limit. The reading
    /// is `sct_format::fsio`'s; what is checked here is the loader's errors for it.
    #[cfg(unix)]
    #[test]
    fn only_regular_files_are_read_and_reads_are_bounded() {
        let dir = tempfile::tempdir().expect("tempdir");
        let f = dir.path().join("a.bin");
        std::fs::write(&f, b"0123456789").expect("write");
        assert_eq!(read_file(&f, 10).expect("read"), b"0123456789");
        assert!(matches!(read_file(&f, 9), Err(LoadError::Limit { .. })));
        assert!(matches!(read_file(&dir.path().join("none"), 9), Err(LoadError::Io { .. })));

        let fifo = dir.path().join("pipe.obj");
        let made = std::process::Command::new("mkfifo").arg(&fifo).status().expect("mkfifo");
        assert!(made.success());
        let e = read_file(&fifo, 1 << 20).expect_err("a FIFO is refused");
        assert!(matches!(e, LoadError::NotRegularFile { kind: "a FIFO", .. }), "{e}");
        assert!(e.to_string().contains("pipe.obj"), "{e}");

        // Through a symlink: the type is that of the target.
        let link = dir.path().join("link.obj");
        std::os::unix::fs::symlink(&fifo, &link).expect("symlink");
        assert!(matches!(read_file(&link, 1 << 20), Err(LoadError::NotRegularFile { .. })));
        assert!(matches!(read_file(dir.path(), 1 << 20), Err(LoadError::NotRegularFile { kind: "a directory", .. })));
        // A device reports length 0 and never ends: refused by type, not read.
        assert!(matches!(read_file(Path::new("/dev/zero"), 1 << 20), Err(LoadError::NotRegularFile { kind: "a character device", .. })));
    }
}
