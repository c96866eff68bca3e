//! Mesh loaders: OBJ (our own parser; MTL by tobj), glTF/GLB (gltf), PLY (ply-rs-bw). Entry point [`load`].
//! Every file is read through [`sct_format::fsio`]: regular files only (a FIFO would block
//! `open` forever, a device such as `/dev/zero` reports length 0 and never ends), opened
//! without blocking, read up to the size they had when opened and at most the limit.

mod gltf_load;
mod obj;
mod obj_text;
mod ply;
pub mod sniff;
mod vertex_order;

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
    read_and_load(path, opts, false, obj_piece_bytes()).map(|(scene, _)| scene)
}

/// [`load`], and the BLAKE3 of the bytes it read (lowercase hex, the value of
/// [`sct_format::atomic::hash_file`] on the same bytes): the hash describes exactly what
/// was loaded, and is computed on every thread while the file is parsed rather than in a
/// pass of its own.
pub fn load_and_hash(path: &Path, opts: &LoadOptions) -> Result<(LoadedScene, String), LoadError> {
    read_and_load(path, opts, true, obj_piece_bytes()).map(|(scene, hash)| (scene, hash.unwrap_or_default()))
}

/// Bytes of an OBJ file read and parsed at a time ([`obj::load_streamed`]): a few chunks
/// for every thread, and little beside the parsed statements (the dense 4.4 M-triangle
/// bunny's text is 189 MB).
fn obj_piece_bytes() -> usize {
    (32 << 20).max(rayon::current_num_threads().saturating_mul(4 << 20))
}

/// [`load`], with the BLAKE3 of the bytes read when `hash`. A UTF-8 OBJ file larger than
/// `piece` bytes is read, hashed and parsed piece by piece; other files are read whole, then
/// hashed on every thread while they are parsed.
fn read_and_load(path: &Path, opts: &LoadOptions, hash: bool, piece: usize) -> Result<(LoadedScene, Option<String>), LoadError> {
    let mut file = PieceReader::open(path, opts.max_file_bytes)?;
    let mut bytes = Vec::new();
    // The head decides: a large UTF-8 OBJ is read piece by piece, anything else whole into
    // one buffer of its size (not a piece's buffer grown, which would copy the piece).
    let more = file.read_more(&mut bytes, sniff::SNIFF_BYTES)?;
    if more && file.len() > piece as u64 && matches!(kind_of(path, &bytes, file.len())?, Kind::Obj) && obj::streams(&bytes) {
        let mut hasher = hash.then(blake3::Hasher::new);
        let scene = guarded(path, Kind::Obj, || obj::load_streamed(path, bytes, &mut |b| file.read_more(b, piece), hasher.as_mut(), opts))?;
        let scene = finish_scene(path, scene, opts)?;
        return Ok((scene, hasher.map(|h| h.finalize().to_hex().to_string())));
    }
    if more {
        file.read_more(&mut bytes, usize::MAX)?;
    }
    let (hash, scene) = rayon::join(|| hash.then(|| sct_format::atomic::hash_bytes(&bytes)), || load_bytes(path, &bytes, opts));
    Ok((scene?, hash))
}

/// [`sct_format::fsio::PieceReader`] with the loader's errors.
struct PieceReader<'p> {
    path: &'p Path,
    file: sct_format::fsio::PieceReader,
}

impl<'p> PieceReader<'p> {
    fn open(path: &'p Path, max: u64) -> Result<Self, LoadError> {
        let file = sct_format::fsio::PieceReader::open(path, max).map_err(|e| load_error(path, e))?;
        Ok(PieceReader { path, file })
    }

    /// The file's size when it was opened.
    fn len(&self) -> u64 {
        self.file.len()
    }

    /// Appends the next `n` bytes (or all that are left) to `buf`; whether any are left.
    fn read_more(&mut self, buf: &mut Vec<u8>, n: usize) -> Result<bool, LoadError> {
        self.file.read_more(buf, n).map_err(|e| load_error(self.path, e))
    }
}

/// The loader for `path`, whose first bytes are `head` and whose size is `len`.
fn kind_of(path: &Path, head: &[u8], len: u64) -> Result<Kind, LoadError> {
    let ext = path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase);
    let sniffed = sniff::sniff(&head[..head.len().min(sniff::SNIFF_BYTES)], len);
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
    Ok(kind)
}

/// [`load`] of the bytes read from `path`.
fn load_bytes(path: &Path, bytes: &[u8], opts: &LoadOptions) -> Result<LoadedScene, LoadError> {
    let kind = kind_of(path, bytes, bytes.len() as u64)?;
    let scene = guarded(path, kind, || match kind {
        Kind::Obj => obj::load(path, bytes, opts),
        Kind::Gltf => gltf_load::load(path, bytes, opts),
        Kind::Ply => ply::load(path, bytes, opts),
    })?;
    finish_scene(path, scene, opts)
}

/// `load()`, with a panic turned into a typed error naming the file: third-party parsers
/// are not all panic-free on hostile input, and the tool must not abort.
fn guarded(path: &Path, kind: Kind, load: impl FnOnce() -> Result<LoadedScene, LoadError>) -> Result<LoadedScene, LoadError> {
    match std::panic::catch_unwind(std::panic::AssertUnwindSafe(load)) {
        Ok(r) => r,
        Err(panic) => {
            let message = panic
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| panic.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "unknown panic".into());
            Err(LoadError::ParserPanic { path: path.to_path_buf(), format: kind.name(), message })
        }
    }
}

