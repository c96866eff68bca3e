//! The statements of an OBJ file that the loader uses (`v`, `vt`, `vn`, `f`, `o`, `g`,
//! `usemtl`, `mtllib`), parsed on every thread: the text is cut at line ends into chunks,
//! every chunk is parsed on its own, and the chunks are put back in file order.
//!
//! The models are the ones tobj (`single_index: false`, no triangulation, points and lines
//! ignored) makes, so that a file converts to the same triangles it always did:
//! - a model ends at `o` or `g` after faces, at `usemtl` naming another material after
//!   faces, and at the end of the file (even without faces);
//! - a face's indices are 1-based, or negative counting back from the last element read
//!   before the face; an index must name an element read before the model ends;
//! - a corner without a texture coordinate (or normal), in a model ended after at least one
//!   `vt` (`vn`) line, takes the previous corner's, or the first one of the file for the
//!   model's first corner;
//! - `v x y z w` divides by `w`; `v x y z r g b` adds a vertex colour, and then every vertex
//!   a face uses must have one.
//!
//! Faces of one or two corners (points, lines written with `f`), `usemtl` and `mtllib`
//! without a name, and `l`, `p` and all other statements are skipped. What tobj accepted by accident is refused with the line that
//! says it: an index of 0, a malformed colour, an index too large for the machine.

use rayon::prelude::*;

/// An index a corner does not have (no `vt` or `vn` given).
pub(super) const MISSING: u32 = u32::MAX;

/// The name of a model without one (tobj's, so that meshes keep their names).
pub(super) const UNNAMED: &str = "unnamed_object";

/// One model: a run of faces between model boundaries.
#[derive(Debug, PartialEq)]
pub(super) struct ObjModel {
    /// The name of the last `o` or `g` before it ([`UNNAMED`] before any, or when that
    /// has none).
    pub name: String,
    /// The material of the last `usemtl` before it, if that name was defined by then.
    pub material: Option<usize>,
    /// Its faces: a range of [`Parsed::arities`], whose corners are a range of
    /// [`Parsed::corners`].
    pub faces: std::ops::Range<usize>,
    pub corners: std::ops::Range<usize>,
    /// Elements read before the model ended: its indices must be below these.
    pub positions: usize,
    pub texcoords: usize,
    pub normals: usize,
    pub colors: usize,
}

/// The whole file's elements, faces and models.
#[derive(Debug, Default, PartialEq)]
pub(super) struct Parsed {
    /// `x, y, z` per `v` line (divided by `w` where given).
    pub positions: Vec<[f32; 3]>,
    /// `r, g, b` per `v` line that has a colour, in file order.
    pub colors: Vec<[f32; 3]>,
    pub texcoords: Vec<[f32; 2]>,
    pub normals: Vec<[f32; 3]>,
    /// Per corner `[v, vt, vn]`, 0-based ([`MISSING`] where not given).
    pub corners: Vec<[u32; 3]>,
    /// Corners per face (faces of three or more corners only).
    pub arities: Vec<u32>,
    pub models: Vec<ObjModel>,
}

/// What went wrong, and on which line (1-based).
#[derive(Debug)]
pub(super) struct SyntaxError {
    pub line: usize,
    pub message: String,
}

/// A statement that ends or starts a model, at its place among the faces.
enum Event {
    Object(String),
    UseMtl(String),
    MtlLib(String),
}

/// An element count at some point of the file: positions, colours, texcoords, normals.
#[derive(Clone, Copy, Default)]
struct Counts {
    v: usize,
    c: usize,
    vt: usize,
    vn: usize,
}

impl Counts {
    fn add(self, o: Counts) -> Counts {
        Counts { v: self.v + o.v, c: self.c + o.c, vt: self.vt + o.vt, vn: self.vn + o.vn }
    }
}

/// A negative index, resolved once the elements before its chunk are counted.
struct Relative {
    corner: usize,
    component: usize,
    /// Elements of that kind read in the chunk before the face, plus the (negative) index.
    local: i64,
    line: usize,
}

