//! The parallel reader of the common binary PLY layout: a vertex element of fixed-size
//! records followed by a face element whose records are fixed-size too, because every face
//! is a triangle (its list count is 3 throughout). Fixed-size records decode independently,
//! so the body is cut into chunks decoded on every thread, and the result is the general
//! reader's value for value (the same conversions, in the same order).
//!
//! Anything else gives `None` and the general reader reads the file: other elements, a list
//! among the vertex properties or a second one among the face properties, per-corner
//! texcoords, a face that is not a triangle, an index out of range, a non-finite position,
//! too few bytes. Faults are thus reported by one reader, with its element, index and place.

use std::sync::atomic::{AtomicBool, Ordering};

use rayon::prelude::*;

use super::{binary_scalar, Elem, Payload, Prop, Ty, VertexLayout, SLOTS, X};

/// The body of a binary file of elements `elems` (`nverts` vertices) decoded in parallel, or
/// `None` when it is not of the common layout or has a fault.
pub(super) fn read(body: &[u8], big: bool, elems: &[Elem], nverts: usize) -> Option<Payload> {
    let [ve, fe] = elems else { return None };
    if ve.name != "vertex" || fe.name != "face" || ve.count != nverts {
        return None;
    }
    let lay = VertexLayout::new(ve);
    if !(lay.has(X) && lay.has(X + 1) && lay.has(X + 2)) {
        return None;
    }
    // Vertex record: every property a scalar; the slots read and where their bytes are.
    let mut fields: Vec<(usize, usize, Ty)> = Vec::new();
    let mut vrec = 0usize;
    for (pi, (_, p)) in ve.props.iter().enumerate() {
        let Prop::Scalar(t) = *p else { return None };
        if let Some(k) = lay.slot[pi] {
            fields.push((k, vrec, t));
        }
        vrec += t.size();
    }
    // Face record: the index list (integer items, three of them) among scalars.
    let (ipi, ict, ity) = match fe.property(&["vertex_indices", "vertex_index"]) {
        Some((i, Prop::List(c, t))) if t.is_int() => (i, c, t),
        _ => return None,
    };
    let (mut count_at, mut frec) = (0usize, 0usize);
    for (pi, (_, p)) in fe.props.iter().enumerate() {
        match *p {
            Prop::Scalar(t) => frec += t.size(),
            Prop::List(c, t) if pi == ipi => {
                count_at = frec;
                frec += c.size() + 3 * t.size();
            }
            Prop::List(..) => return None,
        }
    }
    let vbytes = nverts.checked_mul(vrec)?;
    let fbytes = fe.count.checked_mul(frec)?;
    if vbytes.checked_add(fbytes)? > body.len() {
        return None;
    }
    let (vdata, rest) = body.split_at(vbytes);
    let fdata = &rest[..fbytes];

    let slots = |r: &[u8]| {
        let mut v = [0.0f64; SLOTS];
        for &(k, at, t) in &fields {
            v[k] = binary_scalar(&r[at..at + t.size()], t, big);
        }
        v
    };
    let has = lay.attributes();
    // Indexed collections write in place (collecting `Option`s would gather pieces and copy
    // them); a fault is flagged and the result dropped.
    let fault = AtomicBool::new(false);
    let flag = |ok: bool| {
        if !ok {
            fault.store(true, Ordering::Relaxed);
        }
    };
    let mut positions: Vec<[f32; 3]> = Vec::new();
    vdata
        .par_chunks_exact(vrec)
        .map(|r| {
            let p = VertexLayout::position(&slots(r));
            flag(p.is_some());
            p.unwrap_or_default()
        })
        .collect_into_vec(&mut positions);
    let normals = has.normals.then(|| vdata.par_chunks_exact(vrec).map(|r| VertexLayout::normal(&slots(r))).collect());
    let colors = has.colors.then(|| vdata.par_chunks_exact(vrec).map(|r| lay.color(&slots(r), has.alpha)).collect());
    let uvs = has.uvs.then(|| vdata.par_chunks_exact(vrec).map(|r| VertexLayout::uv(&slots(r))).collect());

    let (csize, isz) = (ict.size(), ity.size());
    let first = count_at + csize;
    let n = nverts as f64;
    let mut triangles: Vec<[u32; 3]> = Vec::new();
    fdata
        .par_chunks_exact(frec)
        .map(|r| {
            let mut ok = binary_scalar(&r[count_at..first], ict, big) == 3.0;
            let mut t = [0u32; 3];
            for (k, v) in t.iter_mut().enumerate() {
                let at = first + k * isz;
                let i = binary_scalar(&r[at..at + isz], ity, big);
                // An integer type (checked above), so `i` is an exact integer.
                ok &= i >= 0.0 && i < n;
                *v = i as u32;
            }
            flag(ok);
            t
        })
        .collect_into_vec(&mut triangles);
    if fault.into_inner() {
        return None;
    }
    Some(Payload { positions, normals, colors, uvs, triangles, ..Payload::default() })
}

