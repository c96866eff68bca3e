//! glTF 2.0 (.gltf with external or data-URI resources, .glb) via the gltf crate.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use gltf::accessor::{DataType, Dimensions};
use gltf::mesh::Mode;
use rayon::prelude::*;

use super::{finish_primitive, from_dynamic, LoadOptions};
use crate::error::LoadError;
use crate::mesh::{self as m, *};

/// Extensions we implement or may safely ignore when a file lists them as required.
const HANDLED: &[&str] = &[
    "KHR_texture_transform",
    "KHR_mesh_quantization",
    "EXT_mesh_gpu_instancing",
    "KHR_materials_unlit",
    "KHR_materials_emissive_strength",
    "KHR_materials_ior",
    "KHR_materials_specular",
    "KHR_materials_transmission",
    "KHR_materials_volume",
    "KHR_materials_clearcoat",
    "KHR_materials_sheen",
    "KHR_lights_punctual",
];

fn unsupported_hint(ext: &str) -> &'static str {
    match ext {
        "KHR_draco_mesh_compression" => "Draco-compressed geometry is not decoded; decompress it first (e.g. `gltf-transform copy in.gltf out.glb` without Draco, or `gltf-pipeline -i in.gltf -o out.gltf`)",
        "EXT_meshopt_compression" | "KHR_meshopt_compression" => "meshoptimizer-compressed buffers are not decoded; decompress them first (e.g. `gltfpack -noq` or `gltf-transform copy`)",
        "KHR_texture_basisu" | "EXT_texture_webp" | "EXT_texture_avif" => "this texture encoding is not decoded; convert textures to PNG or JPEG",
        _ => "not implemented by sct-voxelize",
    }
}

