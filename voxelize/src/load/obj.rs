//! OBJ files: the text decoded (UTF-8 with or without a BOM, UTF-16 with one), backslash
//! line continuations joined, its statements parsed on every thread ([`obj_text`]; a large
//! UTF-8 file piece by piece as it is read, [`load_streamed`]), MTL
//! libraries read with tobj (texture paths with backslashes, spaces or options found), and
//! n-gons triangulated by CDT ([`crate::polygon`]).

use std::borrow::Cow;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

use rayon::prelude::*;

use super::obj_text::{self, ChunkedParse};
use super::{decode_image, finish_primitive, read_file, LoadOptions};
use crate::error::LoadError;
use crate::mesh::*;

pub(super) fn load(path: &Path, bytes: &[u8], opts: &LoadOptions) -> Result<LoadedScene, LoadError> {
    let text = decode_text(path, bytes)?;
    let mut parse = ChunkedParse::default();
    parse.add(&join_continuations(&text), obj_text::CHUNK_BYTES);
    drop(text);
    load_parsed(path, parse, opts)
}

/// Whether the OBJ file starting with `head` can be read piece by piece ([`load_streamed`]):
/// UTF-8 can (a line end is never part of another character), UTF-16 is decoded whole.
pub(super) fn streams(head: &[u8]) -> bool {
    !(head.starts_with(&[0xFE, 0xFF]) || head.starts_with(&[0xFF, 0xFE]))
}

/// [`load`] of a UTF-8 OBJ file read piece by piece, so that the text held at once is one
/// piece, not the file (a scan's OBJ text is 40–45 bytes per triangle): `buf` holds the
/// file's first bytes, `more` appends the next ones to it and says whether any are left,
/// and `hasher`, if any, is given every byte. Each piece ends at a line end that does not
/// continue its line (a backslash before it), so decoding, joining continuations and
/// parsing piece by piece give exactly what they give on the whole text, errors included
/// (an invalid byte is reported at its offset in the file).
pub(super) fn load_streamed(
    path: &Path,
    mut buf: Vec<u8>,
    more: &mut dyn FnMut(&mut Vec<u8>) -> Result<bool, LoadError>,
    mut hasher: Option<&mut blake3::Hasher>,
    opts: &LoadOptions,
) -> Result<LoadedScene, LoadError> {
    let mut done = false;
    while buf.len() < 3 && !done {
        done = !more(&mut buf)?;
    }
    let bom = buf.starts_with(&[0xEF, 0xBB, 0xBF]);
    // File offset of `buf[0]`; the bytes of `buf` from `fresh` on are not hashed yet.
    let (mut at, mut fresh) = (0u64, 0usize);
    let mut start = if bom { 3 } else { 0 };
    // No line end before this index ends a piece (each byte is searched once: a file of
    // continued lines must not be searched again for every piece read).
    let mut searched = start;
    let mut parse = ChunkedParse::default();
    loop {
        let cut = if done { Some(buf.len()) } else { logical_line_end(&buf, searched) };
        let Some(cut) = cut else {
            // Not one whole line yet.
            searched = buf.len();
            done = !more(&mut buf)?;
            continue;
        };
        let text = std::str::from_utf8(&buf[start..cut]).map_err(|e| utf8_error(path, at + (start + e.valid_up_to()) as u64, bom))?;
        let new = &buf[fresh..];
        rayon::join(
            || {
                if let Some(h) = hasher.as_deref_mut() {
                    h.update(new);
                }
            },
            || {
                // After a malformed line nothing changes the error reported, but the rest is
                // still checked for invalid bytes, which are reported first (as when decoded
                // whole).
                if !parse.failed() {
                    parse.add(&join_continuations(text), obj_text::CHUNK_BYTES);
                }
            },
        );
        if done {
            break;
        }
        buf.drain(..cut);
        at += cut as u64;
        fresh = buf.len();
        start = 0;
        searched = 0;
        done = !more(&mut buf)?;
    }
    drop(buf);
    load_parsed(path, parse, opts)
}

/// Just past the last line end in `b`, at or after `from`, that does not continue its line: a
/// `\n` (or `\r\n`) with no backslash before it (see [`join_continuations`]).
fn logical_line_end(b: &[u8], from: usize) -> Option<usize> {
    let from = from.min(b.len());
    let mut end = b.len();
    while let Some(i) = b[from..end].iter().rposition(|&c| c == b'\n') {
        let i = from + i;
        let line = &b[..i];
        let line = line.strip_suffix(b"\r").unwrap_or(line);
        if !line.ends_with(b"\\") {
            return Some(i + 1);
        }
        end = i;
    }
    None
}

