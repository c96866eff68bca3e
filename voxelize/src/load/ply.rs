//! PLY (ASCII and binary) via ply-rs-bw: faces and triangle strips, vertex colours (uchar
//! or float), normals, per-vertex UVs, and per-face-corner UVs (a `texcoord` float list on
//! faces, MeshLab/VCGLIB) with the texture named by a `comment TextureFile <name>` header
//! line; a file without faces is a point cloud.
//!
//! PLY has no material model: when a texture is bound it gives the colour and vertex
//! colours are not multiplied in (MeshLab shows one or the other; VCGLIB writes a
//! placeholder grey per vertex next to textures).

use std::io::Cursor;
use std::path::Path;

use ply_rs_bw::parser::Parser;
use ply_rs_bw::ply::{DefaultElement, Encoding, Header, PropertyType, ScalarType};

use super::{decode_image, finish_primitive, read_file, LoadOptions};
use crate::error::LoadError;
use crate::mesh::*;

mod binary;

/// A PLY scalar type.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Ty {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Ty {
    fn of(t: &ScalarType) -> Ty {
        match t {
            ScalarType::Char => Ty::I8,
            ScalarType::UChar => Ty::U8,
            ScalarType::Short => Ty::I16,
            ScalarType::UShort => Ty::U16,
            ScalarType::Int => Ty::I32,
            ScalarType::UInt => Ty::U32,
            ScalarType::Float => Ty::F32,
            ScalarType::Double => Ty::F64,
        }
    }

    /// Bytes of one binary value.
    fn size(self) -> usize {
        match self {
            Ty::I8 | Ty::U8 => 1,
            Ty::I16 | Ty::U16 => 2,
            Ty::I32 | Ty::U32 | Ty::F32 => 4,
            Ty::F64 => 8,
        }
    }

    fn is_int(self) -> bool {
        !matches!(self, Ty::F32 | Ty::F64)
    }
}

/// A property's type: a scalar, or a list (length type, item type).
#[derive(Clone, Copy, Debug)]
enum Prop {
    Scalar(Ty),
    List(Ty, Ty),
}

/// An element of the header: name, declared count, properties in file order.
struct Elem {
    name: String,
    count: usize,
    props: Vec<(String, Prop)>,
}

impl Elem {
    /// The header's elements in file order.
    fn all(h: &Header) -> Vec<Elem> {
        h.elements
            .iter()
            .map(|(name, e)| Elem {
                name: name.clone(),
                count: e.count,
                props: e
                    .properties
                    .iter()
                    .map(|(n, p)| {
                        let t = match &p.data_type {
                            PropertyType::Scalar(s) => Prop::Scalar(Ty::of(s)),
                            PropertyType::List(c, s) => Prop::List(Ty::of(c), Ty::of(s)),
                        };
                        (n.clone(), t)
                    })
                    .collect(),
            })
            .collect()
    }

    /// The index and type of the first of `names` among the properties.
    fn property(&self, names: &[&str]) -> Option<(usize, Prop)> {
        names.iter().find_map(|n| self.props.iter().position(|(k, _)| k == n)).map(|i| (i, self.props[i].1))
    }
}

/// The element body, read one value at a time, in the header's property order. The
/// payload is decoded straight into the arrays the mesh needs (no per-element map: the
/// ply-rs payload reader kept a hash map per vertex, ≈ 190 bytes for a 3-byte vertex).
enum Body<'a> {
    /// Binary, little- or big-endian.
    Binary { data: &'a [u8], pos: usize, big: bool },
    /// ASCII: one element per line, values separated by white space.
    Ascii { lines: std::iter::Enumerate<std::str::Lines<'a>>, tokens: std::str::SplitAsciiWhitespace<'a>, line: usize, line_base: usize },
}

impl<'a> Body<'a> {
    /// Starts the next element record (ASCII: its line; blank lines are skipped).
    fn begin(&mut self) -> Result<(), String> {
        if let Body::Ascii { lines, tokens, line, line_base } = self {
            loop {
                let Some((i, l)) = lines.next() else { return Err("the file ends early (truncated?)".into()) };
                if !l.trim().is_empty() {
                    *line = *line_base + i + 1;
                    *tokens = l.split_ascii_whitespace();
                    return Ok(());
                }
            }
        }
        Ok(())
    }

    /// Where the reader is, for messages.
    fn location(&self) -> String {
        match self {
            Body::Binary { pos, .. } => format!("byte {pos}"),
            Body::Ascii { line, .. } => format!("line {line}"),
        }
    }