pub(super) fn load(path: &Path, bytes: &[u8], opts: &LoadOptions) -> Result<LoadedScene, LoadError> {
    let perr = |loc: &str, msg: String| LoadError::parse(path, "glTF", loc, msg);
    // The gltf crate subtracts the 12-byte header from a GLB's declared length unchecked
    // (a panic in debug builds, a wrapped length in release ones).
    if let Some(h) = bytes.get(..12).filter(|h| h.starts_with(b"glTF")) {
        let declared = u32::from_le_bytes([h[8], h[9], h[10], h[11]]);
        if declared < 12 {
            return Err(perr("GLB header", format!("declares {declared} bytes, less than the header's own 12")));
        }
    }
    let gltf::Gltf { document, mut blob } =
        gltf::Gltf::from_slice_without_validation(bytes).map_err(|e| perr("document", e.to_string()))?;
    let mut root = document.into_json();
    for ext in &root.extensions_required {
        if !HANDLED.contains(&ext.as_str()) {
            return Err(LoadError::UnsupportedExtension { path: path.to_path_buf(), extension: ext.clone(), hint: unsupported_hint(ext) });
        }
    }
    // The crate's validator rejects required extensions it does not know even when we
    // implement them (EXT_mesh_gpu_instancing); having checked them above, drop them and run
    // its validation for everything else (indices in range, required fields …).
    root.extensions_required.clear();
    // KHR_mesh_quantization allows 8/16-bit (normalized) integer POSITION, NORMAL and
    // TEXCOORD; without it the core float-only layouts are enforced.
    let quantized = root.extensions_used.iter().any(|e| e == "KHR_mesh_quantization");
    // POSITION min/max are required by the validator, but a bound of ±Infinity is not valid
    // JSON and reads as "missing"; we never use them, so fill them in and let the real data
    // check report the non-finite vertex precisely.
    let mut pos_accessors = Vec::new();
    for (m, mesh) in root.meshes.iter().enumerate() {
        for (p, prim) in mesh.primitives.iter().enumerate() {
            for (sem, idx) in &prim.attributes {
                if matches!(sem, gltf::json::validation::Checked::Valid(gltf::Semantic::Positions)) {
                    // The crate's validator looks this accessor up without a bounds check
                    // (gltf-json 1.4 panics on a missing one), so it is checked first.
                    if idx.value() >= root.accessors.len() {
                        let msg = format!("POSITION names accessor {}, but the file has {} accessors", idx.value(), root.accessors.len());
                        return Err(perr(&format!("mesh {m} primitive {p}"), msg));
                    }
                    pos_accessors.push(idx.value());
                }
            }
        }
    }
    for i in pos_accessors {
        if let Some(acc) = root.accessors.get_mut(i) {
            if acc.min.is_none() || acc.max.is_none() {
                acc.min = Some(serde_json::json!([0.0, 0.0, 0.0]));
                acc.max = Some(serde_json::json!([0.0, 0.0, 0.0]));
            }
        }
    }
    let document = gltf::Document::from_json(root).map_err(|e| perr("document validation", e.to_string()))?;
    // A bare file name's parent is the empty path, which does not canonicalize: the model's
    // directory is then the working directory.
    let base = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or_else(|| Path::new("."));
    let mut scene = LoadedScene { declares_sides: true, ..Default::default() };

    // Buffers: a missing one is fatal (the geometry is in it). External files are read here,
    // not by the gltf crate, so that they are regular files inside the model's directory,
    // read with a bound (see `external`).
    let mut buffers: Vec<gltf::buffer::Data> = Vec::new();
    for b in document.buffers() {
        let what = match b.source() {
            gltf::buffer::Source::Bin => "GLB BIN chunk".to_string(),
            gltf::buffer::Source::Uri(u) if u.starts_with("data:") => "data URI".to_string(),
            gltf::buffer::Source::Uri(u) => format!("file {u:?}"),
        };
        let data = match b.source() {
            gltf::buffer::Source::Uri(uri) if !uri.starts_with("data:") => {
                let file = external(path, base, uri, &format!("buffer {}", b.index()), opts)?;
                // A missing or unreadable buffer is the model's fault: a parse error naming
                // the model and the buffer. Refusals by type or size keep their own errors.
                let mut bytes = super::read_file(&file, opts.max_file_bytes).map_err(|e| match e {
                    LoadError::Io { path: f, source } => perr(&format!("buffer {}", b.index()), format!("cannot load {what} ({}): {source}", f.display())),
                    other => other,
                })?;
                // As the gltf crate does: buffers are padded to a multiple of 4 bytes.
                bytes.resize(bytes.len().next_multiple_of(4), 0);
                scene.files.push(file);
                gltf::buffer::Data(bytes)
            }
            _ => gltf::buffer::Data::from_source_and_blob(b.source(), Some(base), &mut blob)
                .map_err(|e| perr(&format!("buffer {}", b.index()), format!("cannot load {what}: {e}")))?,
        };
        if data.len() < b.length() {
            return Err(perr(&format!("buffer {}", b.index()), format!("{what} has {} bytes, the file declares {}", data.len(), b.length())));
        }
        buffers.push(data);
    }
    for v in document.views() {
        let blen = buffers.get(v.buffer().index()).map_or(0, |d| d.len());
        if v.offset().checked_add(v.length()).is_none_or(|end| end > blen) {
            return Err(perr(&format!("bufferView {}", v.index()), format!("range {}+{} exceeds buffer {} ({} bytes)", v.offset(), v.length(), v.buffer().index(), blen)));
        }
    }

    // Images: a missing or undecodable one is a warning (colour falls back to the factor).
    let mut image_map: Vec<Option<usize>> = Vec::new();
    for img in document.images() {
        if !opts.load_textures {
            image_map.push(None);
            continue;
        }
        let name = match img.source() {
            gltf::image::Source::Uri { uri, .. } if !uri.starts_with("data:") => uri.to_string(),
            _ => format!("embedded image {}", img.index()),
        };
        let decoded = match img.source() {
            gltf::image::Source::Uri { uri, .. } if !uri.starts_with("data:") => {
                // Like a missing texture, a refused one (outside the model's directory, not
                // a regular file) is a warning: the base colour factor still applies.
                external(path, base, uri, &format!("image {}", img.index()), opts)
                    .inspect(|file| {
                        if !file.exists() {
                            scene.missing.push(file.clone());
                        }
                    })
                    .and_then(|file| super::read_file(&file, opts.max_file_bytes))
                    .map_err(|e| e.to_string())
                    .and_then(|b| image::load_from_memory(&b).map_err(|e| e.to_string()))
                    .map(gltf_image_data)
            }
            source => gltf::image::Data::from_source(source, Some(base), &buffers).map(Some).map_err(|e| e.to_string()),
        };
        match decoded.and_then(|d| d.ok_or_else(|| "unsupported pixel format".to_string())) {
            Ok(d) => match image_data_to_rgba(d, name.clone()) {
                Some(i) => {
                    scene.images.push(i);
                    image_map.push(Some(scene.images.len() - 1));
                }
                None => {
                    scene.warnings.push(format!("{}: image {name}: unsupported pixel format; using the base colour factor", path.display()));
                    image_map.push(None);
                }
            },
            Err(e) => {
                scene.warnings.push(format!("{}: image {name}: {e}; using the base colour factor", path.display()));
                image_map.push(None);
            }
        }
    }

    for mat in document.materials() {
        let pbr = mat.pbr_metallic_roughness();
        let mut out = Material {
            name: mat.name().unwrap_or("").to_string(),
            base_color: pbr.base_color_factor(),
            texture: None,
            alpha_texture: None,
            alpha_mode: match mat.alpha_mode() {
                gltf::material::AlphaMode::Opaque => AlphaMode::Opaque,
                gltf::material::AlphaMode::Mask => AlphaMode::Mask(mat.alpha_cutoff().unwrap_or(0.5)),
                gltf::material::AlphaMode::Blend => AlphaMode::Blend,
            },
            double_sided: mat.double_sided(),
        };
        if !out.base_color.iter().all(|c| c.is_finite()) {
            return Err(LoadError::NonFinite { path: path.to_path_buf(), element: "baseColorFactor of material".into(), index: mat.index().unwrap_or(0) as u64 });
        }
        if let Some(info) = pbr.base_color_texture() {
            let tex = info.texture();
            let img = image_map.get(tex.source().index()).copied().flatten();
            if let Some(image) = img {
                let mut tex_coord = info.tex_coord();
                let mut transform = UV_IDENTITY;
                if let Some(t) = info.texture_transform() {
                    let [ox, oy] = t.offset();
                    let r = t.rotation();
                    let [sx, sy] = t.scale();
                    let (s, c) = r.sin_cos();
                    // KHR_texture_transform: uv' = T · R · S · uv.
                    transform = [[c * sx, s * sy, ox], [-s * sx, c * sy, oy]];
                    if let Some(tc) = t.tex_coord() {
                        tex_coord = tc;
                    }
                }
                let wrap = |w: gltf::texture::WrappingMode| match w {
                    gltf::texture::WrappingMode::ClampToEdge => Wrap::ClampToEdge,
                    gltf::texture::WrappingMode::MirroredRepeat => Wrap::MirroredRepeat,
                    gltf::texture::WrappingMode::Repeat => Wrap::Repeat,
                };
                let sampler = tex.sampler();
                out.texture = Some(TextureRef { image, tex_coord, transform, wrap_s: wrap(sampler.wrap_s()), wrap_t: wrap(sampler.wrap_t()) });
            }
        }
        scene.materials.push(out);
    }

    // Meshes are converted once, on first use, and shared by every node that uses them.
    let mut mesh_map: HashMap<usize, usize> = HashMap::new();
    let roots: Vec<gltf::Node> = match document.default_scene().or_else(|| document.scenes().next()) {
        Some(s) => s.nodes().collect(),
        None => {
            // No scene: every node that is nobody's child is a root.
            let mut is_child = vec![false; document.nodes().len()];
            for n in document.nodes() {
                for c in n.children() {
                    if let Some(f) = is_child.get_mut(c.index()) {
                        *f = true;
                    }
                }
            }
            document.nodes().filter(|n| !is_child.get(n.index()).copied().unwrap_or(false)).collect()
        }
    };
    let mut stack: Vec<(gltf::Node, Mat4, u32)> = roots.into_iter().rev().map(|n| (n, IDENTITY, 0)).collect();
    // glTF node hierarchies are disjoint strict trees (no node has two parents, nor is a
    // root and a child): each node is placed at most once. A file that shares nodes would
    // have its paths expanded, 2^60 of them for 120 nodes that each use the previous level's
    // two twice (a 3 KB file once took 7 s and 0.7 GB before a visit cap stopped it).
    let mut placed = vec![false; document.nodes().len()];
    while let Some((node, parent, depth)) = stack.pop() {
        if depth > 1024 {
            return Err(perr(&format!("node {}", node.index()), "node hierarchy too deep".into()));
        }
        match placed.get_mut(node.index()) {
            Some(p) if !*p => *p = true,
            _ => {
                let what = "node is reached twice (a child of two nodes, a root and a child, or in a cycle): glTF node hierarchies are strict trees";
                return Err(perr(&format!("node {}", node.index()), what.into()));
            }
        }
        let local = node_matrix(&node);
        let world = mat_mul(&parent, &local);
        if !world.iter().flatten().all(|v| v.is_finite()) {
            return Err(LoadError::NonFinite { path: path.to_path_buf(), element: "transform of node".into(), index: node.index() as u64 });
        }
        if let Some(gm) = node.mesh() {
            let mi = match mesh_map.get(&gm.index()) {
                Some(&i) => i,
                None => {
                    let mesh = convert_mesh(path, &gm, &buffers, quantized, &mut scene)?;
                    scene.meshes.push(mesh);
                    let i = scene.meshes.len() - 1;
                    mesh_map.insert(gm.index(), i);
                    i
                }
            };
            match node.extension_value("EXT_mesh_gpu_instancing") {
                Some(ext) => {
                    for t in gpu_instances(path, &document, &buffers, ext, node.index())? {
                        scene.instances.push(Instance { mesh: mi, transform: mat_mul(&world, &t) });
                    }
                }
                None => scene.instances.push(Instance { mesh: mi, transform: world }),
            }
        }
        for c in node.children().collect::<Vec<_>>().into_iter().rev() {
            stack.push((c, world, depth + 1));
        }
    }
    if scene.instances.is_empty() {
        scene.warnings.push(format!("{}: the scene places no mesh", path.display()));
    }
    Ok(scene)
}