/// The scene of a parsed OBJ file.
fn load_parsed(path: &Path, parse: ChunkedParse, opts: &LoadOptions) -> Result<LoadedScene, LoadError> {
    let dir = path.parent().map(Path::to_path_buf).unwrap_or_default();
    let mut scene = LoadedScene::default();
    let mut mats: Vec<tobj::Material> = Vec::new();
    // Material name -> directory of the MTL that defined it (texture paths are relative to
    // the MTL, not the OBJ).
    let mut mtl_dirs = HashMap::<String, PathBuf>::new();
    let parsed = parse.finish(|mtl| {
        let loaded = load_mtl(path, &dir, mtl, opts, &mut scene);
        let names = loaded.iter().map(|(m, _)| m.name.clone()).collect();
        for (m, mdir) in loaded {
            mtl_dirs.insert(m.name.clone(), mdir);
            mats.push(m);
        }
        names
    })
    .map_err(|e| LoadError::parse(path, "OBJ", format!("line {}", e.line), e.message))?;
    add_materials(path, &dir, &mats, &mtl_dirs, opts, &mut scene)?;
    let mut first = vec![u32::MAX; parsed.positions.len()];
    for model in &parsed.models {
        let what = format!("object {:?}", model.name);
        let mut prim = model_primitive(path, &what, &parsed, model, opts, &mut first, &mut scene.stats)?;
        prim.material = model.material.filter(|&m| m < scene.materials.len());
        finish_primitive(path, &what, &mut prim, &mut scene.stats)?;
        scene.meshes.push(Mesh { name: model.name.clone(), primitives: vec![prim] });
        scene.instances.push(Instance { mesh: scene.meshes.len() - 1, transform: IDENTITY });
    }
    if scene.meshes.iter().all(|m| m.triangle_count() == 0) && scene.stats.triangles_read == 0 {
        return Err(LoadError::parse(path, "OBJ", "file", "no faces"));
    }
    // The parsed statements (about 45 bytes a triangle: 200 MB for the dense 4.4 M-triangle
    // bunny) are freed on a pool thread: unmapping them took the loading thread about 30 ms
    // while the pool had nothing to do.
    crate::par::drop_later((parsed, first));
    Ok(scene)
}

/// The materials of the library named by `mtllib` line text `mtl`, each with the directory
/// its texture paths are relative to; none (and a warning) when it cannot be found, read or
/// parsed: the model then loads with the default colour.
fn load_mtl(path: &Path, dir: &Path, mtl: &str, opts: &LoadOptions, scene: &mut LoadedScene) -> Vec<(tobj::Material, PathBuf)> {
    let Some(found) = resolve(dir, mtl) else {
        scene.missing.extend(candidates(dir, mtl));
        scene.warnings.push(format!("{}: material library {mtl} not found; using default colour", path.display()));
        return Vec::new();
    };
    let text = match read_file(&found, opts.max_file_bytes).and_then(|b| decode_text(&found, &b).map(|t| join_continuations(&t).into_owned())) {
        Ok(t) => t,
        Err(e) => {
            scene.warnings.push(format!("{e}; using default colour"));
            return Vec::new();
        }
    };
    if let Some((line, key)) = short_colour(&text) {
        scene.warnings.push(format!("{}: line {line}: {key} needs three numbers; using default colour", found.display()));
        return Vec::new();
    }
    match tobj::load_mtl_buf(&mut std::io::Cursor::new(text.as_bytes())) {
        Ok((mats, _)) => {
            scene.files.push(found.clone());
            let mdir = found.parent().map(Path::to_path_buf).unwrap_or_default();
            mats.into_iter().map(|m| (m, mdir.clone())).collect()
        }
        Err(e) => {
            scene.warnings.push(format!("{}: {e}; using default colour", found.display()));
            Vec::new()
        }
    }
}

/// The first colour statement (`Ka`, `Kd`, `Ks`, `Ke`) of MTL text with fewer than three
/// words after it, as its line (1-based) and keyword: tobj unwraps the three numbers it
/// takes and panics on fewer.
fn short_colour(text: &str) -> Option<(usize, &str)> {
    text.lines().enumerate().find_map(|(i, l)| {
        let mut words = l.split_whitespace();
        let key = words.next().filter(|k| matches!(*k, "Ka" | "Kd" | "Ks" | "Ke"))?;
        (words.count() < 3).then_some((i + 1, key))
    })
}

/// Appends the MTL materials to the scene, with their textures.
fn add_materials(path: &Path, dir: &Path, mats: &[tobj::Material], mtl_dirs: &HashMap<String, PathBuf>, opts: &LoadOptions, scene: &mut LoadedScene) -> Result<(), LoadError> {
    let mut image_cache: HashMap<PathBuf, Option<usize>> = HashMap::new();
    for m in mats {
        let mdir = mtl_dirs.get(&m.name).cloned().unwrap_or_else(|| dir.to_path_buf());
        let kd = m.diffuse.unwrap_or([0.8, 0.8, 0.8]);
        let d = m.dissolve.unwrap_or(1.0);
        let mut mat = Material {
            name: m.name.clone(),
            base_color: [srgb_to_linear(kd[0]), srgb_to_linear(kd[1]), srgb_to_linear(kd[2]), d.clamp(0.0, 1.0)],
            ..Default::default()
        };
        if !mat.base_color.iter().all(|c| c.is_finite()) {
            return Err(LoadError::NonFinite { path: path.to_path_buf(), element: format!("Kd/d of material {}", m.name), index: 0 });
        }
        let mut tex = |name: &Option<String>, what: &str, scene: &mut LoadedScene| -> Option<TextureRef> {
            let name = name.as_ref()?;
            if !opts.load_textures {
                return None;
            }
            let Some(file) = resolve(&mdir, name) else {
                scene.missing.extend(candidates(&mdir, name));
                scene.warnings.push(format!("{}: {what} texture {name:?} of material {} not found; using the material colour", path.display(), m.name));
                return None;
            };
            let idx = *image_cache.entry(file.clone()).or_insert_with(|| {
                match read_file(&file, opts.max_file_bytes).map_err(|e| e.to_string()).and_then(|b| decode_image(&b, file.display().to_string())) {
                    Ok(img) => {
                        scene.images.push(img);
                        scene.files.push(file.clone());
                        Some(scene.images.len() - 1)
                    }
                    Err(e) => {
                        scene.warnings.push(format!("{}: cannot decode texture: {e}; using the material colour", file.display()));
                        None
                    }
                }
            });
            idx.map(|image| TextureRef { image, tex_coord: 0, transform: UV_IDENTITY, wrap_s: Wrap::Repeat, wrap_t: Wrap::Repeat })
        };
        mat.texture = tex(&m.diffuse_texture, "map_Kd", scene);
        mat.alpha_texture = tex(&m.dissolve_texture, "map_d", scene);
        if d < 1.0 || mat.alpha_texture.is_some() {
            mat.alpha_mode = AlphaMode::Blend;
        }
        scene.materials.push(mat);
    }
    Ok(())
}