/// What every loader's scene gets: the texture override bound, world coordinates checked,
/// the file recorded.
fn finish_scene(path: &Path, mut scene: LoadedScene, opts: &LoadOptions) -> Result<LoadedScene, LoadError> {
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

/// The index of the first item (in order) for which `f` holds, looked for on every thread: by
/// chunks, then within the first chunk that has one (rayon's `position_first` pays for its
/// bookkeeping on every item: 0.17 s for the dense bunny's 13 M corners, against 0.02 s).
pub(crate) fn first_where<T: Sync>(items: &[T], f: impl Fn(&T) -> bool + Sync) -> Option<usize> {
    use rayon::prelude::*;
    const CHUNK: usize = 1 << 14;
    let k = items.par_chunks(CHUNK).position_first(|ch| ch.iter().any(&f))?;
    let at = k * CHUNK;
    items[at..].iter().position(&f).map(|i| at + i)
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
    // Checked in parallel; `first_where` finds the first fault, the one a serial scan
    // would report.
    if let Some(i) = first_where(&p.positions, |v| !v.iter().all(|c| c.is_finite())) {
        return Err(LoadError::NonFinite { path: path.to_path_buf(), element: format!("position of {what}"), index: i as u64 });
    }
    if let Some(n) = &mut p.normals {
        // Bad normals are not worth refusing a file for: zero or non-finite ones are
        // replaced by computed normals at sampling time (zeroed here).
        n.par_iter_mut().filter(|v| !v.iter().all(|c| c.is_finite())).for_each(|v| *v = [0.0; 3]);
    }
    for (k, set) in p.uvs.iter_mut().enumerate() {
        if let Some(i) = first_where(set, |v| !v.iter().all(|c| c.is_finite())) {
            return Err(LoadError::NonFinite { path: path.to_path_buf(), element: format!("TEXCOORD_{k} of {what}"), index: i as u64 });
        }
    }
    if let Some(c) = &p.colors {
        if let Some(i) = first_where(c, |v| !v.iter().all(|c| c.is_finite())) {
            return Err(LoadError::NonFinite { path: path.to_path_buf(), element: format!("colour of {what}"), index: i as u64 });
        }
    }
    let n = p.positions.len() as u64;
    if let Some(i) = first_where(&p.triangles, |t| t.iter().any(|&v| u64::from(v) >= n)) {
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

        // The same for the mesh itself, which is read in pieces.
        let limited = LoadOptions { max_file_bytes: 9, ..LoadOptions::default() };
        assert!(matches!(load(&f, &limited), Err(LoadError::Limit { .. })));
        assert!(matches!(load(&fifo, &LoadOptions::default()), Err(LoadError::NotRegularFile { kind: "a FIFO", .. })));
        assert!(matches!(load(dir.path(), &LoadOptions::default()), Err(LoadError::NotRegularFile { kind: "a directory", .. })));
        assert!(matches!(load(Path::new("/dev/zero"), &LoadOptions::default()), Err(LoadError::NotRegularFile { .. })));
    }

    /// The first item found on every thread is the first in order, wherever the chunks end.
    #[test]
    fn first_where_finds_the_first_in_order() {
        let mut rng = sct_format::rng::SplitMix64(5);
        for case in 0..200 {
            let x = rng.next_u64();
            let len = (x % 100_000) as usize;
            let every = 1 + (x >> 20) % 50_000;
            let items: Vec<u64> = (0..len as u64).map(|i| i.wrapping_mul(0x9e37_79b9_7f4a_7c15) >> 40).collect();
            let f = |v: &u64| v % every == (case % 3) as u64;
            assert_eq!(first_where(&items, f), items.iter().position(f), "case {case}");
        }
    }

    /// A shared OBJ read in small pieces (hashed and parsed piece by piece) loads to the scene
    /// and hash of the whole-file path, through the public entry points too.
    #[test]
    fn an_obj_read_in_pieces_loads_as_read_whole() {
        let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/models");
        // Materials without their images: the scenes are compared as text.
        let opts = LoadOptions { load_textures: false, ..LoadOptions::default() };
        for rel in ["scans/stanford-bunny/stanford-bunny.obj", "textured-obj/spider/spider.obj", "textured-obj/capsule/capsule.obj"] {
            let path = root.join(rel);
            let bytes = std::fs::read(&path).expect("read");
            let whole = format!("{:?}", load_bytes(&path, &bytes, &opts).expect("loads"));
            let hash = sct_format::atomic::hash_bytes(&bytes);
            for piece in [1 << 12, 100_003] {
                let (scene, h) = read_and_load(&path, &opts, true, piece).expect("loads in pieces");
                assert_eq!(format!("{scene:?}"), whole, "{rel}, pieces of {piece}");
                assert_eq!(h.as_deref(), Some(hash.as_str()), "{rel}");
            }
            let (scene, h) = load_and_hash(&path, &opts).expect("loads");
            assert_eq!((format!("{scene:?}"), h), (whole, hash));
        }
    }
}