/// The file a non-`data:` buffer or image URI names: percent-decoded, a `file:` scheme
/// stripped, relative paths taken from the model's directory `base`. Unless
/// `opts.allow_outside_uris`, the file (symlinks followed) must lie inside `base`
/// ([`LoadError::UriOutsideDirectory`]); a file that does not exist is left to the read,
/// which names it.
fn external(path: &Path, base: &Path, uri: &str, what: &str, opts: &LoadOptions) -> Result<PathBuf, LoadError> {
    let perr = |msg: String| LoadError::parse(path, "glTF", what, msg);
    let rest = match uri.strip_prefix("file://").or_else(|| uri.strip_prefix("file:")) {
        Some(rest) => rest,
        // Any other scheme (http:, …) is not read; the gltf crate refuses them the same way.
        None if uri.contains(':') => return Err(perr(format!("unsupported URI scheme in {uri:?}"))),
        None => uri,
    };
    let decoded = percent_decode(rest).ok_or_else(|| perr(format!("URI {uri:?} is not valid percent-encoded UTF-8")))?;
    let file = base.join(&decoded);
    if opts.allow_outside_uris {
        return Ok(file);
    }
    let outside = |resolved: PathBuf| LoadError::UriOutsideDirectory {
        path: path.to_path_buf(),
        what: what.to_string(),
        uri: uri.to_string(),
        resolved,
        dir: base.to_path_buf(),
    };
    let Ok(dir) = base.canonicalize() else {
        return Err(outside(file));
    };
    match file.canonicalize() {
        Ok(real) if real.starts_with(&dir) => Ok(file),
        Ok(real) => Err(outside(real)),
        // Not there (or unreadable): refuse what leads out lexically; otherwise the read
        // reports the missing file by name.
        Err(_) => {
            let lexical = lexically_normal(&dir.join(&decoded));
            if lexical.starts_with(&dir) {
                Ok(file)
            } else {
                Err(outside(lexical))
            }
        }
    }
}