/// The vertices and triangles of one model. OBJ indexes positions, texture coordinates and
/// normals separately; a vertex is one distinct (position, uv, normal) triple, numbered in
/// the order the faces first use it. `first` (one entry per position of the file, all
/// `u32::MAX`) is scratch space, left as it was found.
fn model_primitive(
    path: &Path,
    what: &str,
    parsed: &obj_text::Parsed,
    model: &obj_text::ObjModel,
    opts: &LoadOptions,
    first: &mut [u32],
    stats: &mut LoadStats,
) -> Result<Primitive, LoadError> {
    let positions_only = model.texcoords == 0 && model.normals == 0;
    if positions_only && opts.max_face_corners >= 3 && parsed.arities[model.faces.clone()].par_iter().all(|&a| a == 3) {
        if let Some(prim) = positions_only_primitive(path, what, parsed, model)? {
            return Ok(prim);
        }
    }
    walked_primitive(path, what, parsed, model, opts, first, stats)
}

/// The index error of `corners[c]` of a model, for an index past what the model read.
fn index_error(path: &Path, what: &str, element: &str, c: usize, value: u32, count: usize) -> LoadError {
    LoadError::IndexOutOfRange { path: path.to_path_buf(), element: format!("{element} of {what}"), index: c as u64, value: value.into(), count: count as u64 }
}

/// [`walked_primitive`] of a model of triangles whose corners name positions only (scans):
/// one vertex per position used, numbered in the order of first use, found on every thread
/// (the walk takes a tenth of a second per million triangles on one). The vertex of a
/// position is its rank among the corners that use a position first
/// ([`super::vertex_order::first_use_order`]).
///
/// `None` for a model of 2^32 − 1 corners or more, which the walk numbers.
fn positions_only_primitive(path: &Path, what: &str, parsed: &obj_text::Parsed, model: &obj_text::ObjModel) -> Result<Option<Primitive>, LoadError> {
    let corners = &parsed.corners[model.corners.clone()];
    let has_vc = model.colors > 0 && !corners.is_empty();
    // The first corner in file order whose index is out of range, as the walk reports it.
    let bad = |k: &[u32; 3]| k[0] as usize >= model.positions || (has_vc && k[0] as usize >= model.colors);
    if let Some(c) = super::first_where(corners, bad) {
        let p = corners[c][0];
        return Err(if p as usize >= model.positions {
            index_error(path, what, "face vertex index", c, p, model.positions)
        } else {
            index_error(path, what, "vertex colour of face vertex index", c, p, model.colors)
        });
    }
    let Some((order, vertex)) = super::vertex_order::first_use_order(model.positions, corners.len(), |c| corners[c][0]) else { return Ok(None) };
    let at = |k: &[u32; 3]| vertex[k[0] as usize].load(std::sync::atomic::Ordering::Relaxed);
    Ok(Some(Primitive {
        positions: order.par_iter().map(|&p| parsed.positions[p as usize]).collect(),
        colors: has_vc.then(|| order.par_iter().map(|&p| vertex_color(parsed.colors[p as usize])).collect()),
        triangles: corners.par_chunks_exact(3).map(|t| [at(&t[0]), at(&t[1]), at(&t[2])]).collect(),
        ..Primitive::default()
    }))
}

/// An OBJ vertex colour (`v x y z r g b`, sRGB) as a linear, opaque vertex colour.
fn vertex_color(c: [f32; 3]) -> [f32; 4] {
    [srgb_to_linear(c[0]), srgb_to_linear(c[1]), srgb_to_linear(c[2]), 1.0]
}

