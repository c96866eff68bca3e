//! QSplat vertex patches (§5.2.1): one sample per used vertex.

use sct_format::Node;

use crate::mesh::*;

use super::shade::{shade, srgb8, Mat, Tri};

/// QSplat vertex patches (§5.2.1): a sphere at every used vertex, radius = the longest
/// incident edge (so the spheres of a triangle's corners contain it), area = a third of the
/// incident triangles' areas.
pub(super) fn vertex_patches(
    prim: &Primitive,
    pos: &[[f64; 3]],
    nrm: &Option<Vec<[f32; 3]>>,
    computed: Option<&[[[f32; 3]; 3]]>,
    mat: &Mat,
    h: f64,
) -> (Vec<Node>, u64) {
    let nv = pos.len();
    let mut radius = vec![0.0f64; nv];
    let mut area = vec![0.0f64; nv];
    let mut nacc = vec![[0.0f64; 3]; nv];
    // Area-weighted face normals around each vertex: the side a file's normal must face.
    let mut front = vec![[0.0f64; 3]; nv];
    let mut used = vec![false; nv];
    for (ti, t) in prim.triangles.iter().enumerate() {
        let v = t.map(|i| i as usize);
        let fnrm = cross(sub(pos[v[1]], pos[v[0]]), sub(pos[v[2]], pos[v[0]]));
        let fa = 0.5 * norm(fnrm);
        for e in 0..3 {
            for k in 0..3 {
                front[v[e]][k] += fnrm[k];
            }
            let (i, j) = (v[e], v[(e + 1) % 3]);
            let l = norm(sub(pos[i], pos[j]));
            radius[i] = radius[i].max(l);
            radius[j] = radius[j].max(l);
            area[v[e]] += fa / 3.0;
            used[v[e]] = true;
            if let Some(c) = computed {
                for k in 0..3 {
                    nacc[v[e]][k] += fa * f64::from(c[ti][e][k]);
                }
            }
        }
    }
    let uvset = mat.tex.and_then(|t| prim.uvs.get(t.tr.tex_coord as usize));
    let uvset2 = mat.alpha_tex.and_then(|t| prim.uvs.get(t.tr.tex_coord as usize));
    let mut out = Vec::new();
    let mut dropped = 0;
    for i in 0..nv {
        if !used[i] {
            continue;
        }
        let n = match nrm {
            // Turned to the winding's front, as the other samplers do (`prepare::front_facing`).
            Some(n) if (0..3).map(|k| f64::from(n[i][k]) * front[i][k]).sum::<f64>() < 0.0 => n[i].map(|x| -x),
            Some(n) => n[i],
            None => nacc[i].map(|x| x as f32),
        };
        let t = Tri {
            p: [pos[i]; 3],
            n: [n; 3],
            c: [prim.colors.as_ref().map_or([1.0; 4], |c| c[i]); 3],
            uv: [uvset.map_or([0.0; 2], |s| s[i]); 3],
            uv2: [uvset2.map_or([0.0; 2], |s| s[i]); 3],
        };
        let (c, n) = shade(&t, [1.0, 0.0, 0.0], mat);
        let Some(c) = c else {
            dropped += 1;
            continue;
        };
        let l = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        let n = if l > 0.0 { n.map(|x| x / l) } else { [0.0, 0.0, 1.0] };
        out.push(Node {
            center: pos[i].map(|x| (x * h) as f32),
            radius: (radius[i] * h) as f32,
            normal: n,
            cone: 0.0,
            area: (area[i] * h * h) as f32,
            color: srgb8(c),
        });
    }
    (out, dropped)
}