/// `p` with `.` dropped and `..` applied to the components before it (no file system access).
fn lexically_normal(p: &Path) -> PathBuf {
    use std::path::Component;
    let mut out = PathBuf::new();
    for c in p.components() {
        match c {
            Component::CurDir => {}
            Component::ParentDir => {
                out.pop();
            }
            other => out.push(other),
        }
    }
    out
}

/// Decodes `%XX` escapes (RFC 3986); `None` for a malformed escape or non-UTF-8 result.
fn percent_decode(s: &str) -> Option<String> {
    let b = s.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        if b[i] == b'%' {
            let hex = b.get(i + 1..i + 3)?;
            let hex = std::str::from_utf8(hex).ok()?;
            out.push(u8::from_str_radix(hex, 16).ok()?);
            i += 3;
        } else {
            out.push(b[i]);
            i += 1;
        }
    }
    String::from_utf8(out).ok()
}

/// A decoded image in the gltf crate's pixel layout (what its own importer produces for a
/// file, so textures read here convert exactly as embedded ones do); `None` for layouts it
/// has no format for.
fn gltf_image_data(img: image::DynamicImage) -> Option<gltf::image::Data> {
    use gltf::image::Format as F;
    use image::DynamicImage as D;
    let format = match img {
        D::ImageLuma8(_) => F::R8,
        D::ImageLumaA8(_) => F::R8G8,
        D::ImageRgb8(_) => F::R8G8B8,
        D::ImageRgba8(_) => F::R8G8B8A8,
        D::ImageLuma16(_) => F::R16,
        D::ImageLumaA16(_) => F::R16G16,
        D::ImageRgb16(_) => F::R16G16B16,
        D::ImageRgba16(_) => F::R16G16B16A16,
        D::ImageRgb32F(_) => F::R32G32B32FLOAT,
        D::ImageRgba32F(_) => F::R32G32B32A32FLOAT,
        _ => return None,
    };
    let (width, height) = (img.width(), img.height());
    Some(gltf::image::Data { pixels: img.into_bytes(), format, width, height })
}

fn node_matrix(node: &gltf::Node) -> Mat4 {
    match node.transform() {
        gltf::scene::Transform::Matrix { matrix } => matrix.map(|c| c.map(f64::from)),
        gltf::scene::Transform::Decomposed { translation, rotation, scale } => {
            let q = rotation.map(f64::from);
            let n = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
            let q = if n > 0.0 { q.map(|v| v / n) } else { [0.0, 0.0, 0.0, 1.0] };
            trs_matrix(translation.map(f64::from), q, scale.map(f64::from))
        }
    }
}

fn image_data_to_rgba(d: gltf::image::Data, source: String) -> Option<m::Image> {
    use gltf::image::Format as F;
    let (w, h) = (d.width, d.height);
    let px = d.pixels;
    let n = (w as usize).checked_mul(h as usize)?;
    let rgba: Vec<[u8; 4]> = match d.format {
        F::R8 => px.iter().map(|&r| [r, r, r, 255]).collect(),
        F::R8G8 => px.chunks_exact(2).map(|c| [c[0], c[0], c[0], c[1]]).collect(),
        F::R8G8B8 => px.chunks_exact(3).map(|c| [c[0], c[1], c[2], 255]).collect(),
        F::R8G8B8A8 => px.chunks_exact(4).map(|c| [c[0], c[1], c[2], c[3]]).collect(),
        F::R16G16B16 => px.chunks_exact(6).map(|c| [c[1], c[3], c[5], 255]).collect(),
        F::R16G16B16A16 => px.chunks_exact(8).map(|c| [c[1], c[3], c[5], c[7]]).collect(),
        _ => {
            let _ = from_dynamic; // other formats are rare in base-colour textures
            return None;
        }
    };
    (rgba.len() == n).then_some(m::Image { width: w, height: h, rgba, source })
}