/// A model's primitive, walking its corners in file order: each (position, uv, normal)
/// triple a vertex, numbered in the order of first use; n-gons triangulated.
fn walked_primitive(
    path: &Path,
    what: &str,
    parsed: &obj_text::Parsed,
    model: &obj_text::ObjModel,
    opts: &LoadOptions,
    first: &mut [u32],
    stats: &mut LoadStats,
) -> Result<Primitive, LoadError> {
    let corners = &parsed.corners[model.corners.clone()];
    let has_uv = model.texcoords > 0 && !corners.is_empty();
    let has_n = model.normals > 0 && !corners.is_empty();
    let has_vc = model.colors > 0 && !corners.is_empty();
    let mut prim = Primitive::default();
    let mut uvs = Vec::new();
    let mut normals = Vec::new();
    let mut colors = Vec::new();
    // The vertices of one position form a chain (first per position, next per vertex)
    // holding their (uv, normal) pair: positions rarely have more than a few, and a hash
    // map of triples costs more than the parse.
    let mut next: Vec<u32> = Vec::new();
    let mut tn: Vec<(u32, u32)> = Vec::new();
    let mut vertex_position: Vec<u32> = Vec::new();
    // A corner without a uv (normal) takes the previous corner's; the model's first one the
    // file's first.
    let (mut prev_t, mut prev_n) = (0u32, 0u32);
    let oor = |element: &str, c: usize, value: u32, count: usize| index_error(path, what, element, c, value, count);
    let mut corner_vertex = |c: usize, prim: &mut Primitive| -> Result<u32, LoadError> {
        let [p, t, n] = corners[c];
        let t = if !has_uv { u32::MAX } else if t == obj_text::MISSING { prev_t } else { t };
        let n = if !has_n { u32::MAX } else if n == obj_text::MISSING { prev_n } else { n };
        if p as usize >= model.positions {
            return Err(oor("face vertex index", c, p, model.positions));
        }
        if has_uv && t as usize >= model.texcoords {
            return Err(oor("face texcoord index", c, t, model.texcoords));
        }
        if has_n && n as usize >= model.normals {
            return Err(oor("face normal index", c, n, model.normals));
        }
        if has_vc && p as usize >= model.colors {
            return Err(oor("vertex colour of face vertex index", c, p, model.colors));
        }
        (prev_t, prev_n) = (t, n);
        let pi = p as usize;
        let mut v = first[pi];
        // Positions only (scans): one vertex per position, no chain to walk.
        if v != u32::MAX && !has_uv && !has_n {
            return Ok(v);
        }
        while v != u32::MAX {
            if tn[v as usize] == (t, n) {
                return Ok(v);
            }
            v = next[v as usize];
        }
        let v = prim.positions.len() as u32;
        next.push(first[pi]);
        first[pi] = v;
        tn.push((t, n));
        vertex_position.push(p);
        prim.positions.push(parsed.positions[pi]);
        if has_uv {
            let uv = parsed.texcoords[t as usize];
            // OBJ's v axis points up; images are stored top row first.
            uvs.push([uv[0], 1.0 - uv[1]]);
        }
        if has_n {
            normals.push(parsed.normals[n as usize]);
        }
        if has_vc {
            colors.push(vertex_color(parsed.colors[pi]));
        }
        Ok(v)
    };
    let mut start = 0usize;
    let mut verts = Vec::new();
    let mut result = Ok(());
    for (fi, &ar) in parsed.arities[model.faces.clone()].iter().enumerate() {
        let ar = ar as usize;
        // Checked before the face's corners are gathered or triangulated.
        if ar > opts.max_face_corners {
            result = Err(LoadError::Limit {
                path: path.to_path_buf(),
                what: format!("{what}: face {fi} has {ar} corners, more than the limit of {}", opts.max_face_corners),
            });
            break;
        }
        let end = start + ar;
        verts.clear();
        for c in start..end {
            match corner_vertex(c, &mut prim) {
                Ok(v) => verts.push(v),
                Err(e) => {
                    result = Err(e);
                    break;
                }
            }
        }
        if result.is_err() {
            break;
        }
        if ar == 3 {
            prim.triangles.push([verts[0], verts[1], verts[2]]);
        } else {
            let corners: Vec<[f32; 3]> = verts.iter().map(|&v| prim.positions[v as usize]).collect();
            for t in crate::polygon::triangulate(&corners) {
                prim.triangles.push(t.map(|k| verts[k as usize]));
            }
            stats.polygons_triangulated += 1;
        }
        start = end;
    }
    for &p in &vertex_position {
        first[p as usize] = u32::MAX;
    }
    result?;
    if has_uv {
        prim.uvs.push(uvs);
    }
    if has_n {
        prim.normals = Some(normals);
    }
    if has_vc {
        prim.colors = Some(colors);
    }
    Ok(prim)
}

pub(super) fn file_stem(path: &Path) -> String {
    path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default()
}

/// UTF-8 (with or without BOM) or UTF-16 with a BOM; anything else is refused with the
/// byte offset of the first invalid sequence. UTF-8 is borrowed, not copied.
pub(super) fn decode_text<'a>(path: &Path, bytes: &'a [u8]) -> Result<Cow<'a, str>, LoadError> {
    let enc = |message: String| LoadError::Encoding { path: path.to_path_buf(), message };
    if let Some(rest) = bytes.strip_prefix(&[0xEF, 0xBB, 0xBF]) {
        return std::str::from_utf8(rest).map(Cow::Borrowed).map_err(|e| utf8_error(path, e.valid_up_to() as u64 + 3, true));
    }
    let utf16 = |rest: &[u8], be: bool| -> Result<Cow<'a, str>, LoadError> {
        if rest.len() % 2 != 0 {
            return Err(enc("UTF-16 file with an odd number of bytes".into()));
        }
        let units = rest.chunks_exact(2).map(|c| if be { u16::from_be_bytes([c[0], c[1]]) } else { u16::from_le_bytes([c[0], c[1]]) });
        char::decode_utf16(units)
            .collect::<Result<String, _>>()
            .map(Cow::Owned)
            .map_err(|e| enc(format!("invalid UTF-16: unpaired surrogate {:#x}", e.unpaired_surrogate())))
    };
    if let Some(rest) = bytes.strip_prefix(&[0xFE, 0xFF]) {
        return utf16(rest, true);
    }
    if let Some(rest) = bytes.strip_prefix(&[0xFF, 0xFE]) {
        return utf16(rest, false);
    }
    std::str::from_utf8(bytes).map(Cow::Borrowed).map_err(|e| utf8_error(path, e.valid_up_to() as u64, false))
}