    /// One scalar as f64 (every PLY scalar type converts exactly).
    fn scalar(&mut self, t: Ty) -> Result<f64, String> {
        match self {
            Body::Binary { data, pos, big } => {
                let end = pos.checked_add(t.size()).filter(|&e| e <= data.len()).ok_or("the file ends early (truncated?)")?;
                let v = binary_scalar(&data[*pos..end], t, *big);
                *pos = end;
                Ok(v)
            }
            Body::Ascii { tokens, .. } => {
                let s = tokens.next().ok_or("the line has too few values")?;
                let bad = || format!("{s:?} is not a valid {t:?}");
                let int = |lo: i64, hi: i64| s.parse::<i64>().ok().filter(|v| (lo..=hi).contains(v)).map(|v| v as f64).ok_or_else(bad);
                match t {
                    Ty::I8 => int(i8::MIN.into(), i8::MAX.into()),
                    Ty::U8 => int(0, u8::MAX.into()),
                    Ty::I16 => int(i16::MIN.into(), i16::MAX.into()),
                    Ty::U16 => int(0, u16::MAX.into()),
                    Ty::I32 => int(i32::MIN.into(), i32::MAX.into()),
                    Ty::U32 => int(0, u32::MAX.into()),
                    // Parsed at the declared precision, so a float reads as its f32 value.
                    Ty::F32 => s.parse::<f32>().map(f64::from).map_err(|_| bad()),
                    Ty::F64 => s.parse::<f64>().map_err(|_| bad()),
                }
            }
        }
    }

    /// A list's length (an integer, non-negative).
    fn count(&mut self, t: Ty) -> Result<u64, String> {
        let v = self.scalar(t)?;
        if !(v >= 0.0) || v.fract() != 0.0 {
            return Err(format!("list length {v} is not a non-negative integer"));
        }
        Ok(v as u64)
    }

    /// Skips a value of property type `t`.
    fn skip(&mut self, t: Prop) -> Result<(), String> {
        match t {
            Prop::Scalar(s) => self.scalar(s).map(drop),
            Prop::List(c, s) => {
                let n = self.count(c)?;
                if let Body::Binary { data, pos, .. } = self {
                    // Bounded by the bytes left: a hostile length ends the file, not the loop.
                    let bytes = n.checked_mul(s.size() as u64).filter(|&b| b <= (data.len() - *pos) as u64).ok_or("the file ends early (truncated?)")?;
                    *pos += bytes as usize;
                    return Ok(());
                }
                for _ in 0..n {
                    self.scalar(s)?;
                }
                Ok(())
            }
        }
    }
}

/// A binary scalar of type `t` from its `t.size()` bytes, as f64 (every PLY scalar type
/// converts exactly).
fn binary_scalar(b: &[u8], t: Ty, big: bool) -> f64 {
    let n = t.size().min(b.len());
    let mut a = [0u8; 8];
    a[..n].copy_from_slice(&b[..n]);
    if big {
        a[..n].reverse();
    }
    match t {
        Ty::I8 => f64::from(a[0] as i8),
        Ty::U8 => f64::from(a[0]),
        Ty::I16 => f64::from(i16::from_le_bytes([a[0], a[1]])),
        Ty::U16 => f64::from(u16::from_le_bytes([a[0], a[1]])),
        Ty::I32 => f64::from(i32::from_le_bytes([a[0], a[1], a[2], a[3]])),
        Ty::U32 => f64::from(u32::from_le_bytes([a[0], a[1], a[2], a[3]])),
        Ty::F32 => f64::from(f32::from_le_bytes([a[0], a[1], a[2], a[3]])),
        Ty::F64 => f64::from_le_bytes(a),
    }
}

/// The smallest record an element's properties can make in binary (lists empty).
fn min_record_bytes(e: &Elem) -> u64 {
    e.props
        .iter()
        .map(|(_, p)| match *p {
            Prop::Scalar(s) => s.size() as u64,
            Prop::List(c, _) => c.size() as u64,
        })
        .sum()
}

/// A colour channel: integers are 8-bit sRGB (16-bit for ushort), floats are [0, 1] sRGB.
fn channel(t: Ty, v: f64) -> f32 {
    let unit = match t {
        Ty::F32 | Ty::F64 => v,
        Ty::U16 => v / 65535.0,
        _ => v / 255.0,
    };
    unit.clamp(0.0, 1.0) as f32
}

/// What is read of the vertex element: the index (in property order) of each wanted
/// scalar property, the first of its names found in the header.
#[derive(Default)]
struct VertexLayout {
    slot: Vec<Option<usize>>,
    types: Vec<Ty>,
}

/// Vertex slots (indices into the values read per vertex).
const X: usize = 0;
const NX: usize = 3;
const R: usize = 6;
const U: usize = 10;
const SLOTS: usize = 12;