fn check_accessor(path: &Path, acc: &gltf::Accessor, what: &str, dt: &[DataType], dims: &[Dimensions]) -> Result<(), LoadError> {
    if !dt.contains(&acc.data_type()) || !dims.contains(&acc.dimensions()) {
        return Err(LoadError::parse(
            path,
            "glTF",
            format!("accessor {} ({what})", acc.index()),
            format!("unsupported component layout {:?} {:?} (integer attributes need KHR_mesh_quantization in extensionsUsed)", acc.data_type(), acc.dimensions()),
        ));
    }
    if let Some(s) = acc.sparse() {
        if s.count() == 0 {
            return Err(LoadError::parse(path, "glTF", format!("accessor {} ({what})", acc.index()), "sparse count 0"));
        }
    }
    // glTF requires a stride of at least the element; gltf's iterator asserts it (debug
    // builds) or reads overlapping elements (release builds). Every read checks it here.
    if let Some((v, stride)) = acc.view().and_then(|v| Some((v.index(), v.stride()?))) {
        if stride < acc.size() {
            let msg = format!("bufferView {v} has byteStride {stride}, less than the {}-byte element", acc.size());
            return Err(LoadError::parse(path, "glTF", format!("accessor {} ({what})", acc.index()), msg));
        }
    }
    Ok(())
}

/// Reads a float attribute stored as f32 or (KHR_mesh_quantization) as 8/16-bit integers,
/// normalized (scaled to [0, 1] or [-1, 1]) or not (integer values as floats).
fn read_floats<const N: usize>(acc: &gltf::Accessor, buffers: &[gltf::buffer::Data]) -> Option<Vec<[f32; N]>>
where
    [f32; N]: gltf::accessor::Item,
    [i8; N]: gltf::accessor::Item,
    [u8; N]: gltf::accessor::Item,
    [i16; N]: gltf::accessor::Item,
    [u16; N]: gltf::accessor::Item,
{
    let norm = acc.normalized();
    // Normalized signed values: max(c / MAX, -1) (glTF 2.0 §3.11).
    let f = |c: f32, max: f32, signed: bool| if !norm { c } else if signed { (c / max).max(-1.0) } else { c / max };
    Some(match acc.data_type() {
        DataType::F32 => elements::<[f32; N]>(acc, buffers)?,
        DataType::I8 => elements::<[i8; N]>(acc, buffers)?.into_iter().map(|v| v.map(|c| f(c.into(), 127.0, true))).collect(),
        DataType::U8 => elements::<[u8; N]>(acc, buffers)?.into_iter().map(|v| v.map(|c| f(c.into(), 255.0, false))).collect(),
        DataType::I16 => elements::<[i16; N]>(acc, buffers)?.into_iter().map(|v| v.map(|c| f(c.into(), 32767.0, true))).collect(),
        DataType::U16 => elements::<[u16; N]>(acc, buffers)?.into_iter().map(|v| v.map(|c| f(c.into(), 65535.0, false))).collect(),
        _ => return None,
    })
}

/// The elements of accessor `acc` as `T`; `None` where its data is missing or lies outside
/// its buffer view.
fn elements<T: gltf::accessor::Item + Send>(acc: &gltf::Accessor, buffers: &[gltf::buffer::Data]) -> Option<Vec<T>> {
    dense_elements(acc, buffers).or_else(|| {
        let get = |b: gltf::Buffer| buffers.get(b.index()).map(|d| &d.0[..]);
        gltf::accessor::Iter::<T>::new(acc.clone(), get).map(Iterator::collect)
    })
}

/// The elements of a dense (not sparse) accessor, decoded on every thread straight from its
/// buffer view: the values gltf's iterator gives, which decoded a 4.4 M-triangle GLB's
/// positions and indices on one thread (0.2 s, the other thread idle). `None` where this
/// does not apply (sparse, no view, a stride below the element, a range outside the view);
/// [`elements`] then takes the iterator, which decides those cases.
fn dense_elements<T: gltf::accessor::Item + Send>(acc: &gltf::Accessor, buffers: &[gltf::buffer::Data]) -> Option<Vec<T>> {
    let size = std::mem::size_of::<T>();
    if acc.sparse().is_some() || acc.size() != size {
        return None;
    }
    let view = acc.view()?;
    let stride = view.stride().unwrap_or(size);
    if stride < size {
        return None;
    }
    let end = acc.count().checked_sub(1)?.checked_mul(stride)?.checked_add(size)?.checked_add(acc.offset())?;
    let in_view = buffers.get(view.buffer().index())?.0.get(view.offset()..view.offset().checked_add(view.length())?)?;
    let data = in_view.get(acc.offset()..end)?;
    // Element `i` ends at `i · stride + size ≤ end - offset`: the indexing cannot fail.
    Some((0..acc.count()).into_par_iter().with_min_len(4096).map(|i| T::from_slice(&data[i * stride..i * stride + size])).collect())
}

