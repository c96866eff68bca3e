//! PLY (ASCII and binary) via ply-rs-bw: faces and triangle strips, vertex colours (uchar
//! or float), normals, per-vertex UVs, and per-face-corner UVs (a `texcoord` float list on
//! faces, MeshLab/VCGLIB) with the texture named by a `comment TextureFile <name>` header
//! line; a file without faces is a point cloud.
//!
//! PLY has no material model: when a texture is bound it gives the colour and vertex
//! colours are not multiplied in (MeshLab shows one or the other; VCGLIB writes a
//! placeholder grey per vertex next to textures).

use std::io::{BufRead, Cursor};
use std::path::Path;

use ply_rs_bw::parser::Parser;
use ply_rs_bw::ply::{DefaultElement, Encoding, Property};

use super::{decode_image, finish_primitive, read_file, LoadOptions};
use crate::error::LoadError;
use crate::mesh::*;

fn scalar(p: &Property) -> Option<f64> {
    Some(match *p {
        Property::Char(v) => v.into(),
        Property::UChar(v) => v.into(),
        Property::Short(v) => v.into(),
        Property::UShort(v) => v.into(),
        Property::Int(v) => v.into(),
        Property::UInt(v) => v.into(),
        Property::Float(v) => v.into(),
        Property::Double(v) => v,
        _ => return None,
    })
}

fn list(p: &Property) -> Option<Vec<i64>> {
    Some(match p {
        Property::ListChar(v) => v.iter().map(|&x| x.into()).collect(),
        Property::ListUChar(v) => v.iter().map(|&x| x.into()).collect(),
        Property::ListShort(v) => v.iter().map(|&x| x.into()).collect(),
        Property::ListUShort(v) => v.iter().map(|&x| x.into()).collect(),
        Property::ListInt(v) => v.iter().map(|&x| x.into()).collect(),
        Property::ListUInt(v) => v.iter().map(|&x| x.into()).collect(),
        _ => return None,
    })
}

fn float_list(p: &Property) -> Option<Vec<f64>> {
    Some(match p {
        Property::ListFloat(v) => v.iter().map(|&x| x.into()).collect(),
        Property::ListDouble(v) => v.clone(),
        _ => return None,
    })
}

/// A colour channel: integers are 8-bit sRGB, floats are [0, 1] sRGB.
fn channel(p: &Property) -> Option<f32> {
    let v = scalar(p)?;
    let unit = match p {
        Property::Float(_) | Property::Double(_) => v,
        Property::UShort(_) => v / 65535.0,
        _ => v / 255.0,
    };
    Some(unit.clamp(0.0, 1.0) as f32)
}

/// Some exporters (Blender 2.4x) write free text lines in the header; they are turned into
/// comments so the strict header grammar accepts the file. `None` = no change needed.
fn sanitize_header(bytes: &[u8]) -> Option<Vec<u8>> {
    const KEYWORDS: &[&str] = &["ply", "format", "element", "property", "comment", "obj_info", "end_header"];
    let end = bytes.windows(10).position(|w| w == b"end_header")?;
    let header = std::str::from_utf8(&bytes[..end]).ok()?;
    let bad = |l: &str| !l.trim().is_empty() && !KEYWORDS.contains(&l.split_whitespace().next().unwrap_or(""));
    if !header.lines().any(bad) {
        return None;
    }
    let mut out = Vec::with_capacity(bytes.len() + 64);
    for line in header.split_inclusive('\n') {
        if bad(line) {
            out.extend_from_slice(b"comment ");
        }
        out.extend_from_slice(line.as_bytes());
    }
    out.extend_from_slice(&bytes[end..]);
    Some(out)
}