/// One chunk of lines, parsed.
#[derive(Default)]
struct Chunk {
    lines: usize,
    positions: Vec<[f32; 3]>,
    colors: Vec<[f32; 3]>,
    texcoords: Vec<[f32; 2]>,
    normals: Vec<[f32; 3]>,
    corners: Vec<[u32; 3]>,
    arities: Vec<u32>,
    relative: Vec<Relative>,
    /// Events with the chunk's face, corner and element counts when they occur.
    events: Vec<(usize, usize, Counts, Event)>,
    error: Option<SyntaxError>,
}

impl Chunk {
    /// The elements read so far.
    fn counts(&self) -> Counts {
        Counts { v: self.positions.len(), c: self.colors.len(), vt: self.texcoords.len(), vn: self.normals.len() }
    }
}

/// Bytes per chunk: large enough that a chunk's set-up is negligible, small enough that
/// every thread gets many.
pub(super) const CHUNK_BYTES: usize = 1 << 20;

/// Parses `text` (calls `mtllib` for each `mtllib` statement, in file order, with the rest
/// of its line; it returns the names of the materials the library adds, which `usemtl`
/// then finds).
#[cfg(test)]
fn parse(text: &str, mtllib: impl FnMut(&str) -> Vec<String>) -> Result<Parsed, SyntaxError> {
    parse_in_chunks(text, CHUNK_BYTES, mtllib)
}

/// [`parse`] with chunks of about `chunk_bytes` (whole lines).
#[cfg(test)]
fn parse_in_chunks(text: &str, chunk_bytes: usize, mtllib: impl FnMut(&str) -> Vec<String>) -> Result<Parsed, SyntaxError> {
    let mut p = ChunkedParse::default();
    p.add(text, chunk_bytes);
    p.finish(mtllib)
}

/// A file's statements parsed as its text arrives, in pieces of whole lines ([`Self::add`]),
/// then put together in file order ([`Self::finish`]): a reader streaming the file holds
/// one piece of text at a time, not the file.
#[derive(Default)]
pub(super) struct ChunkedParse {
    chunks: Vec<Chunk>,
}

impl ChunkedParse {
    /// Parses `text`, the lines that follow those added before, on every thread in chunks of
    /// about `chunk_bytes` (whole lines).
    pub(super) fn add(&mut self, text: &str, chunk_bytes: usize) {
        let bytes = text.as_bytes();
        let mut cuts = vec![0];
        while let Some(&last) = cuts.last() {
            if last >= bytes.len() {
                break;
            }
            let want = (last + chunk_bytes.max(1)).min(bytes.len());
            // Cut after a line end (a chunk never splits a line).
            let end = match bytes[want..].iter().position(|&b| b == b'\n') {
                Some(i) => want + i + 1,
                None => bytes.len(),
            };
            cuts.push(end);
        }
        self.chunks.par_extend(cuts.par_windows(2).map(|w| parse_chunk(&text[w[0]..w[1]])));
    }

    /// Whether a line added so far is malformed ([`Self::finish`] reports the first).
    pub(super) fn failed(&self) -> bool {
        self.chunks.iter().any(|c| c.error.is_some())
    }