fn convert_mesh(path: &Path, gm: &gltf::Mesh, buffers: &[gltf::buffer::Data], quantized: bool, scene: &mut LoadedScene) -> Result<Mesh, LoadError> {
    let q_all: &[DataType] = if quantized { &[DataType::F32, DataType::I8, DataType::U8, DataType::I16, DataType::U16] } else { &[DataType::F32] };
    let q_signed: &[DataType] = if quantized { &[DataType::F32, DataType::I8, DataType::I16] } else { &[DataType::F32] };
    let mut out = Mesh { name: gm.name().map(str::to_string).unwrap_or_else(|| format!("mesh {}", gm.index())), primitives: Vec::new() };
    for prim in gm.primitives() {
        let what = format!("mesh {} primitive {}", gm.index(), prim.index());
        let loc = |s: &str| format!("{s} of {what}");
        let mode = prim.mode();
        if matches!(mode, Mode::Points | Mode::Lines | Mode::LineLoop | Mode::LineStrip) {
            scene.stats.skipped_primitives += 1;
            scene.warnings.push(format!("{}: {what}: {mode:?} primitive skipped (only surfaces are sampled)", path.display()));
            continue;
        }
        let reader = prim.reader(|b| buffers.get(b.index()).map(|d| &d.0[..]));
        let Some(pacc) = prim.get(&gltf::Semantic::Positions) else {
            return Err(LoadError::parse(path, "glTF", what, "primitive has no POSITION"));
        };
        if pacc.count() == 0 {
            continue;
        }
        check_accessor(path, &pacc, "POSITION", q_all, &[Dimensions::Vec3])?;
        let positions: Vec<[f32; 3]> = read_floats::<3>(&pacc, buffers)
            .ok_or_else(|| LoadError::parse(path, "glTF", loc("POSITION"), "accessor data missing or out of its buffer view"))?;
        if positions.len() != pacc.count() {
            return Err(LoadError::parse(path, "glTF", loc("POSITION"), "accessor data shorter than its count"));
        }
        let nv = positions.len();
        let mut p = Primitive { positions, material: prim.material().index(), ..Default::default() };
        if let Some(nacc) = prim.get(&gltf::Semantic::Normals).filter(|a| a.count() > 0) {
            check_accessor(path, &nacc, "NORMAL", q_signed, &[Dimensions::Vec3])?;
            if let Some(n) = read_floats::<3>(&nacc, buffers) {
                if n.len() == nv {
                    p.normals = Some(n);
                }
            }
        }
        if let Some(cacc) = prim.get(&gltf::Semantic::Colors(0)).filter(|a| a.count() > 0) {
            check_accessor(path, &cacc, "COLOR_0", &[DataType::F32, DataType::U8, DataType::U16], &[Dimensions::Vec3, Dimensions::Vec4])?;
            if let Some(it) = reader.read_colors(0) {
                let c: Vec<[f32; 4]> = it.into_rgba_f32().collect();
                if c.len() == nv {
                    p.colors = Some(c);
                }
            }
        }
        for set in 0..8u32 {
            let Some(tacc) = prim.get(&gltf::Semantic::TexCoords(set)).filter(|a| a.count() > 0) else { break };
            let core: &[DataType] = &[DataType::F32, DataType::U8, DataType::U16];
            check_accessor(path, &tacc, "TEXCOORD", if quantized { q_all } else { core }, &[Dimensions::Vec2])?;
            match read_floats::<2>(&tacc, buffers) {
                Some(t) => {
                    if t.len() != nv {
                        break;
                    }
                    p.uvs.push(t);
                }
                None => break,
            }
        }
        let indices: Vec<u32> = match prim.indices() {
            Some(iacc) => {
                if iacc.count() == 0 {
                    Vec::new()
                } else {
                    check_accessor(path, &iacc, "indices", &[DataType::U8, DataType::U16, DataType::U32], &[Dimensions::Scalar])?;
                    let v: Option<Vec<u32>> = match iacc.data_type() {
                        DataType::U8 => elements::<u8>(&iacc, buffers).map(|v| v.into_par_iter().map(u32::from).collect()),
                        DataType::U16 => elements::<u16>(&iacc, buffers).map(|v| v.into_par_iter().map(u32::from).collect()),
                        _ => elements::<u32>(&iacc, buffers),
                    };
                    let v = v.ok_or_else(|| LoadError::parse(path, "glTF", loc("indices"), "accessor data missing or out of its buffer view"))?;
                    if v.len() != iacc.count() {
                        return Err(LoadError::parse(path, "glTF", loc("indices"), "accessor data shorter than its count"));
                    }
                    v
                }
            }
            None => (0..nv as u32).collect(),
        };
        // The largest index first (a parallel reduction, where finding the first bad one
        // item by item costs several times more); the first bad one only for the error.
        if indices.par_iter().max().is_some_and(|&v| v as usize >= nv) {
            if let Some((i, &v)) = indices.iter().enumerate().find(|(_, &v)| v as usize >= nv) {
                return Err(LoadError::IndexOutOfRange { path: path.to_path_buf(), element: loc("indices"), index: i as u64, value: v.into(), count: nv as u64 });
            }
        }
        p.triangles = match mode {
            Mode::Triangles => indices.par_chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
            Mode::TriangleStrip => (0..indices.len().saturating_sub(2))
                .map(|i| if i % 2 == 0 { [indices[i], indices[i + 1], indices[i + 2]] } else { [indices[i + 1], indices[i], indices[i + 2]] })
                .collect(),
            Mode::TriangleFan => (1..indices.len().saturating_sub(1)).map(|i| [indices[0], indices[i], indices[i + 1]]).collect(),
            _ => Vec::new(),
        };
        finish_primitive(path, &what, &mut p, &mut scene.stats)?;
        out.primitives.push(p);
    }
    Ok(out)
}