impl VertexLayout {
    fn new(e: &Elem) -> Self {
        const NAMES: [&[&str]; SLOTS] = [
            &["x"],
            &["y"],
            &["z"],
            &["nx"],
            &["ny"],
            &["nz"],
            &["red", "r", "diffuse_red"],
            &["green", "g", "diffuse_green"],
            &["blue", "b", "diffuse_blue"],
            &["alpha", "a", "diffuse_alpha"],
            &["u", "s", "texture_u", "texture_s"],
            &["v", "t", "texture_v", "texture_t"],
        ];
        let mut slot = vec![None; e.props.len()];
        let mut types = vec![Ty::F32; SLOTS];
        for (k, names) in NAMES.iter().enumerate() {
            // The first name of the list that the header has (as a scalar) fills the slot.
            if let Some((i, Prop::Scalar(t))) = e.property(names) {
                slot[i] = Some(k);
                types[k] = t;
            }
        }
        VertexLayout { slot, types }
    }

    fn has(&self, k: usize) -> bool {
        self.slot.contains(&Some(k))
    }

    /// Whether the vertices have normals, colours, alpha and UVs (all their slots filled).
    fn attributes(&self) -> Attributes {
        Attributes {
            normals: self.has(NX) && self.has(NX + 1) && self.has(NX + 2),
            colors: self.has(R) && self.has(R + 1) && self.has(R + 2),
            alpha: self.has(R + 3),
            uvs: self.has(U) && self.has(U + 1),
        }
    }

    /// A vertex's position from its slot values (`None` when not finite).
    fn position(v: &[f64; SLOTS]) -> Option<[f32; 3]> {
        let p = [v[X] as f32, v[X + 1] as f32, v[X + 2] as f32];
        p.iter().all(|c| c.is_finite()).then_some(p)
    }

    fn normal(v: &[f64; SLOTS]) -> [f32; 3] {
        [v[NX] as f32, v[NX + 1] as f32, v[NX + 2] as f32]
    }

    /// A vertex's linear colour (alpha 1 without an alpha property).
    fn color(&self, v: &[f64; SLOTS], alpha: bool) -> [f32; 4] {
        let ch = |k: usize| channel(self.types[k], v[k]);
        [srgb_to_linear(ch(R)), srgb_to_linear(ch(R + 1)), srgb_to_linear(ch(R + 2)), if alpha { ch(R + 3) } else { 1.0 }]
    }

    /// A vertex's UV, v flipped to the glTF convention.
    fn uv(v: &[f64; SLOTS]) -> [f32; 2] {
        [v[U] as f32, 1.0 - v[U + 1] as f32]
    }
}

/// Which optional vertex attributes a file has.
#[derive(Clone, Copy)]
struct Attributes {
    normals: bool,
    colors: bool,
    alpha: bool,
    uvs: bool,
}

/// Everything read from the body.
#[derive(Default)]
struct Payload {
    positions: Vec<[f32; 3]>,
    normals: Option<Vec<[f32; 3]>>,
    colors: Option<Vec<[f32; 4]>>,
    uvs: Option<Vec<[f32; 2]>>,
    /// Faces: corner counts and their vertex indices, flat (each checked against the
    /// declared vertex count).
    face_len: Vec<u32>,
    face_idx: Vec<u32>,
    /// Per-corner texcoords (u, v pairs, flat) when faces carry a `texcoord` list.
    face_uv: Option<Vec<f32>>,
    /// Triangle strips, flat, -1 separating strips and ending each element.
    strips: Vec<i64>,
    /// Triangles decoded straight from the file (the parallel binary reader), before those
    /// of `face_len` and `strips`.
    triangles: Vec<[u32; 3]>,
}

/// Where the header's `end_header` starts, if it has one.
fn header_end(bytes: &[u8]) -> Option<usize> {
    bytes.windows(10).position(|w| w == b"end_header")
}