    /// The statements of all the text added, in file order.
    pub(super) fn finish(self, mut mtllib: impl FnMut(&str) -> Vec<String>) -> Result<Parsed, SyntaxError> {
        let chunks = self.chunks;
        // Counts before each chunk, and the first error in file order.
        let mut before = Vec::with_capacity(chunks.len());
        let (mut counts, mut lines, mut faces, mut corners) = (Counts::default(), 0usize, 0usize, 0usize);
        for ch in &chunks {
            if let Some(e) = &ch.error {
                return Err(SyntaxError { line: lines + e.line, message: e.message.clone() });
            }
            before.push((counts, lines, faces, corners));
            counts = counts.add(ch.counts());
            lines += ch.lines;
            faces += ch.arities.len();
            corners += ch.corners.len();
        }
        let total = counts;
        // Zeroed by the allocator (fresh pages): each is written once, below, on every thread.
        let mut p = Parsed {
            positions: vec![[0.0; 3]; total.v],
            colors: vec![[0.0; 3]; total.c],
            texcoords: vec![[0.0; 2]; total.vt],
            normals: vec![[0.0; 3]; total.vn],
            corners: vec![[0; 3]; corners],
            arities: vec![0; faces],
            models: Vec::new(),
        };
        // Models, from the events in file order.
        let mut defined: std::collections::HashMap<String, usize> = std::collections::HashMap::new();
        let mut material_count = 0usize;
        let mut open = ObjModel { name: UNNAMED.to_owned(), material: None, faces: 0..0, corners: 0..0, positions: 0, texcoords: 0, normals: 0, colors: 0 };
        let end_model = |open: &mut ObjModel, face: usize, corner: usize, at: Counts, models: &mut Vec<ObjModel>| {
            let name = open.name.clone();
            let m = ObjModel { name, material: open.material, faces: open.faces.start..face, corners: open.corners.start..corner, positions: at.v, texcoords: at.vt, normals: at.vn, colors: at.c };
            open.faces = face..face;
            open.corners = corner..corner;
            models.push(m);
        };
        for (ch, &(base, _, face0, corner0)) in chunks.iter().zip(&before) {
            for (face_local, corner_local, at, ev) in &ch.events {
                let (face, corner, at) = (face0 + face_local, corner0 + corner_local, base.add(*at));
                let has_faces = face > open.faces.start;
                match ev {
                    Event::Object(name) => {
                        if has_faces {
                            end_model(&mut open, face, corner, at, &mut p.models);
                        }
                        open.name = if name.is_empty() { UNNAMED.to_owned() } else { name.clone() };
                    }
                    Event::UseMtl(name) => {
                        let new = defined.get(name).copied();
                        if open.material != new && has_faces {
                            end_model(&mut open, face, corner, at, &mut p.models);
                        }
                        open.material = new;
                    }
                    Event::MtlLib(file) => {
                        // The library's materials follow the ones before; a name defined again
                        // means the later one.
                        let names = mtllib(file);
                        for (k, name) in names.iter().enumerate() {
                            defined.insert(name.clone(), material_count + k);
                        }
                        material_count += names.len();
                    }
                }
            }
        }
        end_model(&mut open, faces, corners, total, &mut p.models);

        // Elements and corners in file order, copied on every thread into each chunk's part
        // of the arrays, each chunk freed once copied (the peak holds the chunks in flight
        // twice, not the file); negative indices resolved against the elements before their
        // chunk. The first error in file order is the first chunk's that has one.
        let parts: Vec<Part> = {
            let sizes = |f: fn(&Chunk) -> usize| chunks.iter().map(f).collect::<Vec<_>>();
            let mut positions = split_into(&mut p.positions, sizes(|c| c.positions.len()));
            let mut colors = split_into(&mut p.colors, sizes(|c| c.colors.len()));
            let mut texcoords = split_into(&mut p.texcoords, sizes(|c| c.texcoords.len()));
            let mut normals = split_into(&mut p.normals, sizes(|c| c.normals.len()));
            let mut corners = split_into(&mut p.corners, sizes(|c| c.corners.len()));
            let mut arities = split_into(&mut p.arities, sizes(|c| c.arities.len()));
            (0..chunks.len())
                .map(|_| Part {
                    positions: positions.pop_front().unwrap_or_default(),
                    colors: colors.pop_front().unwrap_or_default(),
                    texcoords: texcoords.pop_front().unwrap_or_default(),
                    normals: normals.pop_front().unwrap_or_default(),
                    corners: corners.pop_front().unwrap_or_default(),
                    arities: arities.pop_front().unwrap_or_default(),
                })
                .collect()
        };
        let copied: Vec<Result<(), SyntaxError>> = chunks
            .into_par_iter()
            .zip(parts)
            .zip(&before)
            .map(|((ch, part), &(base, lines0, _, _))| {
                part.positions.copy_from_slice(&ch.positions);
                part.colors.copy_from_slice(&ch.colors);
                part.texcoords.copy_from_slice(&ch.texcoords);
                part.normals.copy_from_slice(&ch.normals);
                part.arities.copy_from_slice(&ch.arities);
                part.corners.copy_from_slice(&ch.corners);
                for r in &ch.relative {
                    let b = [base.v, base.vt, base.vn][r.component] as i64;
                    let v = b + r.local;
                    match u32::try_from(v) {
                        Ok(v) if v != MISSING => part.corners[r.corner][r.component] = v,
                        _ => {
                            let message = if v < 0 {
                                format!("a relative index points {} elements before the first of its kind", -v)
                            } else {
                                format!("a relative index resolves to {v}, too large")
                            };
                            return Err(SyntaxError { line: lines0 + r.line, message });
                        }
                    }
                }
                Ok(())
            })
            .collect();
        copied.into_iter().collect::<Result<(), _>>()?;
        Ok(p)
    }
}