pub(super) fn load(path: &Path, bytes: &[u8], opts: &LoadOptions) -> Result<LoadedScene, LoadError> {
    let perr = |loc: String, msg: String| LoadError::parse(path, "PLY", loc, msg);
    let parser = Parser::<DefaultElement>::new();
    let fixed = sanitize_header(bytes);
    let bytes: &[u8] = fixed.as_deref().unwrap_or(bytes);
    let mut cur = Cursor::new(bytes);
    let header = parser.read_header(&mut cur).map_err(|e| perr("header".into(), e.to_string()))?;
    // A declared count can never exceed the bytes left (each element takes at least one
    // byte, one line in ASCII): refuse before the parser allocates for it.
    let remaining = bytes.len() as u64 - cur.position().min(bytes.len() as u64);
    for (name, e) in &header.elements {
        if e.count as u64 > remaining {
            return Err(perr(format!("element {name}"), format!("header declares {} elements but only {remaining} bytes follow (truncated file?)", e.count)));
        }
    }
    let _ = cur.fill_buf();
    let payload = parser.read_payload(&mut cur, &header).map_err(|e| {
        let enc = match header.encoding {
            Encoding::Ascii => "ascii",
            _ => "binary",
        };
        perr(format!("{enc} payload after byte {}", cur.position()), format!("{e} (truncated or malformed file?)"))
    })?;
    for (name, e) in &header.elements {
        let got = payload.get(name).map_or(0, Vec::len);
        if got != e.count {
            return Err(perr(format!("element {name}"), format!("header declares {} elements, file holds {got} (truncated?)", e.count)));
        }
    }
    let verts = payload.get("vertex").map(Vec::as_slice).unwrap_or(&[]);
    if verts.is_empty() {
        return Err(perr("element vertex".into(), "no vertices".into()));
    }
    let get = |e: &DefaultElement, names: &[&str]| names.iter().find_map(|n| e.get(*n)).and_then(scalar);
    let mut positions = Vec::with_capacity(verts.len());
    for (i, v) in verts.iter().enumerate() {
        let (Some(x), Some(y), Some(z)) = (get(v, &["x"]), get(v, &["y"]), get(v, &["z"])) else {
            return Err(perr(format!("vertex {i}"), "missing x, y or z".into()));
        };
        let p = [x as f32, y as f32, z as f32];
        if !p.iter().all(|c| c.is_finite()) {
            return Err(LoadError::NonFinite { path: path.to_path_buf(), element: "vertex".into(), index: i as u64 });
        }
        positions.push(p);
    }
    let first = &verts[0];
    let has = |names: &[&str]| names.iter().any(|n| first.contains_key(*n));
    let normals = if has(&["nx"]) && has(&["ny"]) && has(&["nz"]) {
        Some(verts.iter().map(|v| [get(v, &["nx"]), get(v, &["ny"]), get(v, &["nz"])].map(|c| c.unwrap_or(0.0) as f32)).collect::<Vec<_>>())
    } else {
        None
    };
    const R: &[&str] = &["red", "r", "diffuse_red"];
    const G: &[&str] = &["green", "g", "diffuse_green"];
    const B: &[&str] = &["blue", "b", "diffuse_blue"];
    const A: &[&str] = &["alpha", "a", "diffuse_alpha"];
    let colors = if has(R) && has(G) && has(B) {
        let ch = |v: &DefaultElement, names: &[&str]| names.iter().find_map(|n| v.get(*n)).and_then(channel);
        Some(
            verts
                .iter()
                .map(|v| {
                    let lut = |c: Option<f32>| srgb_to_linear(c.unwrap_or(1.0));
                    [lut(ch(v, R)), lut(ch(v, G)), lut(ch(v, B)), ch(v, A).unwrap_or(1.0)]
                })
                .collect::<Vec<_>>(),
        )
    } else {
        None
    };
    const U: &[&str] = &["u", "s", "texture_u", "texture_s"];
    const V: &[&str] = &["v", "t", "texture_v", "texture_t"];
    let uvs = if has(U) && has(V) {
        Some(verts.iter().map(|v| [get(v, U).unwrap_or(0.0) as f32, 1.0 - get(v, V).unwrap_or(0.0) as f32]).collect::<Vec<_>>())
    } else {
        None
    };

    let n = positions.len() as i64;
    let mut triangles: Vec<[u32; 3]> = Vec::new();
    let mut polygons = 0u64;
    let idx_of = |e: &DefaultElement| e.get("vertex_indices").or_else(|| e.get("vertex_index")).and_then(list);
    let check = |elem: &str, i: usize, v: i64| -> Result<u32, LoadError> {
        if v < 0 || v >= n {
            return Err(LoadError::IndexOutOfRange { path: path.to_path_buf(), element: elem.into(), index: i as u64, value: v as u64, count: n as u64 });
        }
        Ok(v as u32)
    };
    let faces = payload.get("face").map(Vec::as_slice).unwrap_or(&[]);
    // Per-corner UVs: every corner becomes its own vertex (attributes copied), since the
    // same position can carry different UVs across a seam.
    let corner_uv = faces.first().is_some_and(|f| f.contains_key("texcoord"));
    let (mut positions, mut normals, mut colors, mut uvs) = (positions, normals, colors, uvs);
    let (src_pos, src_nrm, src_col) = if corner_uv { (positions.clone(), normals.clone(), colors.clone()) } else { (Vec::new(), None, None) };
    let mut corner_uvs: Vec<[f32; 2]> = Vec::new();
    if corner_uv {
        positions.clear();
        if let Some(n) = &mut normals {
            n.clear();
        }
        if let Some(c) = &mut colors {
            c.clear();
        }
    }
    for (fi, f) in faces.iter().enumerate() {
        let Some(idx) = idx_of(f) else {
            return Err(perr(format!("face {fi}"), "no vertex_indices list".into()));
        };
        let mut idx: Vec<u32> = idx.iter().map(|&v| check("face", fi, v)).collect::<Result<_, _>>()?;
        if corner_uv {
            let tc = f.get("texcoord").and_then(float_list).unwrap_or_default();
            if tc.len() != 2 * idx.len() {
                return Err(perr(format!("face {fi}"), format!("texcoord list has {} values for {} corners (expected 2 per corner)", tc.len(), idx.len())));
            }
            for (k, v) in idx.iter_mut().enumerate() {
                let uv = [tc[2 * k] as f32, 1.0 - tc[2 * k + 1] as f32];
                if !uv.iter().all(|c| c.is_finite()) {
                    return Err(LoadError::NonFinite { path: path.to_path_buf(), element: "face texcoord".into(), index: fi as u64 });
                }
                let src = *v as usize;
                positions.push(src_pos[src]);
                if let (Some(n), Some(sn)) = (&mut normals, &src_nrm) {
                    n.push(sn[src]);
                }
                if let (Some(c), Some(sc)) = (&mut colors, &src_col) {
                    c.push(sc[src]);
                }
                corner_uvs.push(uv);
                *v = (positions.len() - 1) as u32;
            }
        }
        match idx.len() {
            0..=2 => {}
            3 => triangles.push([idx[0], idx[1], idx[2]]),
            _ => {
                polygons += 1;
                let corners: Vec<[f32; 3]> = idx.iter().map(|&v| positions[v as usize]).collect();
                for t in crate::polygon::triangulate(&corners) {
                    triangles.push(t.map(|k| idx[k as usize]));
                }
            }
        }
    }
    for (si, s) in payload.get("tristrips").map(Vec::as_slice).unwrap_or(&[]).iter().enumerate() {
        let Some(idx) = idx_of(s) else {
            return Err(perr(format!("tristrips {si}"), "no vertex_indices list".into()));
        };
        // -1 restarts the strip; winding alternates within a strip.
        for run in idx.split(|&v| v < 0) {
            let run: Vec<u32> = run.iter().map(|&v| check("tristrips", si, v)).collect::<Result<_, _>>()?;
            for i in 0..run.len().saturating_sub(2) {
                triangles.push(if i % 2 == 0 { [run[i], run[i + 1], run[i + 2]] } else { [run[i + 1], run[i], run[i + 2]] });
            }
        }
    }
    let mut scene = LoadedScene::default();
    scene.stats.polygons_triangulated = polygons;
    if triangles.is_empty() {
        let (positions, normals, colors) = if corner_uv { (src_pos, src_nrm, src_col) } else { (positions, normals, colors) };
        scene.points = Some(PointCloud { positions, normals, colors });
        return Ok(scene);
    }
    if corner_uv {
        uvs = Some(corner_uvs);
    }
    let mut material = None;
    if uvs.is_some() && opts.load_textures {
        if let Some(name) = header.comments.iter().find_map(|c| c.trim().strip_prefix("TextureFile").map(str::trim)).filter(|n| !n.is_empty()) {
            let file = path.parent().unwrap_or(Path::new(".")).join(name);
            match read_file(&file, opts.max_file_bytes).map_err(|e| e.to_string()).and_then(|b| decode_image(&b, file.display().to_string())) {
                Ok(img) => {
                    scene.images.push(img);
                    scene.files.push(file);
                    let texture = TextureRef { image: 0, tex_coord: 0, transform: UV_IDENTITY, wrap_s: Wrap::Repeat, wrap_t: Wrap::Repeat };
                    scene.materials.push(Material { name: name.to_string(), base_color: [1.0; 4], texture: Some(texture), ..Default::default() });
                    material = Some(0);
                    colors = None;
                }
                Err(e) => scene.warnings.push(format!("{}: TextureFile {name:?}: {e}; using vertex colours", path.display())),
            }
        }
    }
    let mut prim = Primitive { positions, normals, colors, uvs: uvs.into_iter().collect(), triangles, material };
    finish_primitive(path, "faces", &mut prim, &mut scene.stats)?;
    scene.meshes.push(Mesh { name: super::obj::file_stem(path), primitives: vec![prim] });
    scene.instances.push(Instance { mesh: 0, transform: IDENTITY });
    Ok(scene)
}