/// The error for an invalid UTF-8 sequence at byte `at` of the file (`bom`: the file starts
/// with a UTF-8 byte-order mark, so it declared its encoding).
fn utf8_error(path: &Path, at: u64, bom: bool) -> LoadError {
    let message = if bom {
        format!("invalid UTF-8 at byte {at}")
    } else {
        format!("invalid UTF-8 at byte {at} (only UTF-8 and UTF-16 with a byte-order mark are supported)")
    };
    LoadError::Encoding { path: path.to_path_buf(), message }
}

/// Joins lines ending in a backslash with the next line (an OBJ/MTL continuation). A line
/// ends at `\n` or `\r\n`, as tobj reads it (so that the search below finds every
/// continuation the copy joins).
pub(super) fn join_continuations(text: &str) -> Cow<'_, str> {
    // Most files have none (a substring search is far cheaper than a copy line by line; a
    // backslash elsewhere, as in a Windows path, is no reason to copy).
    if !text.contains("\\\n") && !text.contains("\\\r\n") && !text.ends_with('\\') && !text.ends_with("\\\r") {
        return Cow::Borrowed(text);
    }
    let mut out = String::with_capacity(text.len());
    for line in text.split_inclusive('\n') {
        let trimmed = line.strip_suffix('\n').unwrap_or(line);
        let trimmed = trimmed.strip_suffix('\r').unwrap_or(trimmed);
        if let Some(body) = trimmed.strip_suffix('\\') {
            out.push_str(body);
            out.push(' ');
        } else {
            out.push_str(line);
        }
    }
    Cow::Owned(out)
}

/// Finds a file referenced from an OBJ/MTL: as written, with backslashes as separators,
/// the last token (dropping `-o u v`-style options), and finally the bare file name in
/// `dir` (exporters often write absolute paths from the author's machine).
pub(super) fn resolve(dir: &Path, name: &str) -> Option<PathBuf> {
    candidates(dir, name).into_iter().find(|full| full.is_file())
}