/// EXT_mesh_gpu_instancing: per-instance TRS read from accessors (float only).
fn gpu_instances(path: &Path, doc: &gltf::Document, buffers: &[gltf::buffer::Data], ext: &serde_json::Value, node: usize) -> Result<Vec<Mat4>, LoadError> {
    let loc = format!("EXT_mesh_gpu_instancing of node {node}");
    let perr = |msg: String| LoadError::parse(path, "glTF", loc.clone(), msg);
    let attrs = ext.get("attributes").and_then(|a| a.as_object()).ok_or_else(|| perr("no attributes".into()))?;
    let get = |name: &str, dims: Dimensions| -> Result<Option<Vec<Vec<f32>>>, LoadError> {
        let Some(idx) = attrs.get(name) else { return Ok(None) };
        let idx = idx.as_u64().ok_or_else(|| perr(format!("{name} is not an accessor index")))? as usize;
        let acc = doc.accessors().nth(idx).ok_or_else(|| perr(format!("{name} accessor {idx} does not exist")))?;
        check_accessor(path, &acc, name, &[DataType::F32], &[dims])?;
        if acc.count() == 0 {
            return Ok(Some(Vec::new()));
        }
        let v: Vec<Vec<f32>> = match dims {
            Dimensions::Vec4 => gltf::accessor::Iter::<[f32; 4]>::new(acc.clone(), |b| buffers.get(b.index()).map(|d| &d.0[..]))
                .ok_or_else(|| perr(format!("{name} data out of its buffer view")))?
                .map(|x| x.to_vec())
                .collect(),
            _ => gltf::accessor::Iter::<[f32; 3]>::new(acc.clone(), |b| buffers.get(b.index()).map(|d| &d.0[..]))
                .ok_or_else(|| perr(format!("{name} data out of its buffer view")))?
                .map(|x| x.to_vec())
                .collect(),
        };
        if v.len() != acc.count() {
            return Err(perr(format!("{name} data shorter than its count")));
        }
        Ok(Some(v))
    };
    let t = get("TRANSLATION", Dimensions::Vec3)?;
    let r = get("ROTATION", Dimensions::Vec4)?;
    let s = get("SCALE", Dimensions::Vec3)?;
    let n = [&t, &r, &s].iter().filter_map(|a| a.as_ref().map(Vec::len)).max().unwrap_or(0);
    for (name, a) in [("TRANSLATION", &t), ("ROTATION", &r), ("SCALE", &s)] {
        if let Some(a) = a {
            if a.len() != n {
                return Err(perr(format!("{name} has {} items, other attributes {n}", a.len())));
            }
        }
    }
    let mut out = Vec::with_capacity(n);
    for i in 0..n {
        let tt = t.as_ref().map_or([0.0; 3], |v| [v[i][0], v[i][1], v[i][2]].map(f64::from));
        let rr = r.as_ref().map_or([0.0, 0.0, 0.0, 1.0], |v| [v[i][0], v[i][1], v[i][2], v[i][3]].map(f64::from));
        let ss = s.as_ref().map_or([1.0; 3], |v| [v[i][0], v[i][1], v[i][2]].map(f64::from));
        if !tt.iter().chain(rr.iter()).chain(ss.iter()).all(|x| x.is_finite()) {
            return Err(LoadError::NonFinite { path: path.to_path_buf(), element: loc.clone(), index: i as u64 });
        }
        let qn = (rr[0] * rr[0] + rr[1] * rr[1] + rr[2] * rr[2] + rr[3] * rr[3]).sqrt();
        let rr = if qn > 0.0 { rr.map(|x| x / qn) } else { [0.0, 0.0, 0.0, 1.0] };
        out.push(trs_matrix(tt, rr, ss));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A GLB whose one buffer holds `bin` and whose JSON is `json`.
    fn glb(json: &str, bin: &[u8]) -> Vec<u8> {
        let mut j = json.as_bytes().to_vec();
        j.resize(j.len().next_multiple_of(4), b' ');
        let mut b = bin.to_vec();
        b.resize(b.len().next_multiple_of(4), 0);
        let mut out = b"glTF".to_vec();
        out.extend(2u32.to_le_bytes());
        out.extend(((12 + 8 + j.len() + 8 + b.len()) as u32).to_le_bytes());
        out.extend((j.len() as u32).to_le_bytes());
        out.extend(b"JSON");
        out.extend(&j);
        out.extend((b.len() as u32).to_le_bytes());
        out.extend(b"BIN\0");
        out.extend(&b);
        out
    }

    /// Accessors decoded straight from their views equal gltf's iterator: interleaved
    /// (strided) attributes at an offset, tightly packed indices of every width, and
    /// accessors that end past their view, which neither reads.
    #[test]
    fn dense_elements_match_the_gltf_iterator() {
        let n = 5usize;
        let mut bin = vec![0xAAu8; 8];
        for i in 0..n {
            for c in 0..6 {
                bin.extend(((i * 6 + c) as f32 * 0.5 - 3.0).to_le_bytes());
            }
        }
        let idx_at = bin.len();
        for i in 0..6u16 {
            bin.extend((i * 7 % 5).to_le_bytes());
        }
        for i in 0..6u32 {
            bin.extend((i * 3 % 5).to_le_bytes());
        }
        bin.extend([4u8, 0, 1, 2, 3, 1, 0, 0]);
        let json = format!(
            r#"{{"asset":{{"version":"2.0"}},"buffers":[{{"byteLength":{len}}}],
            "bufferViews":[{{"buffer":0,"byteOffset":8,"byteLength":{attr},"byteStride":24}},
                           {{"buffer":0,"byteOffset":{idx_at},"byteLength":12}},
                           {{"buffer":0,"byteOffset":{u32_at},"byteLength":24}},
                           {{"buffer":0,"byteOffset":{u8_at},"byteLength":8}}],
            "accessors":[{{"bufferView":0,"componentType":5126,"count":{n},"type":"VEC3"}},
                         {{"bufferView":0,"byteOffset":12,"componentType":5126,"count":{n},"type":"VEC3"}},
                         {{"bufferView":1,"componentType":5123,"count":6,"type":"SCALAR"}},
                         {{"bufferView":2,"componentType":5125,"count":6,"type":"SCALAR"}},
                         {{"bufferView":3,"componentType":5121,"count":6,"type":"SCALAR"}},
                         {{"bufferView":1,"byteOffset":4,"componentType":5123,"count":6,"type":"SCALAR"}},
                         {{"bufferView":0,"byteOffset":12,"componentType":5126,"count":{past},"type":"VEC3"}}]}}"#,
            len = bin.len().next_multiple_of(4),
            attr = n * 24,
            u32_at = idx_at + 12,
            u8_at = idx_at + 36,
            past = n + 1,
        );
        let (doc, buffers, _) = gltf::import_slice(glb(&json, &bin)).expect("valid GLB");
        let get = |b: gltf::Buffer| buffers.get(b.index()).map(|d| &d.0[..]);
        let acc = |i: usize| doc.accessors().nth(i).expect("accessor");
        fn same<T: gltf::accessor::Item + Send + PartialEq + std::fmt::Debug>(a: &gltf::Accessor, buffers: &[gltf::buffer::Data], iter: Option<Vec<T>>) {
            assert_eq!(dense_elements::<T>(a, buffers), iter, "accessor {}", a.index());
            assert_eq!(elements::<T>(a, buffers), iter, "accessor {}", a.index());
        }
        for i in [0, 1, 6] {
            let iter = gltf::accessor::Iter::<[f32; 3]>::new(acc(i), get).map(Iterator::collect::<Vec<_>>);
            same::<[f32; 3]>(&acc(i), &buffers, iter);
        }
        assert_eq!(dense_elements::<[f32; 3]>(&acc(1), &buffers).expect("in its view")[4], [10.5, 11.0, 11.5], "vertex 4's normal: components 27–29 of 0.5·k − 3");
        for i in [2, 5] {
            same::<u16>(&acc(i), &buffers, gltf::accessor::Iter::<u16>::new(acc(i), get).map(Iterator::collect::<Vec<_>>));
        }
        same::<u32>(&acc(3), &buffers, gltf::accessor::Iter::<u32>::new(acc(3), get).map(Iterator::collect::<Vec<_>>));
        same::<u8>(&acc(4), &buffers, gltf::accessor::Iter::<u8>::new(acc(4), get).map(Iterator::collect::<Vec<_>>));
        // Past their views: neither path reads them.
        assert_eq!(dense_elements::<[f32; 3]>(&acc(6), &buffers), None);
        assert_eq!(dense_elements::<u16>(&acc(5), &buffers), None);
    }
}