/// Some exporters (Blender 2.4x) write free text lines in the header; they are turned into
/// comments so the strict header grammar accepts the file. `None` = no change needed.
fn sanitize_header(bytes: &[u8]) -> Option<Vec<u8>> {
    const KEYWORDS: &[&str] = &["ply", "format", "element", "property", "comment", "obj_info", "end_header"];
    let end = header_end(bytes)?;
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

/// The first `format` or `element` line of the header (1-based) holding a number past
/// `u64`: the header grammar unwraps its parse and panics on one.
fn number_past_u64(bytes: &[u8]) -> Option<usize> {
    let end = header_end(bytes).unwrap_or(bytes.len());
    bytes[..end].split(|&b| b == b'\n').position(|line| {
        let keyword = line.split(|b| b.is_ascii_whitespace()).find(|w| !w.is_empty());
        matches!(keyword, Some(b"format" | b"element"))
            && line.split(|b| !b.is_ascii_digit()).any(|digits| std::str::from_utf8(digits).is_ok_and(|d| !d.is_empty() && d.parse::<u64>().is_err()))
    })
    .map(|i| i + 1)
}

pub(super) fn load(path: &Path, bytes: &[u8], opts: &LoadOptions) -> Result<LoadedScene, LoadError> {
    let perr = |loc: String, msg: String| LoadError::parse(path, "PLY", loc, msg);
    if let Some(line) = number_past_u64(bytes) {
        return Err(perr(format!("header line {line}"), "a number too large for 64 bits".into()));
    }
    let parser = Parser::<DefaultElement>::new();
    let fixed = sanitize_header(bytes);
    let bytes: &[u8] = fixed.as_deref().unwrap_or(bytes);
    let mut cur = Cursor::new(bytes);
    let header = parser.read_header(&mut cur).map_err(|e| {
        let (loc, msg) = header_error(&e.to_string());
        perr(loc, msg)
    })?;
    let start = usize::try_from(cur.position()).unwrap_or(usize::MAX).min(bytes.len());
    let binary = header.encoding != Encoding::Ascii;
    // A declared count can never exceed what the bytes left can hold (a binary record takes
    // at least its fixed-size properties, an ASCII one a line): refuse before anything is
    // sized by it.
    let remaining = (bytes.len() - start) as u64;
    let elems = Elem::all(&header);
    for e in &elems {
        let name = &e.name;
        let per = if binary { min_record_bytes(e).max(1) } else { 1 };
        if (e.count as u64).checked_mul(per).is_none_or(|need| need > remaining) {
            return Err(perr(format!("element {name}"), format!("header declares {} elements but only {remaining} bytes follow (truncated file?)", e.count)));
        }
    }
    let big = header.encoding == Encoding::BinaryBigEndian;
    let nverts = elems.iter().find(|e| e.name == "vertex").map_or(0, |e| e.count);
    // The common binary layout (fixed-size vertices, then triangles only) is decoded in
    // parallel; anything else, and any file it finds a fault in, is read by the reader
    // below, which says what and where the fault is.
    let fast = if binary && opts.max_face_corners >= 3 { binary::read(&bytes[start..], big, &elems, nverts) } else { None };
    let pl = match fast {
        Some(pl) => pl,
        None => read_body(path, bytes, start, binary, big, &elems, nverts, opts)?,
    };
    if pl.positions.is_empty() {
        return Err(perr("element vertex".into(), "no vertices".into()));
    }
    let Payload { positions, normals, colors, uvs, face_len, face_idx, face_uv, strips, triangles } = pl;

    let mut triangles = triangles;
    // Faces of the general reader: at least a triangle each, mostly (bounded by the bytes).
    triangles.reserve(face_len.len());
    let mut polygons = 0u64;
    // Per-corner UVs: every corner becomes its own vertex (attributes copied), since the
    // same position can carry different UVs across a seam.
    let corner_uv = face_uv.is_some();
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
    let mut at = 0usize;
    let mut idx: Vec<u32> = Vec::new();
    let mut corners: Vec<[f32; 3]> = Vec::new();
    for (fi, &len) in face_len.iter().enumerate() {
        let len = len as usize;
        let end = at + len;
        idx.clear();
        idx.extend_from_slice(&face_idx[at..end]);
        if let Some(tc) = &face_uv {
            for (k, v) in idx.iter_mut().enumerate() {
                let c = at + k;
                let uv = [tc[2 * c], 1.0 - tc[2 * c + 1]];
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
        at = end;
        match idx.len() {
            0..=2 => {}
            3 => triangles.push([idx[0], idx[1], idx[2]]),
            _ => {
                polygons += 1;
                corners.clear();
                corners.extend(idx.iter().map(|&v| positions[v as usize]));
                for t in crate::polygon::triangulate(&corners) {
                    triangles.push(t.map(|k| idx[k as usize]));
                }
            }
        }
    }
    // -1 restarts a strip (and ends every strip element); winding alternates within one.
    for run in strips.split(|&v| v < 0) {
        for w in 0..run.len().saturating_sub(2) {
            let [a, b, c] = [run[w], run[w + 1], run[w + 2]].map(|v| v as u32);
            triangles.push(if w % 2 == 0 { [a, b, c] } else { [b, a, c] });
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
                Err(e) => {
                    if !file.exists() {
                        scene.missing.push(file.clone());
                    }
                    scene.warnings.push(format!("{}: TextureFile {name:?}: {e}; using vertex colours", path.display()))
                }
            }
        }
    }
    let mut prim = Primitive { positions, normals, colors, uvs: uvs.into_iter().collect(), triangles, material };
    finish_primitive(path, "faces", &mut prim, &mut scene.stats)?;
    scene.meshes.push(Mesh { name: super::obj::file_stem(path), primitives: vec![prim] });
    scene.instances.push(Instance { mesh: 0, transform: IDENTITY });
    Ok(scene)
}

/// Reads the body element by element, one value at a time (every layout, ASCII and binary).
#[allow(clippy::too_many_arguments)]
fn read_body(path: &Path, bytes: &[u8], start: usize, binary: bool, big: bool, elems: &[Elem], nverts: usize, opts: &LoadOptions) -> Result<Payload, LoadError> {
    let perr = |loc: String, msg: String| LoadError::parse(path, "PLY", loc, msg);
    let mut body = if binary {
        Body::Binary { data: bytes, pos: start, big }
    } else {
        let text = std::str::from_utf8(&bytes[start..]).map_err(|e| perr(format!("byte {}", start + e.valid_up_to()), "ASCII body is not valid text".into()))?;
        let line_base = bytes[..start].iter().filter(|&&b| b == b'\n').count();
        Body::Ascii { lines: text.lines().enumerate(), tokens: "".split_ascii_whitespace(), line: line_base, line_base }
    };
    let mut pl = Payload::default();
    for e in elems {
        let name = &e.name;
        let r = match name.as_str() {
            "vertex" => read_vertices(path, &mut body, e, &mut pl),
            "face" => read_faces(path, &mut body, e, nverts, opts.max_face_corners, &mut pl),
            "tristrips" => read_strips(path, &mut body, e, nverts, &mut pl),
            _ => (0..e.count).try_for_each(|i| {
                body.begin().and_then(|_| e.props.iter().try_for_each(|(_, p)| body.skip(*p))).map_err(|m| (i, m))
            }).map_err(|(i, m)| perr(format!("{name} {i} at {}", body.location()), m)),
        };
        r?;
    }
    Ok(pl)
}

/// Reads the vertex element into positions and the optional normals, colours and UVs.
fn read_vertices(path: &Path, body: &mut Body, e: &Elem, pl: &mut Payload) -> Result<(), LoadError> {
    let lay = VertexLayout::new(e);
    let at = |body: &Body, i: usize, m: String| LoadError::parse(path, "PLY", format!("vertex {i} at {}", body.location()), m);
    if e.count > 0 && !(lay.has(X) && lay.has(X + 1) && lay.has(X + 2)) {
        return Err(LoadError::parse(path, "PLY", "vertex 0", "missing x, y or z"));
    }
    let has = lay.attributes();
    // The count was checked against the bytes left, so these are at most a small multiple
    // of the file's size.
    pl.positions = Vec::with_capacity(e.count);
    pl.normals = has.normals.then(|| Vec::with_capacity(e.count));
    pl.colors = has.colors.then(|| Vec::with_capacity(e.count));
    pl.uvs = has.uvs.then(|| Vec::with_capacity(e.count));
    let mut v = [0.0f64; SLOTS];
    for i in 0..e.count {
        body.begin().map_err(|m| at(body, i, m))?;
        for (pi, (_, p)) in e.props.iter().enumerate() {
            match (lay.slot[pi], *p) {
                (Some(k), Prop::Scalar(t)) => v[k] = body.scalar(t).map_err(|m| at(body, i, m))?,
                (_, t) => body.skip(t).map_err(|m| at(body, i, m))?,
            }
        }
        let Some(p) = VertexLayout::position(&v) else {
            return Err(LoadError::NonFinite { path: path.to_path_buf(), element: "vertex".into(), index: i as u64 });
        };
        pl.positions.push(p);
        if let Some(n) = &mut pl.normals {
            n.push(VertexLayout::normal(&v));
        }
        if let Some(c) = &mut pl.colors {
            c.push(lay.color(&v, has.alpha));
        }
        if let Some(t) = &mut pl.uvs {
            t.push(VertexLayout::uv(&v));
        }
    }
    Ok(())
}

/// Reads a vertex index and checks it against the declared vertex count.
fn vertex_index(path: &Path, body: &mut Body, t: Ty, elem: &str, i: usize, nverts: usize) -> Result<i64, LoadError> {
    let v = body.scalar(t).map_err(|m| LoadError::parse(path, "PLY", format!("{elem} {i} at {}", body.location()), m))?;
    // Integer types only (checked by the caller), so `v` is an exact integer.
    if v >= nverts as f64 {
        return Err(LoadError::IndexOutOfRange { path: path.to_path_buf(), element: elem.into(), index: i as u64, value: v as u64, count: nverts as u64 });
    }
    Ok(v as i64)
}

/// Reads the face element: corner lists (flat) and per-corner texcoords.
fn read_faces(path: &Path, body: &mut Body, e: &Elem, nverts: usize, max_corners: usize, pl: &mut Payload) -> Result<(), LoadError> {
    if e.count == 0 {
        return Ok(());
    }
    let at = |body: &Body, i: usize, m: String| LoadError::parse(path, "PLY", format!("face {i} at {}", body.location()), m);
    let (ipi, ict, ity) = match e.property(&["vertex_indices", "vertex_index"]) {
        Some((i, Prop::List(c, t))) if t.is_int() => (i, c, t),
        _ => return Err(LoadError::parse(path, "PLY", "face 0", "no vertex_indices list")),
    };
    let tc = e.property(&["texcoord"]);
    let tpi = tc.as_ref().map(|t| t.0);
    if tc.is_some() {
        pl.face_uv = Some(Vec::new());
    }
    pl.face_len = Vec::with_capacity(e.count);
    for fi in 0..e.count {
        body.begin().map_err(|m| at(body, fi, m))?;
        let (mut corners, mut uv_values) = (0u64, 0u64);
        for (pi, &(_, p)) in e.props.iter().enumerate() {
            if pi == ipi {
                corners = body.count(ict).map_err(|m| at(body, fi, m))?;
                if corners > max_corners as u64 {
                    return Err(LoadError::Limit { path: path.to_path_buf(), what: format!("face {fi} has {corners} corners, more than the limit of {max_corners}") });
                }
                for _ in 0..corners {
                    let v = vertex_index(path, body, ity, "face", fi, nverts)?;
                    if v < 0 {
                        return Err(LoadError::IndexOutOfRange { path: path.to_path_buf(), element: "face".into(), index: fi as u64, value: v as u64, count: nverts as u64 });
                    }
                    pl.face_idx.push(v as u32);
                }
            } else if Some(pi) == tpi {
                match (p, &mut pl.face_uv) {
                    (Prop::List(c, t), Some(uv)) if !t.is_int() => {
                        uv_values = body.count(c).map_err(|m| at(body, fi, m))?;
                        for _ in 0..uv_values {
                            uv.push(body.scalar(t).map_err(|m| at(body, fi, m))? as f32);
                        }
                    }
                    (t, _) => body.skip(t).map_err(|m| at(body, fi, m))?,
                }
            } else {
                body.skip(p).map_err(|m| at(body, fi, m))?;
            }
        }
        if tpi.is_some() && uv_values != 2 * corners {
            return Err(LoadError::parse(path, "PLY", format!("face {fi}"), format!("texcoord list has {uv_values} values for {corners} corners (expected 2 per corner)")));
        }
        // At most `max_corners`, which a u32 holds (the loaders' limit is far below 2³²).
        pl.face_len.push(u32::try_from(corners).map_err(|_| at(body, fi, "too many corners".into()))?);
    }
    Ok(())
}

/// Reads the tristrips element: indices, flat, -1 after each strip element.
fn read_strips(path: &Path, body: &mut Body, e: &Elem, nverts: usize, pl: &mut Payload) -> Result<(), LoadError> {
    if e.count == 0 {
        return Ok(());
    }
    let at = |body: &Body, i: usize, m: String| LoadError::parse(path, "PLY", format!("tristrips {i} at {}", body.location()), m);
    let (ipi, ict, ity) = match e.property(&["vertex_indices", "vertex_index"]) {
        Some((i, Prop::List(c, t))) if t.is_int() => (i, c, t),
        _ => return Err(LoadError::parse(path, "PLY", "tristrips 0", "no vertex_indices list")),
    };
    for si in 0..e.count {
        body.begin().map_err(|m| at(body, si, m))?;
        for (pi, &(_, p)) in e.props.iter().enumerate() {
            if pi == ipi {
                let n = body.count(ict).map_err(|m| at(body, si, m))?;
                for _ in 0..n {
                    pl.strips.push(vertex_index(path, body, ity, "tristrips", si, nverts)?);
                }
            } else {
                body.skip(p).map_err(|m| at(body, si, m))?;
            }
        }
        pl.strips.push(-1);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// One value of a property as written in a test file.
    #[derive(Clone, Copy)]
    enum V {
        F(f64),
        I(i64),
    }

    /// Writes `(type, value)` in the given encoding.
    fn put(out: &mut Vec<u8>, enc: &str, ty: &str, v: V) {
        let as_f = |v: V| match v {
            V::F(f) => f,
            V::I(i) => i as f64,
        };
        let as_i = |v: V| match v {
            V::F(f) => f as i64,
            V::I(i) => i,
        };
        if enc == "ascii" {
            match ty {
                "float" | "double" => out.extend_from_slice(format!("{} ", as_f(v)).as_bytes()),
                _ => out.extend_from_slice(format!("{} ", as_i(v)).as_bytes()),
            }
            return;
        }
        let mut b: Vec<u8> = match ty {
            "char" => (as_i(v) as i8).to_le_bytes().to_vec(),
            "uchar" => (as_i(v) as u8).to_le_bytes().to_vec(),
            "short" => (as_i(v) as i16).to_le_bytes().to_vec(),
            "ushort" => (as_i(v) as u16).to_le_bytes().to_vec(),
            "int" => (as_i(v) as i32).to_le_bytes().to_vec(),
            "uint" => (as_i(v) as u32).to_le_bytes().to_vec(),
            "float" => (as_f(v) as f32).to_le_bytes().to_vec(),
            "double" => as_f(v).to_le_bytes().to_vec(),
            _ => unreachable!(),
        };
        if enc == "binary_big_endian" {
            b.reverse();
        }
        out.extend_from_slice(&b);
    }

    /// A PLY exercising every reader path: vertex positions as double, normals, uchar
    /// colours, float UVs and an extra list on vertices; an unknown element between vertex
    /// and face; faces with an int index list, a texcoord list and an extra scalar; strips
    /// with restarts. The same content in ASCII, little- and big-endian binary must load to
    /// the same scene.
    fn sample_ply(enc: &str) -> Vec<u8> {
        let mut out = format!(
            "ply\nformat {enc} 1.0\nelement vertex 5\nproperty double x\nproperty double y\nproperty double z\n\
             property float nx\nproperty float ny\nproperty float nz\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n\
             property list uchar short junk\nproperty float u\nproperty float v\n\
             element material 2\nproperty list int float weights\nproperty uchar id\n\
             element face 2\nproperty uchar flags\nproperty list uchar uint vertex_indices\nproperty list uchar float texcoord\n\
             element tristrips 1\nproperty list int int vertex_indices\nend_header\n"
        )
        .into_bytes();
        let nl = |o: &mut Vec<u8>| {
            if enc == "ascii" {
                o.push(b'\n');
            }
        };
        let verts = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.25], [0.0, 1.0, 0.5], [0.5, 2.0, 0.0]];
        for (i, p) in verts.iter().enumerate() {
            for c in p {
                put(&mut out, enc, "double", V::F(*c));
            }
            for c in [0.0, 0.0, 1.0] {
                put(&mut out, enc, "float", V::F(c));
            }
            for c in [10 * i as i64, 200, 255] {
                put(&mut out, enc, "uchar", V::I(c));
            }
            put(&mut out, enc, "uchar", V::I(i as i64));
            for k in 0..i {
                put(&mut out, enc, "short", V::I(-(k as i64)));
            }
            put(&mut out, enc, "float", V::F(0.25 * i as f64));
            put(&mut out, enc, "float", V::F(0.5));
            nl(&mut out);
        }
        for m in 0..2 {
            put(&mut out, enc, "int", V::I(3));
            for w in [0.5, 1.5, 2.5] {
                put(&mut out, enc, "float", V::F(w));
            }
            put(&mut out, enc, "uchar", V::I(m));
            nl(&mut out);
        }
        for (f, corners) in [vec![0u32, 1, 2, 3], vec![2, 3, 4]].iter().enumerate() {
            put(&mut out, enc, "uchar", V::I(f as i64));
            put(&mut out, enc, "uchar", V::I(corners.len() as i64));
            for &c in corners {
                put(&mut out, enc, "uint", V::I(c.into()));
            }
            put(&mut out, enc, "uchar", V::I(2 * corners.len() as i64));
            for &c in corners {
                put(&mut out, enc, "float", V::F(0.125 * f64::from(c)));
                put(&mut out, enc, "float", V::F(0.75));
            }
            nl(&mut out);
        }
        put(&mut out, enc, "int", V::I(6));
        for v in [0, 1, 2, -1, 2, 3] {
            put(&mut out, enc, "int", V::I(v));
        }
        nl(&mut out);
        out
    }

    #[test]
    fn encodings_load_alike_and_as_written() {
        let path = Path::new("sample.ply");
        let opts = LoadOptions::default();
        let scenes: Vec<LoadedScene> = ["ascii", "binary_little_endian", "binary_big_endian"].iter().map(|e| load(path, &sample_ply(e), &opts).expect(e)).collect();
        let p = &scenes[0].meshes[0].primitives[0];
        // Per-corner texcoords: 4 + 3 corner vertices; quad → 2 triangles, triangle, strip
        // of 3 (0 1 2) and the restart's strip is too short (2 3).
        assert_eq!(p.positions.len(), 7);
        assert_eq!(p.triangles.len(), 4);
        assert_eq!(p.positions[6], [0.5, 2.0, 0.0]);
        assert_eq!(p.uvs[0][1], [0.125, 0.25]);
        let c = p.colors.as_ref().expect("colours");
        assert_eq!(c[1], [srgb_to_linear(10.0 / 255.0), srgb_to_linear(200.0 / 255.0), 1.0, 1.0]);
        assert_eq!(p.normals.as_ref().expect("normals")[3], [0.0, 0.0, 1.0]);
        for s in &scenes[1..] {
            let q = &s.meshes[0].primitives[0];
            assert_eq!((&q.positions, &q.triangles, &q.uvs, &q.colors, &q.normals), (&p.positions, &p.triangles, &p.uvs, &p.colors, &p.normals));
        }
    }

    /// Truncated bodies, hostile list lengths and out-of-range indices are refused with the
    /// element, its index and where in the file.
    #[test]
    fn broken_bodies_are_refused_with_a_location() {
        let path = Path::new("bad.ply");
        let opts = LoadOptions::default();
        for enc in ["ascii", "binary_little_endian", "binary_big_endian"] {
            let full = sample_ply(enc);
            for cut in [full.len() - 3, full.len() - 40, full.len() / 2] {
                let e = load(path, &full[..cut], &opts).expect_err("truncated");
                assert!(matches!(e, LoadError::Parse { .. }), "{enc} cut at {cut}: {e}");
            }
        }
        // A face list claiming 4 billion corners in a few bytes: refused by the corner limit
        // before anything is read for it.
        let mut b = b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty uchar x\nproperty uchar y\nproperty uchar z\nelement face 1\nproperty list uint uint vertex_indices\nend_header\n".to_vec();
        b.extend_from_slice(&[0, 0, 0, 1, 0, 0, 0, 1, 0]);
        b.extend_from_slice(&u32::MAX.to_le_bytes());
        let e = load(path, &b, &opts).expect_err("corner limit");
        assert!(matches!(e, LoadError::Limit { .. }), "{e}");
        // An index past the vertices, an unskippable list in an unknown element.
        let mut b = b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty uchar x\nproperty uchar y\nproperty uchar z\nelement face 1\nproperty list uchar uint vertex_indices\nend_header\n".to_vec();
        b.extend_from_slice(&[0, 0, 0, 1, 0, 0, 0, 1, 0, 3]);
        for v in [0u32, 1, 3] {
            b.extend_from_slice(&v.to_le_bytes());
        }
        assert!(matches!(load(path, &b, &opts), Err(LoadError::IndexOutOfRange { value: 3, count: 3, .. })));
        let b = b"ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty uchar x\nproperty uchar y\nproperty uchar z\nelement blob 1\nproperty list uint double d\nend_header\n\x00\x00\x00\xff\xff\xff\xff";
        let e = load(path, b, &opts).expect_err("list past the end");
        assert!(matches!(&e, LoadError::Parse { location, .. } if location.contains("blob 0")), "{e}");
    }
}

/// The PLY parser's header error (`Line 6: Couldn't parse line.\n\tString: '…'\n\tError:
/// ParseError { location: LineCol { … column: 10 … }, expected: ExpectedSet { … } }`) as a
/// location and one readable sentence: the line, what it says, and what was expected.
fn header_error(raw: &str) -> (String, String) {
    let Some(rest) = raw.strip_prefix("Line ") else {
        return ("header".into(), raw.split_whitespace().collect::<Vec<_>>().join(" "));
    };
    let line = rest.split(':').next().unwrap_or("?").trim().to_string();
    let text = raw.split_once("String: '").and_then(|(_, r)| r.split_once('\'')).map(|(t, _)| t.trim().to_string());
    let column = raw.split_once("column: ").and_then(|(_, r)| r.split(|c: char| !c.is_ascii_digit()).next()).filter(|c| !c.is_empty());
    let expected: Vec<String> = raw
        .split_once("expected: {")
        .map(|(_, r)| r.split('}').next().unwrap_or(""))
        .map(|set| {
            set.split(", ")
                .map(|t| t.trim().trim_matches('"').trim_matches('\\').trim_matches('"').to_string())
                .filter(|t| !t.is_empty() && !t.starts_with('['))
                .collect()
        })
        .unwrap_or_default();
    let mut msg = match &text {
        Some(t) => format!("cannot parse {t:?}"),
        None => "cannot parse the line".to_string(),
    };
    if let Some(c) = column {
        msg.push_str(&format!(" at column {c}"));
    }
    if !expected.is_empty() {
        msg.push_str(&format!("; expected one of: {}", expected.join(", ")));
    }
    (format!("header line {line}"), msg)
}

#[cfg(test)]
mod header_error_tests {
    /// No Rust debug structure reaches the user: the line, its text, the column and the
    /// expected keywords.
    #[test]
    fn header_errors_read_as_sentences() {
        let raw = "Line 6: Couldn't parse line.\n\tString: 'property floot z\n'\n\tError: ParseError { location: LineCol { line: 1, column: 10, offset: 9 }, expected: ExpectedSet { expected: {\"\\\"char\\\"\", \"\\\"float\\\"\", \"[' '|'\\\\t']\"} } }";
        let (loc, msg) = super::header_error(raw);
        assert_eq!(loc, "header line 6");
        assert_eq!(msg, "cannot parse \"property floot z\" at column 10; expected one of: char, float");
        assert!(!msg.contains("ParseError") && !msg.contains('{'));
    }
}
