//! OBJ/MTL via tobj, with the preprocessing tobj lacks: UTF-16/UTF-8-BOM decoding,
//! backslash line continuations, texture paths with backslashes/spaces/options, and CDT
//! triangulation of n-gons (tobj's own triangulation is a fan).

use std::borrow::Cow;
use std::cell::RefCell;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

use super::{decode_image, finish_primitive, read_file, LoadOptions};
use crate::error::LoadError;
use crate::mesh::*;

pub(super) fn load(path: &Path, bytes: &[u8], opts: &LoadOptions) -> Result<LoadedScene, LoadError> {
    let text = decode_text(path, bytes)?;
    let text = join_continuations(&text);
    let dir = path.parent().map(Path::to_path_buf).unwrap_or_default();
    let warnings = RefCell::new(Vec::<String>::new());
    let files = RefCell::new(Vec::<PathBuf>::new());
    let missing = RefCell::new(Vec::<PathBuf>::new());
    // Material name -> directory of the MTL that defined it (texture paths are relative to
    // the MTL, not the OBJ).
    let mtl_dirs = RefCell::new(HashMap::<String, PathBuf>::new());
    let load_opts = tobj::LoadOptions { single_index: false, triangulate: false, ignore_points: true, ignore_lines: true };
    let mut reader = std::io::Cursor::new(text.as_bytes());
    let result = tobj::load_obj_buf(&mut reader, &load_opts, |mtl: &Path| {
        let Some(found) = resolve(&dir, &mtl.to_string_lossy()) else {
            missing.borrow_mut().extend(candidates(&dir, &mtl.to_string_lossy()));
            warnings.borrow_mut().push(format!("{}: material library {} not found; using default colour", path.display(), mtl.display()));
            return Err(tobj::LoadError::OpenFileFailed);
        };
        let bytes = match read_file(&found, opts.max_file_bytes) {
            Ok(b) => b,
            Err(e) => {
                warnings.borrow_mut().push(format!("{e}; using default colour"));
                return Err(tobj::LoadError::OpenFileFailed);
            }
        };
        let text = match decode_text(&found, &bytes) {
            Ok(t) => join_continuations(&t).into_owned(),
            Err(e) => {
                warnings.borrow_mut().push(format!("{e}; using default colour"));
                return Err(tobj::LoadError::ReadError);
            }
        };
        let r = tobj::load_mtl_buf(&mut std::io::Cursor::new(text.as_bytes()));
        match &r {
            Ok((mats, _)) => {
                let mdir = found.parent().map(Path::to_path_buf).unwrap_or_default();
                for m in mats {
                    mtl_dirs.borrow_mut().insert(m.name.clone(), mdir.clone());
                }
                files.borrow_mut().push(found.clone());
            }
            Err(e) => warnings.borrow_mut().push(format!("{}: {e}; using default colour", found.display())),
        }
        r
    });
    let (models, mats) = result.map_err(|e| LoadError::parse(path, "OBJ", "face or vertex line", e.to_string()))?;
    let mut scene = LoadedScene { warnings: warnings.into_inner(), files: files.into_inner(), missing: missing.into_inner(), ..Default::default() };
    let mtl_dirs = mtl_dirs.into_inner();
    let mats = mats.unwrap_or_default();
    let mut image_cache: HashMap<PathBuf, Option<usize>> = HashMap::new();
    for m in &mats {
        let mdir = mtl_dirs.get(&m.name).cloned().unwrap_or_else(|| dir.clone());
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
        mat.texture = tex(&m.diffuse_texture, "map_Kd", &mut scene);
        mat.alpha_texture = tex(&m.dissolve_texture, "map_d", &mut scene);
        if d < 1.0 || mat.alpha_texture.is_some() {
            mat.alpha_mode = AlphaMode::Blend;
        }
        scene.materials.push(mat);
    }
    for (mi, model) in models.iter().enumerate() {
        let mesh = &model.mesh;
        let what = format!("object {:?}", model.name);
        let mut prim = Primitive { material: mesh.material_id.filter(|&m| m < scene.materials.len()), ..Default::default() };
        let npos = mesh.positions.len() / 3;
        let nuv = mesh.texcoords.len() / 2;
        let nn = mesh.normals.len() / 3;
        let has_vc = mesh.vertex_color.len() == mesh.positions.len() && !mesh.vertex_color.is_empty();
        let has_uv = !mesh.texcoord_indices.is_empty() && mesh.texcoord_indices.len() == mesh.indices.len();
        let has_n = !mesh.normal_indices.is_empty() && mesh.normal_indices.len() == mesh.indices.len();
        let mut uvs = Vec::new();
        let mut normals = Vec::new();
        let mut colors = Vec::new();
        // Corner (position, uv, normal) triple -> vertex: OBJ indexes attributes separately.
        // The vertices of one position form a chain (first per position, next per vertex)
        // holding their (uv, normal) pair: positions rarely have more than a few, and a
        // hash map of triples cost more than the OBJ parse.
        let mut first = vec![u32::MAX; npos];
        let mut next: Vec<u32> = Vec::new();
        let mut tn: Vec<(u32, u32)> = Vec::new();
        let mut corner_vertex = |c: usize, prim: &mut Primitive| -> Result<u32, LoadError> {
            let p = mesh.indices[c];
            let t = if has_uv { mesh.texcoord_indices[c] } else { u32::MAX };
            let n = if has_n { mesh.normal_indices[c] } else { u32::MAX };
            let oor = |what_idx: &str, value: u32, count: usize| LoadError::IndexOutOfRange {
                path: path.to_path_buf(),
                element: format!("{what_idx} of {what}"),
                index: c as u64,
                value: value.into(),
                count: count as u64,
            };
            if p as usize >= npos {
                return Err(oor("face vertex index", p, npos));
            }
            if has_uv && t as usize >= nuv {
                return Err(oor("face texcoord index", t, nuv));
            }
            if has_n && n as usize >= nn {
                return Err(oor("face normal index", n, nn));
            }
            let pi = p as usize;
            let mut v = first[pi];
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
            prim.positions.push([mesh.positions[3 * pi], mesh.positions[3 * pi + 1], mesh.positions[3 * pi + 2]]);
            if has_uv {
                let ti = t as usize;
                // OBJ's v axis points up; images are stored top row first.
                uvs.push([mesh.texcoords[2 * ti], 1.0 - mesh.texcoords[2 * ti + 1]]);
            }
            if has_n {
                let ni = n as usize;
                normals.push([mesh.normals[3 * ni], mesh.normals[3 * ni + 1], mesh.normals[3 * ni + 2]]);
            }
            if has_vc {
                colors.push([
                    srgb_to_linear(mesh.vertex_color[3 * pi]),
                    srgb_to_linear(mesh.vertex_color[3 * pi + 1]),
                    srgb_to_linear(mesh.vertex_color[3 * pi + 2]),
                    1.0,
                ]);
            }
            Ok(v)
        };
        let arities: Vec<u32> = if mesh.face_arities.is_empty() {
            vec![3; mesh.indices.len() / 3]
        } else {
            mesh.face_arities.clone()
        };
        let mut start = 0usize;
        for (fi, &ar) in arities.iter().enumerate() {
            let ar = ar as usize;
            // Checked before the face's corners are gathered or triangulated.
            if ar > opts.max_face_corners {
                return Err(LoadError::Limit {
                    path: path.to_path_buf(),
                    what: format!("{what}: face {fi} has {ar} corners, more than the limit of {}", opts.max_face_corners),
                });
            }
            let end = start + ar;
            if end > mesh.indices.len() {
                return Err(LoadError::parse(path, "OBJ", what.clone(), "face arity runs past the index list"));
            }
            let verts: Vec<u32> = (start..end).map(|c| corner_vertex(c, &mut prim)).collect::<Result<_, _>>()?;
            if ar == 3 {
                prim.triangles.push([verts[0], verts[1], verts[2]]);
            } else if ar > 3 {
                let corners: Vec<[f32; 3]> = verts.iter().map(|&v| prim.positions[v as usize]).collect();
                for t in crate::polygon::triangulate(&corners) {
                    prim.triangles.push(t.map(|k| verts[k as usize]));
                }
                scene.stats.polygons_triangulated += 1;
            }
            start = end;
        }
        if has_uv {
            prim.uvs.push(uvs);
        }
        if has_n {
            prim.normals = Some(normals);
        }
        if has_vc {
            prim.colors = Some(colors);
        }
        finish_primitive(path, &what, &mut prim, &mut scene.stats)?;
        let name = if model.name.is_empty() { format!("{}#{mi}", file_stem(path)) } else { model.name.clone() };
        scene.meshes.push(Mesh { name, primitives: vec![prim] });
        scene.instances.push(Instance { mesh: scene.meshes.len() - 1, transform: IDENTITY });
    }
    if scene.meshes.iter().all(|m| m.triangle_count() == 0) && scene.stats.triangles_read == 0 {
        return Err(LoadError::parse(path, "OBJ", "file", "no faces"));
    }
    Ok(scene)
}