/// One chunk's part of the file's arrays.
struct Part<'a> {
    positions: &'a mut [[f32; 3]],
    colors: &'a mut [[f32; 3]],
    texcoords: &'a mut [[f32; 2]],
    normals: &'a mut [[f32; 3]],
    corners: &'a mut [[u32; 3]],
    arities: &'a mut [u32],
}

/// `all` cut into consecutive parts of the given sizes (which sum to its length).
fn split_into<T>(mut all: &mut [T], sizes: Vec<usize>) -> std::collections::VecDeque<&mut [T]> {
    sizes
        .into_iter()
        .map(|n| {
            let (part, rest) = std::mem::take(&mut all).split_at_mut(n);
            all = rest;
            part
        })
        .collect()
}

/// The whitespace-separated words of a line, as `str::split_whitespace` gives them: on
/// ASCII lines (all numbers are) by bytes, which is several times faster than decoding
/// characters; on others by characters (a non-ASCII space separates words too).
enum Words<'a> {
    Ascii(&'a str, usize),
    Unicode(std::str::SplitWhitespace<'a>),
}

impl<'a> Words<'a> {
    fn new(line: &'a str) -> Words<'a> {
        if line.is_ascii() {
            Words::Ascii(line, 0)
        } else {
            Words::Unicode(line.split_whitespace())
        }
    }
}

/// `char::is_whitespace` for an ASCII byte.
fn ascii_space(b: u8) -> bool {
    matches!(b, b' ' | b'\t' | b'\n' | 0x0b | 0x0c | b'\r')
}

impl<'a> Iterator for Words<'a> {
    type Item = &'a str;

    fn next(&mut self) -> Option<&'a str> {
        match self {
            Words::Ascii(line, at) => {
                let b = line.as_bytes();
                let mut i = *at;
                while i < b.len() && ascii_space(b[i]) {
                    i += 1;
                }
                if i == b.len() {
                    *at = i;
                    return None;
                }
                let start = i;
                while i < b.len() && !ascii_space(b[i]) {
                    i += 1;
                }
                *at = i;
                // ASCII bytes: every index is a character boundary.
                line.get(start..i)
            }
            Words::Unicode(w) => w.next(),
        }
    }
}

/// `i64::from_str` of the bytes (an optional sign, then decimal digits), without the
/// UTF-8 round trip: `None` where that gives an error.
fn parse_index(b: &[u8]) -> Option<i64> {
    let (neg, digits) = match b {
        [b'-', rest @ ..] => (true, rest),
        [b'+', rest @ ..] => (false, rest),
        _ => (false, b),
    };
    if digits.is_empty() {
        return None;
    }
    let mut v: i64 = 0;
    for &d in digits {
        if !d.is_ascii_digit() {
            return None;
        }
        // Accumulated toward the sign, so that i64::MIN parses as it does in std.
        let d = (d - b'0') as i64;
        v = v.checked_mul(10)?;
        v = if neg { v.checked_sub(d)? } else { v.checked_add(d)? };
    }
    Some(v)
}

/// The text of `line` after its word `word` (a slice of it).
fn after<'a>(line: &'a str, word: &str) -> &'a str {
    let end = word.as_ptr() as usize - line.as_ptr() as usize + word.len();
    line.get(end..).unwrap_or("")
}

fn parse_chunk(text: &str) -> Chunk {
    let mut ch = Chunk::default();
    let mut face = Vec::new();
    for (i, line) in text.lines().enumerate() {
        ch.lines = i + 1;
        if let Err(message) = parse_line(line, &mut ch, &mut face) {
            ch.error = Some(SyntaxError { line: i + 1, message });
            return ch;
        }
    }
    ch
}

fn floats<const N: usize>(words: &mut Words, what: &str) -> Result<[f32; N], String> {
    let mut out = [0f32; N];
    for o in out.iter_mut() {
        let w = words.next().ok_or_else(|| format!("{what}: expected {N} numbers"))?;
        *o = w.parse::<f32>().map_err(|_| format!("{what}: {w:?} is not a number"))?;
    }
    Ok(out)
}

