//! Corner normals for primitives without normals: area-weighted face normals averaged over
//! the faces that share a corner's position, within a crease angle.

use super::{cross, dot, norm, sub, Primitive};

/// Faces sharing one position above which [`corner_normals`] sums them by distinct normal
/// (ordinary meshes stay far below: a UV sphere's pole has one face per segment).
const SHARED_POSITION_FACES: usize = 256;

/// Per-corner normals for a primitive without normals: area-weighted face normals averaged
/// over the faces that share the corner's *position* (welded, so split UV seams stay
/// smooth) and whose normal is within `crease_deg` of this face's (thesis §5.2.2:
/// "mean vertex surface normals ... with thresholding for discontinuities").
pub fn corner_normals(p: &Primitive, crease_deg: f32) -> Vec<[[f32; 3]; 3]> {
    use rayon::prelude::*;
    // Each face's normal (length = 2 × area: area weighting for free) with its length beside
    // it: the corner loop below reads both for every neighbour, from one cache line (two
    // arrays cost a second miss per neighbour on a mesh too large for the cache).
    let face: Vec<[f64; 4]> = p
        .triangles
        .par_iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| p.positions[i as usize].map(f64::from));
            let f = cross(sub(b, a), sub(c, a));
            [f[0], f[1], f[2], norm(f)]
        })
        .collect();
    // Vertices at bit-identical positions share a class (sorting, not hashing: no SipHash per
    // corner). Out-of-range indices get no class and no neighbours.
    let nv = p.positions.len();
    let mut order: Vec<u32> = (0..nv as u32).collect();
    order.par_sort_unstable_by_key(|&i| p.positions[i as usize].map(f32::to_bits));
    let mut class_of = vec![0u32; nv];
    let mut classes = 0u32;
    for (k, &i) in order.iter().enumerate() {
        let bits = |j: u32| p.positions[j as usize].map(f32::to_bits);
        if k > 0 && bits(order[k - 1]) != bits(i) {
            classes += 1;
        }
        class_of[i as usize] = classes;
    }
    let classes = if nv == 0 { 0 } else { classes as usize + 1 };
    // Triangles around each class, in triangle then corner order (a triangle listed once per
    // corner at that position), as compressed rows.
    let class = |i: u32| class_of.get(i as usize).map(|&c| c as usize);
    let mut first = vec![0u32; classes + 1];
    for t in &p.triangles {
        for &i in t {
            if let Some(c) = class(i) {
                first[c + 1] += 1;
            }
        }
    }
    for c in 0..classes {
        first[c + 1] += first[c];
    }
    let mut fill = first.clone();
    let mut around = vec![0u32; first[classes] as usize];
    for (ti, t) in p.triangles.iter().enumerate() {
        for &i in t {
            if let Some(c) = class(i) {
                around[fill[c] as usize] = ti as u32;
                fill[c] += 1;
            }
        }
    }
    let cos_crease = f64::from(crease_deg.to_radians().cos());
    // A corner's sum scans every face around its position, so a position shared by very
    // many faces costs their number squared: 76,000 copies of one triangle (a 1 MB PLY)
    // took 62 s here. Faces with bit-identical normals pass or fail the crease test
    // together, so around such a position they are summed once per distinct normal, times
    // their count: the same faces, in another order. (Distinct normals around one position
    // are bounded by the file's size: a fan of 40,000 takes a few seconds.)
    let grouped: std::collections::HashMap<usize, Vec<([f64; 3], f64, f64)>> = (0..classes)
        .filter(|&c| (first[c + 1] - first[c]) as usize > SHARED_POSITION_FACES)
        .map(|c| {
            let mut g: std::collections::BTreeMap<[u64; 3], ([f64; 3], f64, f64)> = Default::default();
            for &o in &around[first[c] as usize..first[c + 1] as usize] {
                let [x, y, z, lo] = face[o as usize];
                let no = [x, y, z];
                g.entry(no.map(f64::to_bits)).or_insert((no, lo, 0.0)).2 += 1.0;
            }
            (c, g.into_values().collect())
        })
        .collect();
    p.triangles
        .par_iter()
        .enumerate()
        .map(|(ti, t)| {
            let [nf @ .., lf] = face[ti];
            let nf: [f64; 3] = nf;
            t.map(|i| {
                let mut acc = [0.0; 3];
                if let Some(groups) = class(i).and_then(|c| grouped.get(&c)) {
                    for &(no, lo, k) in groups {
                        // Its own face's group always counts, as below.
                        if no.map(f64::to_bits) == nf.map(f64::to_bits) || dot(nf, no) >= cos_crease * lf * lo {
                            acc = [acc[0] + k * no[0], acc[1] + k * no[1], acc[2] + k * no[2]];
                        }
                    }
                } else if let Some(c) = class(i) {
                    for &o in &around[first[c] as usize..first[c + 1] as usize] {
                        let [no @ .., lo] = face[o as usize];
                        let no: [f64; 3] = no;
                        if o as usize == ti || dot(nf, no) >= cos_crease * lf * lo {
                            acc = [acc[0] + no[0], acc[1] + no[1], acc[2] + no[2]];
                        }
                    }
                }
                let l = norm(acc);
                if l > 0.0 {
                    acc.map(|v| (v / l) as f32)
                } else if lf > 0.0 {
                    nf.map(|v| (v / lf) as f32)
                } else {
                    [0.0, 0.0, 1.0]
                }
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The class-and-rows corner normals equal the straightforward hash-map version bit for
    /// bit (same neighbours, same summation order), with duplicated vertices at one position,
    /// a triangle with two corners at one position, and a crease.
    #[test]
    fn corner_normals_match_hash_map_reference() {
        fn reference(p: &Primitive, crease_deg: f32) -> Vec<[[f32; 3]; 3]> {
            use std::collections::HashMap;
            let face: Vec<[f64; 3]> = p
                .triangles
                .iter()
                .map(|t| {
                    let [a, b, c] = t.map(|i| p.positions[i as usize].map(f64::from));
                    cross(sub(b, a), sub(c, a))
                })
                .collect();
            let mut by_pos: HashMap<[u32; 3], Vec<u32>> = HashMap::new();
            for (ti, t) in p.triangles.iter().enumerate() {
                for &i in t {
                    by_pos.entry(p.positions[i as usize].map(f32::to_bits)).or_default().push(ti as u32);
                }
            }
            let cos_crease = f64::from(crease_deg.to_radians().cos());
            p.triangles
                .iter()
                .enumerate()
                .map(|(ti, t)| {
                    let (nf, lf) = (face[ti], norm(face[ti]));
                    t.map(|i| {
                        let mut acc = [0.0; 3];
                        for &o in &by_pos[&p.positions[i as usize].map(f32::to_bits)] {
                            let no = face[o as usize];
                            if o as usize == ti || dot(nf, no) >= cos_crease * lf * norm(no) {
                                acc = [acc[0] + no[0], acc[1] + no[1], acc[2] + no[2]];
                            }
                        }
                        let l = norm(acc);
                        if l > 0.0 {
                            acc.map(|v| (v / l) as f32)
                        } else if lf > 0.0 {
                            nf.map(|v| (v / lf) as f32)
                        } else {
                            [0.0, 0.0, 1.0]
                        }
                    })
                })
                .collect()
        }
        // A bumpy grid whose vertices are duplicated per triangle (as OBJ splits by UV), plus
        // a fold (crease) and a triangle with two corners at one position.
        let n = 12u32;
        let h = |x: u32, y: u32| ((x * 7 + y * 13) % 5) as f32 * 0.05 + if x > n / 2 { (x - n / 2) as f32 * 0.6 } else { 0.0 };
        let mut positions = Vec::new();
        let mut triangles = Vec::new();
        for y in 0..n {
            for x in 0..n {
                for [a, b, c] in [[(x, y), (x + 1, y), (x + 1, y + 1)], [(x, y), (x + 1, y + 1), (x, y + 1)]] {
                    let base = positions.len() as u32;
                    for (px, py) in [a, b, c] {
                        positions.push([px as f32 * 0.3, py as f32 * 0.3, h(px, py)]);
                    }
                    triangles.push([base, base + 1, base + 2]);
                }
            }
        }
        let base = positions.len() as u32;
        positions.extend([[0.0, 0.0, h(0, 0)], [0.0, 0.0, h(0, 0)], [0.3, 0.0, h(1, 0)]]);
        triangles.push([base, base + 1, base + 2]);
        let p = Primitive { positions, triangles, ..Default::default() };
        for crease in [0.0, 30.0, 60.0, 180.0] {
            let (got, want) = (corner_normals(&p, crease), reference(&p, crease));
            assert_eq!(got.len(), want.len());
            for (g, w) in got.iter().zip(&want) {
                assert_eq!(g.map(|n| n.map(f32::to_bits)), w.map(|n| n.map(f32::to_bits)), "crease {crease}");
            }
        }
    }

    /// Positions shared by very many faces: 50,000 copies of one triangle (quadratic before:
    /// about 20 s) take milliseconds and keep their normal; around a cone's apex of 400
    /// faces (distinct normals, summed by group) the normals are those of the plain sum.
    #[test]
    fn corner_normals_of_shared_positions_are_linear() {
        let stacked = Primitive { positions: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], triangles: vec![[0, 1, 2]; 50_000], ..Default::default() };
        let t = std::time::Instant::now();
        assert!(corner_normals(&stacked, 60.0).iter().flatten().all(|n| *n == [0.0, 0.0, 1.0]));
        assert!(t.elapsed().as_secs() < 5, "{:?}", t.elapsed());

        let k = 400u32;
        let mut positions = vec![[0.0f32, 0.0, 1.0]];
        positions.extend((0..k).map(|i| {
            let a = i as f32 / k as f32 * std::f32::consts::TAU;
            [a.cos(), a.sin(), 0.0]
        }));
        let triangles: Vec<[u32; 3]> = (0..k).map(|i| [0, 1 + i, 1 + (i + 1) % k]).collect();
        let cone = Primitive { positions, triangles, ..Default::default() };
        for crease in [10.0f32, 60.0, 180.0] {
            let got = corner_normals(&cone, crease);
            let face: Vec<[f64; 3]> = cone
                .triangles
                .iter()
                .map(|t| {
                    let [a, b, c] = t.map(|i| cone.positions[i as usize].map(f64::from));
                    cross(sub(b, a), sub(c, a))
                })
                .collect();
            let cos = f64::from(crease.to_radians().cos());
            for (ti, g) in got.iter().enumerate() {
                let nf = face[ti];
                let acc = face.iter().filter(|&&no| no == nf || dot(nf, no) >= cos * norm(nf) * norm(no)).fold([0.0; 3], |a, no| [a[0] + no[0], a[1] + no[1], a[2] + no[2]]);
                let want = acc.map(|v| (v / norm(acc)) as f32);
                assert!((0..3).all(|j| (g[0][j] - want[j]).abs() < 1e-5), "crease {crease} face {ti}: {:?} {want:?}", g[0]);
            }
        }
    }
}