/// The paths [`resolve`] tries for `name`, in order, without repeats.
pub(super) fn candidates(dir: &Path, name: &str) -> Vec<PathBuf> {
    let name = name.trim();
    if name.is_empty() {
        return Vec::new();
    }
    let slashed = name.replace('\\', "/");
    let mut cands: Vec<String> = vec![name.to_string(), slashed.clone()];
    if let Some(last) = slashed.split_whitespace().last() {
        cands.push(last.to_string());
    }
    if let Some(base) = slashed.rsplit('/').next() {
        cands.push(base.to_string());
    }
    let mut out: Vec<PathBuf> = Vec::new();
    for c in cands {
        let p = Path::new(&c);
        let full = if p.is_absolute() { p.to_path_buf() } else { dir.join(p) };
        if !out.contains(&full) {
            out.push(full);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The models as tobj reads them (the loader before [`obj_text`]), each made into the
    /// primitive [`load`] makes: per model its name, material and primitive.
    fn tobj_models(path: &Path, text: &str) -> Result<Vec<(String, Option<usize>, Primitive)>, String> {
        let dir = path.parent().map(Path::to_path_buf).unwrap_or_default();
        let load_opts = tobj::LoadOptions { single_index: false, triangulate: false, ignore_points: true, ignore_lines: true };
        // tobj refuses `usemtl` and `mtllib` without a name (Rhino writes them); the reader
        // skips them.
        let text: String = join_continuations(text).split_inclusive('\n').map(|l| if matches!(l.trim(), "usemtl" | "mtllib") { "\n" } else { l }).collect();
        let (models, _) = tobj::load_obj_buf(&mut std::io::Cursor::new(text.as_bytes()), &load_opts, |mtl: &Path| {
            let found = resolve(&dir, &mtl.to_string_lossy()).ok_or(tobj::LoadError::OpenFileFailed)?;
            let bytes = std::fs::read(found).map_err(|_| tobj::LoadError::ReadError)?;
            let text = String::from_utf8_lossy(&bytes).into_owned();
            tobj::load_mtl_buf(&mut std::io::Cursor::new(join_continuations(&text).as_bytes()))
        })
        .map_err(|e| e.to_string())?;
        let mut out = Vec::new();
        for m in &models {
            let mesh = &m.mesh;
            let tri = |v: &[f32]| v.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect::<Vec<_>>();
            let has = |idx: &Vec<u32>| !idx.is_empty() && idx.len() == mesh.indices.len();
            let corners: Vec<[u32; 3]> = (0..mesh.indices.len())
                .map(|c| {
                    let t = if has(&mesh.texcoord_indices) { mesh.texcoord_indices[c] } else { obj_text::MISSING };
                    let n = if has(&mesh.normal_indices) { mesh.normal_indices[c] } else { obj_text::MISSING };
                    [mesh.indices[c], t, n]
                })
                .collect();
            let arities = if mesh.face_arities.is_empty() { vec![3; mesh.indices.len() / 3] } else { mesh.face_arities.clone() };
            let texcoords: Vec<[f32; 2]> = mesh.texcoords.chunks_exact(2).map(|c| [c[0], c[1]]).collect();
            let parsed = obj_text::Parsed {
                positions: tri(&mesh.positions),
                colors: tri(&mesh.vertex_color),
                texcoords,
                normals: tri(&mesh.normals),
                corners,
                arities,
                models: Vec::new(),
            };
            let model = obj_text::ObjModel {
                name: m.name.clone(),
                material: mesh.material_id,
                faces: 0..parsed.arities.len(),
                corners: 0..parsed.corners.len(),
                positions: parsed.positions.len(),
                texcoords: if has(&mesh.texcoord_indices) { parsed.texcoords.len() } else { 0 },
                normals: if has(&mesh.normal_indices) { parsed.normals.len() } else { 0 },
                colors: parsed.colors.len(),
            };
            let mut first = vec![u32::MAX; parsed.positions.len()];
            let prim = model_primitive(path, "reference", &parsed, &model, &LoadOptions::default(), &mut first, &mut LoadStats::default()).map_err(|e| e.to_string())?;
            out.push((m.name.clone(), mesh.material_id, prim));
        }
        Ok(out)
    }

    /// [`load`]'s meshes against tobj's for the file at `path` (its text `text`).
    fn assert_same_as_tobj(path: &Path, text: &str) {
        let want = tobj_models(path, text).unwrap_or_else(|e| panic!("{}: tobj refuses it: {e}", path.display()));
        let scene = load(path, text.as_bytes(), &LoadOptions { load_textures: false, ..Default::default() }).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(scene.meshes.len(), want.len(), "{}: models", path.display());
        for (k, (mesh, (name, material, prim))) in scene.meshes.iter().zip(&want).enumerate() {
            let got = &mesh.primitives[0];
            let at = format!("{} model {k} ({name:?})", path.display());
            assert_eq!(&mesh.name, name, "{at}: name");
            assert_eq!(got.material, material.filter(|&m| m < scene.materials.len()), "{at}: material");
            // Degenerate triangles are dropped after the fact (finish_primitive): compare
            // the vertices, and the triangles the reference keeps.
            assert_eq!(got.positions, prim.positions, "{at}: positions");
            assert_eq!(got.uvs, prim.uvs, "{at}: uvs");
            assert_eq!(got.normals, prim.normals, "{at}: normals");
            assert_eq!(got.colors, prim.colors, "{at}: colours");
            let kept: Vec<[u32; 3]> = prim.triangles.iter().copied().filter(|t| got.triangles.contains(t)).collect();
            assert_eq!(got.triangles, kept, "{at}: triangles");
        }
    }

    #[test]
    fn models_match_tobj_on_statements_of_every_kind() {
        let dir = tempfile::tempdir().expect("tempdir");
        std::fs::write(dir.path().join("m.mtl"), "newmtl red\nKd 1 0 0\nnewmtl green\nKd 0 1 0\n").expect("write");
        let cases = [
            // Relative indices, uvs on some corners only (the others take the previous one's).
            "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nf -4 -3/-2 -2\nf 1/1 3/3 4\nvn 0 0 1\nf 1//1 2 3\n",
            // Objects, groups and materials ending models; a quad and a concave hexagon.
            "mtllib m.mtl\nv 0 0 0\nv 2 0 0\nv 2 2 0\nv 0 2 0\nv 1 1 0\nv 1 0.5 0\no a\nusemtl red\nf 1 2 3 4\nusemtl green\nf 1 2 6 3 4 5\ng b\nf 1 2 3\nusemtl red\nusemtl red\nf 2 3 4\n",
            // Vertex colours.
            "v 0 0 0 1 0 0\nv 1 0 0 0 1 0\nv 0 1 0 0 0 1\nv 0 0 1 0.5 0.5 0.5\nf 1 2 3\nf 3 4 1\n",
            // A weight.
            "v 0 0 0\nv 2 0 0 2\nv 0 3 0 3\nf 1 2 3\n",
            // Rhino's nameless usemtl and mtllib, a Windows path, a continued face.
            "mtllib\nmtllib C:\\models\\m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nusemtl red\nf 1 2 3\nusemtl \nf 2 \\\n4 3\nusemtl green\nf 1 2 4\n",
            // The same position with several uv/normal pairs.
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 1\nvn 0 0 1\nvn 0 0 -1\nf 1/1/1 2/1/1 3/1/1\nf 1/2/2 3/2/2 2/2/2\nf 1/1/2 2/2/1 3/1/1\n",
        ];
        for (k, text) in cases.iter().enumerate() {
            let path = dir.path().join(format!("case{k}.obj"));
            std::fs::write(&path, text).expect("write");
            assert_same_as_tobj(&path, text);
        }
        // A face on a vertex without a colour, in a file with colours: both refuse it.
        let text = "v 0 0 0 1 0 0\nv 2 0 0\nv 0 1 0 0 0 1\nf 1 2 3\n";
        let path = dir.path().join("mixed.obj");
        assert!(tobj_models(&path, text).is_err());
        let e = load(&path, text.as_bytes(), &LoadOptions::default()).expect_err("refused");
        assert!(matches!(&e, LoadError::IndexOutOfRange { element, .. } if element.contains("colour")), "{e}");
    }

    /// Every OBJ of the shared models (when present) loads as tobj loaded it.
    #[test]
    fn models_match_tobj_on_the_shared_models() {
        let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/models");
        let mut stack = vec![root];
        let mut seen = 0;
        while let Some(d) = stack.pop() {
            let Ok(rd) = std::fs::read_dir(&d) else { continue };
            for e in rd.flatten() {
                let p = e.path();
                if p.is_dir() {
                    stack.push(p);
                } else if p.extension().is_some_and(|x| x.eq_ignore_ascii_case("obj")) {
                    let bytes = std::fs::read(&p).expect("read");
                    let Ok(text) = decode_text(&p, &bytes) else { continue };
                    assert_same_as_tobj(&p, &text);
                    seen += 1;
                }
            }
        }
        eprintln!("{seen} shared OBJ files compared");
    }

    /// `load_streamed` fed `bytes` `piece` bytes at a time, and the hash it computed.
    fn streamed(path: &Path, bytes: &[u8], piece: usize) -> (Result<LoadedScene, LoadError>, String) {
        let first = bytes[..piece.min(bytes.len())].to_vec();
        let mut at = first.len();
        let mut more = |b: &mut Vec<u8>| {
            let end = (at + piece).min(bytes.len());
            b.extend_from_slice(&bytes[at..end]);
            at = end;
            Ok(at < bytes.len())
        };
        let mut h = blake3::Hasher::new();
        let r = load_streamed(path, first, &mut more, Some(&mut h), &LoadOptions { load_textures: false, ..Default::default() });
        (r, h.finalize().to_hex().to_string())
    }

    /// Random OBJ texts (continuations, CRLF, a BOM, non-ASCII comments, materials and
    /// objects, now and then a malformed line or an invalid byte) read piece by piece give
    /// the scene or the error of the whole text, for pieces from one byte up, and the hash
    /// of every byte.
    #[test]
    fn pieces_load_as_the_whole_text_loads() {
        let mut rng = sct_format::rng::SplitMix64(11);
        let mut next = move |n: u64| rng.next_u64() % n;
        let path = Path::new("random.obj");
        let opts = LoadOptions { load_textures: false, ..Default::default() };
        let (mut ok, mut failed) = (0, 0);
        for case in 0..300 {
            let mut t: Vec<u8> = Vec::new();
            if case % 7 == 0 {
                t.extend_from_slice(&[0xEF, 0xBB, 0xBF]);
            }
            let crlf = case % 3 == 0;
            let mut lines: Vec<Vec<u8>> = (0..4).map(|i| format!("v {i} {} 0.{i}", i * i).into_bytes()).collect();
            lines.push(b"vn 0 1 0".to_vec());
            for _ in 0..next(30) + 5 {
                let line: &str = match next(16) {
                    0 => "vt 0.5 0.25",
                    1 => "vn 0 0 1",
                    2 => "f 1 2 3",
                    3 => "f -1 -2 -3",
                    4 => "f 1//1 2//1 3//1",
                    5 => "f 1 2 3 4",
                    6 => "o part",
                    7 => "g group",
                    8 => "usemtl missing",
                    9 => "# commentaire: déjà vu",
                    10 => "",
                    11 => "f 1 2 \\\n3",
                    12 => "v 0.25 0.5 \\\r\n0.75",
                    13 => "   ",
                    _ => "v 1 2 3",
                };
                lines.push(line.as_bytes().to_vec());
            }
            match next(10) {
                0 => lines.push(b"f 0 1 2".to_vec()),
                1 => {
                    let k = 5 + next(lines.len() as u64 - 5) as usize;
                    lines[k].push(0xFF);
                }
                _ => {}
            }
            for (i, l) in lines.iter().enumerate() {
                t.extend_from_slice(l);
                if i + 1 < lines.len() || case % 2 == 0 {
                    t.extend_from_slice(if crlf { b"\r\n" } else { b"\n" });
                }
            }
            let whole = load(path, &t, &opts);
            for piece in [1, 2, 5, 17, 64, 1 << 20] {
                let (r, hash) = streamed(path, &t, piece);
                match (&whole, &r) {
                    (Ok(a), Ok(b)) => {
                        assert_eq!(format!("{a:?}"), format!("{b:?}"), "case {case}, pieces of {piece}");
                        assert_eq!(hash, blake3::hash(&t).to_hex().to_string(), "case {case}");
                    }
                    (Err(a), Err(b)) => assert_eq!(a.to_string(), b.to_string(), "case {case}, pieces of {piece}"),
                    _ => panic!("case {case}, pieces of {piece}: {:?} whole, {:?} in pieces", whole.as_ref().err(), r.as_ref().err()),
                }
            }
            if whole.is_ok() {
                ok += 1;
            } else {
                failed += 1;
            }
        }
        assert!(ok > 150 && failed > 30, "{ok} loaded, {failed} refused");
    }

    /// A file whose lines all continue is searched for a line end once, not again for every
    /// piece read (300,000 one-byte pieces here: searching the buffer again each time would
    /// take minutes), and loads as it does whole.
    #[test]
    fn continued_lines_are_searched_once() {
        let mut t = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 \\\n".to_vec();
        while t.len() < 300_000 {
            t.extend_from_slice(b"\\\n");
        }
        t.extend_from_slice(b"3\n");
        let whole = load(Path::new("c.obj"), &t, &LoadOptions { load_textures: false, ..Default::default() });
        let (pieces, _) = streamed(Path::new("c.obj"), &t, 1);
        assert_eq!(format!("{:?}", whole.map(|s| s.meshes)), format!("{:?}", pieces.map(|s| s.meshes)));
    }

    /// A piece ends after the last line end that does not continue its line.
    #[test]
    fn pieces_end_after_a_line_that_is_not_continued() {
        assert_eq!(logical_line_end(b"a\nb", 0), Some(2));
        assert_eq!(logical_line_end(b"a\\\nb\n", 0), Some(5));
        assert_eq!(logical_line_end(b"a\nb\\\nc", 0), Some(2));
        assert_eq!(logical_line_end(b"a\\\nb", 0), None);
        assert_eq!(logical_line_end(b"a\\\r\n", 0), None);
        assert_eq!(logical_line_end(b"a\r\n", 0), Some(3));
        assert_eq!(logical_line_end(b"\n", 0), Some(1));
        assert_eq!(logical_line_end(b"\\\n", 0), None);
        assert_eq!(logical_line_end(b"abc", 0), None);
        // Only line ends at or after `from`; the backslash before one may lie before it.
        assert_eq!(logical_line_end(b"a\nb\nc", 3), Some(4));
        assert_eq!(logical_line_end(b"a\nb\nc", 4), None);
        assert_eq!(logical_line_end(b"a\\\nb", 2), None);
        assert_eq!(logical_line_end(b"a\\\r\nb\n", 3), Some(6));
    }

    /// The search for continuations finds every line the copy joins: the borrowed text is
    /// what the line-by-line copy gives (texts of backslashes, CRs, LFs and letters).
    #[test]
    fn continuations_are_found_wherever_they_are_joined() {
        fn copy(text: &str) -> String {
            let mut out = String::new();
            for line in text.split_inclusive('\n') {
                let trimmed = line.strip_suffix('\n').unwrap_or(line);
                let trimmed = trimmed.strip_suffix('\r').unwrap_or(trimmed);
                match trimmed.strip_suffix('\\') {
                    Some(body) => {
                        out.push_str(body);
                        out.push(' ');
                    }
                    None => out.push_str(line),
                }
            }
            out
        }
        let mut rng = sct_format::rng::SplitMix64(3);
        for _ in 0..20_000 {
            let x = rng.next_u64();
            let text: String = (0..(x % 9)).map(|i| ['a', '\\', '\r', '\n'][(x >> (8 + 2 * i) & 3) as usize]).collect();
            assert_eq!(join_continuations(&text), copy(&text), "{text:?}");
        }
    }

    /// Models of triangles on positions only are numbered on every thread exactly as the
    /// walk numbers them (positions in the order of first use, unused ones left out,
    /// colours with them), and refused at the same corner with the same error.
    #[test]
    fn positions_only_models_are_numbered_as_the_walk_numbers_them() {
        let mut rng = sct_format::rng::SplitMix64(13);
        let mut next = move |n: u64| rng.next_u64() % n.max(1);
        let path = Path::new("m.obj");
        let (mut ok, mut refused) = (0, 0);
        for case in 0..400 {
            let positions = next(300) as usize;
            let colors = if case % 3 == 0 { positions - next(3).min(positions as u64) as usize } else { 0 };
            let tris = next(1 << 17 >> (case % 8)) as usize;
            let mut corners: Vec<[u32; 3]> =
                (0..3 * tris).map(|_| [next(positions as u64 + (case % 5 == 0) as u64) as u32, obj_text::MISSING, obj_text::MISSING]).collect();
            if case % 11 == 0 && !corners.is_empty() {
                let c = next(corners.len() as u64) as usize;
                corners[c][0] = u32::MAX - 1;
            }
            let parsed = obj_text::Parsed {
                positions: (0..positions).map(|i| [i as f32, 0.5 * i as f32, -(i as f32)]).collect(),
                colors: (0..colors).map(|i| [(i % 7) as f32 / 7.0, 0.25, 1.0]).collect(),
                arities: vec![3; tris],
                corners,
                ..Default::default()
            };
            let model = obj_text::ObjModel {
                name: "m".into(),
                material: None,
                faces: 0..tris,
                corners: 0..3 * tris,
                positions,
                texcoords: 0,
                normals: 0,
                colors,
            };
            let mut first = vec![u32::MAX; positions];
            let walked = walked_primitive(path, "object", &parsed, &model, &LoadOptions::default(), &mut first, &mut LoadStats::default());
            let fast = positions_only_primitive(path, "object", &parsed, &model);
            match (walked, fast) {
                (Ok(a), Ok(Some(b))) => {
                    assert_eq!(format!("{a:?}"), format!("{b:?}"), "case {case}");
                    ok += 1;
                }
                (Err(a), Err(b)) => {
                    assert_eq!(a.to_string(), b.to_string(), "case {case}");
                    refused += 1;
                }
                (a, b) => panic!("case {case}: {:?} walked, {:?} on every thread", a.err(), b.err()),
            }
        }
        assert!(ok > 200 && refused > 40, "{ok} numbered, {refused} refused");
    }
}