fn parse_line(line: &str, ch: &mut Chunk, face: &mut Vec<[u32; 3]>) -> Result<(), String> {
    let mut words = Words::new(line);
    let Some(keyword) = words.next() else { return Ok(()) };
    let rest = || after(line, keyword);
    match keyword {
        "v" => {
            let mut p = floats::<3>(&mut words, "vertex")?;
            let mut extra = [""; 4];
            let mut n = 0;
            for w in words.by_ref().take(4) {
                extra[n] = w;
                n += 1;
            }
            match n {
                0 => {}
                1 => {
                    let w = extra[0].parse::<f32>().map_err(|_| format!("vertex: weight {:?} is not a number", extra[0]))?;
                    if w == 0.0 {
                        return Err("vertex: weight 0".into());
                    }
                    for c in &mut p {
                        *c /= w;
                    }
                }
                3 => {
                    let mut c = [0f32; 3];
                    for (o, w) in c.iter_mut().zip(&extra[..3]) {
                        *o = w.parse::<f32>().map_err(|_| format!("vertex colour: {w:?} is not a number"))?;
                    }
                    ch.colors.push(c);
                }
                n => return Err(format!("vertex: {} numbers (3, 4 with a weight or 6 with a colour)", 3 + n)),
            }
            ch.positions.push(p);
        }
        "vt" => ch.texcoords.push(floats::<2>(&mut words, "texture coordinate")?),
        "vn" => ch.normals.push(floats::<3>(&mut words, "normal")?),
        "f" => {
            face.clear();
            let at = ch.counts();
            let mut relative = Vec::new();
            for w in words {
                let mut idx = [MISSING; 3];
                for (k, part) in w.as_bytes().split(|&b| b == b'/').enumerate() {
                    if part.is_empty() {
                        continue;
                    }
                    if k > 2 {
                        return Err(format!("face corner {w:?} has more than three indices"));
                    }
                    let x = parse_index(part).ok_or_else(|| format!("face corner {w:?}: {:?} is not an index", String::from_utf8_lossy(part)))?;
                    if x > 0 {
                        idx[k] = u32::try_from(x - 1).ok().filter(|&v| v != MISSING).ok_or_else(|| format!("face corner {w:?}: index {x} is too large"))?;
                    } else if x < 0 {
                        let n = [at.v, at.vt, at.vn][k] as i64;
                        relative.push((face.len(), k, n + x));
                    } else {
                        return Err(format!("face corner {w:?}: index 0 (indices start at 1)"));
                    }
                }
                if idx[0] == MISSING && !relative.iter().any(|r| r.0 == face.len() && r.1 == 0) {
                    return Err(format!("face corner {w:?} has no vertex index"));
                }
                face.push(idx);
            }
            // Points and lines written as faces are not surfaces.
            if face.len() >= 3 {
                let base = ch.corners.len();
                for (c, k, local) in relative {
                    ch.relative.push(Relative { corner: base + c, component: k, local, line: ch.lines });
                }
                ch.corners.extend_from_slice(face);
                ch.arities.push(face.len() as u32);
            }
        }
        "o" | "g" => ch.events.push((ch.arities.len(), ch.corners.len(), ch.counts(), Event::Object(rest().trim().to_owned()))),
        // Without a name (Rhino writes such lines) they say nothing.
        "usemtl" | "mtllib" if rest().trim().is_empty() => {}
        "usemtl" => ch.events.push((ch.arities.len(), ch.corners.len(), ch.counts(), Event::UseMtl(rest().trim().to_owned()))),
        "mtllib" => ch.events.push((ch.arities.len(), ch.corners.len(), ch.counts(), Event::MtlLib(rest().trim().to_owned()))),
        _ => {}
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use sct_format::rng::SplitMix64;

    fn pick<'a>(r: &mut SplitMix64, xs: &[&'a str]) -> &'a str {
        xs[(r.next_u64() % xs.len() as u64) as usize]
    }

    /// A random OBJ text of valid statements (relative indices stay within what was read)
    /// and noise: comments, blank lines, odd spacing, non-ASCII names and spaces.
    fn random_obj(r: &mut SplitMix64) -> String {
        let mut s = String::new();
        let (mut v, mut vt, mut vn) = (0i64, 0i64, 0i64);
        for _ in 0..(20 + r.next_u64() % 200) {
            match r.next_u64() % 12 {
                0..=2 => {
                    v += 1;
                    let colour = if r.next_u64() % 4 == 0 { " 0.5 0.25 1" } else { "" };
                    s += &format!("v {} {}\t{}{colour}\n", r.next_f64() - 0.5, r.next_f64() * 3.0, -r.next_f64());
                }
                3 => {
                    vt += 1;
                    s += &format!("vt {} {}\n", r.next_f64(), r.next_f64());
                }
                4 => {
                    vn += 1;
                    s += &format!("  vn {} {} {}\n", r.next_f64(), r.next_f64(), r.next_f64());
                }
                5..=8 if v > 0 => {
                    let n = 1 + r.next_u64() % 6;
                    s += "f";
                    for _ in 0..n {
                        let idx = |r: &mut SplitMix64, count: i64| {
                            let k = 1 + (r.next_u64() % count as u64) as i64;
                            if r.next_u64() % 3 == 0 { -(count - k + 1) } else { k }
                        };
                        let p = idx(r, v);
                        match (vt > 0 && r.next_u64() % 2 == 0, vn > 0 && r.next_u64() % 2 == 0) {
                            (true, true) => s += &format!(" {p}/{}/{}", idx(r, vt), idx(r, vn)),
                            (true, false) => s += &format!(" {p}/{}", idx(r, vt)),
                            (false, true) => s += &format!(" {p}//{}", idx(r, vn)),
                            (false, false) => s += &format!(" {p}"),
                        }
                    }
                    s += if r.next_u64() % 5 == 0 { "\r\n" } else { "\n" };
                }
                9 => s += &format!("{} {}\n", pick(r, &["o", "g"]), pick(r, &["", "part", "named part", "ünïcode", "a\u{a0}b"])),
                10 => s += &format!("usemtl {}\n", pick(r, &["red", "green", "blue"])),
                _ => s += pick(r, &["# comment\n", "\n", "s off\n", "l 1 2\n", "vp 0.5\n", "\u{3000}\n"]),
            }
        }
        s
    }

    /// Materials "red" and "green" defined by any `mtllib`.
    fn library(_: &str) -> Vec<String> {
        vec!["red".into(), "green".into()]
    }

    #[test]
    fn chunks_put_back_together_give_the_one_chunk_parse() {
        let mut r = SplitMix64(7);
        for _ in 0..300 {
            let mut text = String::from("mtllib m.mtl\n");
            text += &random_obj(&mut r);
            let whole = parse_in_chunks(&text, usize::MAX, library).expect("valid");
            assert!(whole.corners.iter().all(|c| c[0] != MISSING));
            for chunk in [1, 2, 7, 33, 200] {
                let cut = parse_in_chunks(&text, chunk, library).expect("valid");
                assert_eq!(cut, whole, "chunks of {chunk} bytes:\n{text}");
            }
        }
    }

    #[test]
    fn relative_indices_count_back_from_the_last_element_read() {
        let text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf -3/-1 -2/-1 -1/-1\nv 0 0 1\nf 1 -3 -1\n";
        for chunk in [1, 1000] {
            let p = parse_in_chunks(text, chunk, library).expect("valid");
            assert_eq!(p.corners, vec![[0, 0, MISSING], [1, 0, MISSING], [2, 0, MISSING], [0, MISSING, MISSING], [1, MISSING, MISSING], [3, MISSING, MISSING]]);
            assert_eq!(p.arities, vec![3, 3]);
        }
        let e = parse_in_chunks("v 0 0 0\nf 1 -2 1\n", 1, library).expect_err("before the first vertex");
        assert_eq!(e.line, 2);
    }

    #[test]
    fn models_end_where_tobj_ends_them() {
        let text = "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nusemtl red\nf 1 2 3\nusemtl red\nf 1 2 3\no b\nusemtl green\ng\nf 1 2 3\nvt 0 0\nusemtl nope\n";
        let p = parse(text, library).expect("valid");
        let summary: Vec<(&str, Option<usize>, std::ops::Range<usize>, usize)> = p.models.iter().map(|m| (m.name.as_str(), m.material, m.faces.clone(), m.texcoords)).collect();
        assert_eq!(summary, vec![(UNNAMED, None, 0..1, 0), (UNNAMED, Some(0), 1..3, 0), ("unnamed_object", Some(1), 3..4, 1), ("unnamed_object", None, 4..4, 1)]);
    }

    #[test]
    fn malformed_lines_are_refused_with_their_line() {
        for (text, line) in [
            ("v 1 2\n", 1),
            ("v 0 0 0\nv 1 2 3 4 5\n", 2),
            ("v 0 0 0 0\n", 1),
            ("v 0 0 0\nv 0 0 0\nv 0 0 0\nf 1 2 0\n", 4),
            ("v 0 0 0\n\nf 1 2 x\n", 3),
            ("v 0 0 0\nf 1/1/1/1 1 1\n", 2),
            ("v 0 0 0\nf 99999999999 1 1\n", 2),
            ("vt 0\n", 1),
            ("v 0 0 0 1 x 1\n", 1),
        ] {
            for chunk in [1, 1000] {
                let e = parse_in_chunks(text, chunk, library).expect_err(text);
                assert_eq!(e.line, line, "{text:?}: {}", e.message);
            }
        }
        // A trailing slash and a weight are accepted, as tobj accepts them.
        let p = parse("v 2 4 6 2\nv 0 0 0\nv 0 1 0\nf 1/ 2/ 3/\n", library).expect("valid");
        assert_eq!(p.positions[0], [1.0, 2.0, 3.0]);
    }

    /// Lines of random tokens (indices past the ends, zeros, signs, huge numbers, stray
    /// slashes, non-ASCII) never panic: every text parses or is refused with a line.
    #[test]
    fn random_statements_parse_or_are_refused() {
        let mut r = SplitMix64(17);
        let tokens = ["v", "vt", "vn", "f", "o", "g", "usemtl", "mtllib", "1", "-1", "0", "3/", "/2", "1//1", "2/3/4/5", "-99", "+4", "1e40", "nan", "inf", "-9223372036854775808", "4294967296", "é", "\u{a0}", " ", "\t", "/"];
        for _ in 0..3_000 {
            let text: String = (0..r.next_u64() % 40)
                .map(|_| {
                    let mut line: String = (0..r.next_u64() % 8).map(|_| format!("{} ", pick(&mut r, &tokens))).collect();
                    line.push('\n');
                    line
                })
                .collect();
            let whole = parse_in_chunks(&text, usize::MAX, library);
            let cut = parse_in_chunks(&text, 5, library);
            match (whole, cut) {
                // Debug text: a NaN coordinate is equal to itself there.
                (Ok(a), Ok(b)) => assert_eq!(format!("{a:?}"), format!("{b:?}"), "{text:?}"),
                (Err(a), Err(b)) => assert_eq!((a.line, a.message), (b.line, b.message), "{text:?}"),
                (a, b) => panic!("{text:?}: {:?} / {:?}", a.map(|_| ()), b.map(|_| ())),
            }
        }
    }

    #[test]
    fn words_split_as_split_whitespace_does() {
        let mut r = SplitMix64(11);
        let parts = ["v", "1.5", "-2", "", " ", "\t", "\u{b}", "\u{c}", "\r", "\u{a0}", "\u{3000}", "é", "x/y"];
        for _ in 0..20_000 {
            let line: String = (0..r.next_u64() % 9).map(|_| pick(&mut r, &parts)).collect();
            assert_eq!(Words::new(&line).collect::<Vec<_>>(), line.split_whitespace().collect::<Vec<_>>(), "{line:?}");
        }
    }

    #[test]
    fn index_parse_matches_std() {
        let mut r = SplitMix64(13);
        let cases = ["0", "-0", "+5", "-", "+", "", "12a", "9223372036854775807", "9223372036854775808", "-9223372036854775808", "-9223372036854775809", "007", "--1"];
        for c in cases {
            assert_eq!(parse_index(c.as_bytes()), c.parse::<i64>().ok(), "{c:?}");
        }
        for _ in 0..20_000 {
            let s: String = (0..r.next_u64() % 22).map(|_| pick(&mut r, &["0", "1", "5", "9", "-", "+", "a"])).collect();
            assert_eq!(parse_index(s.as_bytes()), s.parse::<i64>().ok(), "{s:?}");
        }
    }
}