#[cfg(test)]
mod tests {
    use super::super::{read_body, Elem, LoadOptions, Payload};
    use ply_rs_bw::parser::Parser;
    use ply_rs_bw::ply::{DefaultElement, Encoding};
    use std::path::Path;

    /// A binary PLY: `n` vertices (double x y z, float normals, uchar colours and alpha,
    /// float u v, one property read by nobody), then faces (a uchar flag before the index
    /// list and a float after it), all triangles unless `corners` says otherwise.
    fn file(big: bool, n: u32, corners: &dyn Fn(u32) -> u32, index: &dyn Fn(u32, u32) -> i32) -> Vec<u8> {
        let enc = if big { "binary_big_endian" } else { "binary_little_endian" };
        let faces = n - 2;
        let mut b = format!(
            "ply\nformat {enc} 1.0\nelement vertex {n}\nproperty double x\nproperty double y\nproperty double z\n\
             property float nx\nproperty float ny\nproperty float nz\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n\
             property uchar alpha\nproperty short extra\nproperty float u\nproperty float v\n\
             element face {faces}\nproperty uchar flags\nproperty list uchar int vertex_indices\nproperty float quality\nend_header\n"
        )
        .into_bytes();
        let put = |b: &mut Vec<u8>, mut bytes: Vec<u8>| {
            if big {
                bytes.reverse();
            }
            b.extend_from_slice(&bytes);
        };
        for i in 0..n {
            let t = f64::from(i);
            for c in [t.sin(), t.cos() * 2.0, 0.1 * t] {
                put(&mut b, c.to_le_bytes().to_vec());
            }
            for c in [0.0f32, -1.0, 0.5] {
                put(&mut b, c.to_le_bytes().to_vec());
            }
            b.extend_from_slice(&[(i * 7) as u8, (i * 13) as u8, 200, (i * 3) as u8]);
            put(&mut b, (i as i16).wrapping_neg().to_le_bytes().to_vec());
            put(&mut b, (0.01 * i as f32).to_le_bytes().to_vec());
            put(&mut b, (0.5f32).to_le_bytes().to_vec());
        }
        for f in 0..faces {
            b.push(f as u8);
            let k = corners(f);
            b.push(k as u8);
            for c in 0..k {
                put(&mut b, index(f, c).to_le_bytes().to_vec());
            }
            put(&mut b, (f as f32).to_le_bytes().to_vec());
        }
        b
    }

    fn triangles(n: u32) -> Vec<u8> {
        file(false, n, &|_| 3, &|f, c| (f + c) as i32)
    }

    /// The body of `bytes` by the parallel reader and by the general one.
    fn both(bytes: &[u8]) -> (Option<Payload>, Payload) {
        let mut cur = std::io::Cursor::new(bytes);
        let header = Parser::<DefaultElement>::new().read_header(&mut cur).expect("header");
        let start = cur.position() as usize;
        let elems = Elem::all(&header);
        let big = header.encoding == Encoding::BinaryBigEndian;
        let nverts = elems[0].count;
        let fast = super::read(&bytes[start..], big, &elems, nverts);
        let general = read_body(Path::new("t.ply"), bytes, start, true, big, &elems, nverts, &LoadOptions::default()).expect("general reader");
        (fast, general)
    }