pub(super) fn file_stem(path: &Path) -> String {
    path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default()
}

/// UTF-8 (with or without BOM) or UTF-16 with a BOM; anything else is refused with the
/// byte offset of the first invalid sequence.
pub(super) fn decode_text(path: &Path, bytes: &[u8]) -> Result<String, LoadError> {
    let enc = |message: String| LoadError::Encoding { path: path.to_path_buf(), message };
    if let Some(rest) = bytes.strip_prefix(&[0xEF, 0xBB, 0xBF]) {
        return String::from_utf8(rest.to_vec()).map_err(|e| enc(format!("invalid UTF-8 at byte {}", e.utf8_error().valid_up_to() + 3)));
    }
    let utf16 = |rest: &[u8], be: bool| -> Result<String, LoadError> {
        if rest.len() % 2 != 0 {
            return Err(enc("UTF-16 file with an odd number of bytes".into()));
        }
        let units = rest.chunks_exact(2).map(|c| if be { u16::from_be_bytes([c[0], c[1]]) } else { u16::from_le_bytes([c[0], c[1]]) });
        char::decode_utf16(units).collect::<Result<String, _>>().map_err(|e| enc(format!("invalid UTF-16: unpaired surrogate {:#x}", e.unpaired_surrogate())))
    };
    if let Some(rest) = bytes.strip_prefix(&[0xFE, 0xFF]) {
        return utf16(rest, true);
    }
    if let Some(rest) = bytes.strip_prefix(&[0xFF, 0xFE]) {
        return utf16(rest, false);
    }
    String::from_utf8(bytes.to_vec()).map_err(|e| {
        enc(format!("invalid UTF-8 at byte {} (only UTF-8 and UTF-16 with a byte-order mark are supported)", e.utf8_error().valid_up_to()))
    })
}

/// Joins lines ending in a backslash with the next line (an OBJ/MTL continuation).
/// Also drops `usemtl`/`mtllib` lines without a name (Rhino writes them; tobj refuses them).
pub(super) fn join_continuations(text: &str) -> Cow<'_, str> {
    // Most files have neither (a substring search is far cheaper than a copy line by line).
    if !text.contains('\\') && !text.contains("usemtl") && !text.contains("mtllib") {
        return Cow::Borrowed(text);
    }
    let mut out = String::with_capacity(text.len());
    for line in text.split_inclusive('\n') {
        let trimmed = line.trim_end_matches(['\n', '\r']);
        if let Some(body) = trimmed.strip_suffix('\\') {
            out.push_str(body);
            out.push(' ');
        } else if matches!(trimmed.trim(), "usemtl" | "mtllib") {
            out.push('\n');
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