    /// Both byte orders, every vertex attribute, scalars around the index list and in the
    /// vertex records, over many parallel chunks: the parallel reader gives the general
    /// reader's values, bit for bit.
    #[test]
    fn parallel_reader_equals_the_general_reader() {
        for big in [false, true] {
            let bytes = file(big, 20_000, &|_| 3, &|f, c| ((f * 7919 + c * 104_729) % 20_000) as i32);
            let (fast, general) = both(&bytes);
            let fast = fast.expect("the common layout is read in parallel");
            let tris: Vec<[u32; 3]> = general.face_idx.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
            assert!(general.face_len.iter().all(|&l| l == 3) && general.triangles.is_empty());
            assert_eq!(fast.triangles, tris);
            let bits2 = |v: &[[f32; 2]]| v.iter().map(|p| p.map(f32::to_bits)).collect::<Vec<_>>();
            let bits3 = |v: &[[f32; 3]]| v.iter().map(|p| p.map(f32::to_bits)).collect::<Vec<_>>();
            let bits4 = |v: &[[f32; 4]]| v.iter().map(|p| p.map(f32::to_bits)).collect::<Vec<_>>();
            assert_eq!(bits3(&fast.positions), bits3(&general.positions));
            assert_eq!(fast.normals.as_deref().map(bits3), general.normals.as_deref().map(bits3));
            assert_eq!(fast.colors.as_deref().map(bits4), general.colors.as_deref().map(bits4));
            assert_eq!(fast.uvs.as_deref().map(bits2), general.uvs.as_deref().map(bits2));
            assert!(fast.normals.is_some() && fast.colors.is_some() && fast.uvs.is_some());
        }
    }

    /// What the parallel reader does not take, the general reader reads (or refuses, naming
    /// the fault): a quad, an index out of range or negative, a non-finite position, a file
    /// cut short, another element.
    #[test]
    fn other_layouts_and_faults_go_to_the_general_reader() {
        assert!(both(&triangles(50)).0.is_some());
        let quad = file(false, 50, &|f| if f == 17 { 4 } else { 3 }, &|f, c| (f + c) as i32);
        let (fast, general) = both(&quad);
        assert!(fast.is_none());
        assert_eq!(general.face_len.iter().filter(|&&l| l == 4).count(), 1);

        let cases: [(&str, Vec<u8>); 4] = [
            ("index out of range", file(false, 50, &|_| 3, &|f, c| if f == 30 { 50 } else { (f + c) as i32 })),
            ("negative index", file(false, 50, &|_| 3, &|f, c| if f == 3 && c == 2 { -1 } else { (f + c) as i32 })),
            ("non-finite position", {
                let mut b = triangles(50);
                let at = b.windows(11).position(|w| w == b"end_header\n").expect("header end") + 11 + 5 * 50;
                b[at..at + 8].copy_from_slice(&f64::NAN.to_le_bytes());
                b
            }),
            ("cut short", {
                let b = triangles(50);
                b[..b.len() - 1].to_vec()
            }),
        ];
        for (what, bytes) in cases {
            let mut cur = std::io::Cursor::new(&bytes[..]);
            let header = Parser::<DefaultElement>::new().read_header(&mut cur).expect("header");
            let start = cur.position() as usize;
            let elems = Elem::all(&header);
            assert!(super::read(&bytes[start..], false, &elems, elems[0].count).is_none(), "{what}");
            let e = super::super::load(Path::new("t.ply"), &bytes, &LoadOptions::default()).expect_err(what);
            assert!(!e.to_string().is_empty());
        }

        let mut extra = triangles(50);
        let at = extra.windows(10).position(|w| w == b"end_header").expect("header end");
        extra.splice(at..at, b"element blob 0\nproperty uchar b\n".iter().copied());
        let mut cur = std::io::Cursor::new(&extra[..]);
        let header = Parser::<DefaultElement>::new().read_header(&mut cur).expect("header");
        let start = cur.position() as usize;
        let elems = Elem::all(&header);
        assert_eq!(elems.len(), 3);
        assert!(super::read(&extra[start..], false, &elems, elems[0].count).is_none());
    }
}
