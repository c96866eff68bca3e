//! Affine instance transforms (spec §7, format 1.3): placements a similarity cannot express
//! (non-uniform scale, shear, mirror), and the world transform a traversal composes, which
//! is a similarity until an affine instance is on the path.
//!
//! What an affine map does to a scene node (spec §7, "affine instance"): the centre is
//! mapped; the radius grows by σ_max, the largest singular value of the linear part A (the
//! most it stretches any length, so the image of the sphere stays inside the new one); the
//! cone axis maps by the inverse transpose and is renormalised; the cone's semi-angle grows
//! to at most κ times itself (κ = σ_max / σ_min, the condition number: no angle between two
//! directions grows by more than κ under a linear map) and is capped at π; the area is
//! multiplied by |det A| · |A⁻ᵀ n| for the unit axis n (Nanson's formula: exact for a flat
//! patch, so for every leaf; for a patch whose normals spread it lies between the bounds
//! σ_min·σ_mid and σ_max·σ_mid of the true factor); colour is unchanged.

use crate::graph::Similarity;
use crate::node::Node;

/// Largest condition number σ_max / σ_min an affine instance may have (spec §7). Beyond it
/// the inverse transpose loses most of its digits in f64 and bounds stop meaning much (a
/// sphere of radius r around a surface squashed to a millionth of it); a writer bakes such
/// placements instead.
pub const MAX_CONDITION: f64 = 1e6;

/// Largest magnitude of an affine instance's matrix entry (spec §7): the largest finite
/// f32. A larger entry cannot map a tree's (f32) nodes to finite f32 world nodes, and below
/// it every product the reader forms (AᵀA, the determinant) is finite in f64.
pub const MAX_ENTRY: f64 = f32::MAX as f64;

/// A general affine map: `world[r] = Σc matrix[r][c]·p[c] + matrix[r][3]`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Affine {
    /// Row-major 3 × 4 matrix: the linear part A in columns 0..3, the translation in column 3.
    pub matrix: [[f64; 4]; 3],
}

/// For messages: `matrix [[a, b, c, d], [e, f, g, h], [i, j, k, l]]`.
impl std::fmt::Display for Affine {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let row = |r: &[f64; 4]| format!("[{}, {}, {}, {}]", r[0], r[1], r[2], r[3]);
        let m = &self.matrix;
        write!(f, "matrix [{}, {}, {}]", row(&m[0]), row(&m[1]), row(&m[2]))
    }
}

fn det3(a: &[[f64; 3]; 3]) -> f64 {
    a[0][0] * (a[1][1] * a[2][2] - a[1][2] * a[2][1]) - a[0][1] * (a[1][0] * a[2][2] - a[1][2] * a[2][0])
        + a[0][2] * (a[1][0] * a[2][1] - a[1][1] * a[2][0])
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

/// The largest singular value of `a`, never below the true one.
fn sigma_max(a: &[[f64; 3]; 3]) -> f64 {
    // Largest eigenvalue of the symmetric AᵀA (closed form for 3 × 3, Smith 1961).
    let s: [[f64; 3]; 3] = std::array::from_fn(|i| std::array::from_fn(|j| (0..3).map(|k| a[k][i] * a[k][j]).sum()));
    let p1 = s[0][1] * s[0][1] + s[0][2] * s[0][2] + s[1][2] * s[1][2];
    let q = (s[0][0] + s[1][1] + s[2][2]) / 3.0;
    let p2 = (s[0][0] - q).powi(2) + (s[1][1] - q).powi(2) + (s[2][2] - q).powi(2) + 2.0 * p1;
    let p = (p2 / 6.0).sqrt();
    let lambda = if p == 0.0 {
        q
    } else {
        let b: [[f64; 3]; 3] = std::array::from_fn(|i| std::array::from_fn(|j| (s[i][j] - if i == j { q } else { 0.0 }) / p));
        let phi = (det3(&b) / 2.0).clamp(-1.0, 1.0).acos() / 3.0;
        q + 2.0 * p * phi.cos()
    };
    // The closed form can land a few ulps low; the Frobenius norm is a hard upper bound.
    let frob = s[0][0] + s[1][1] + s[2][2];
    (lambda * (1.0 + 1e-12)).min(frob).max(0.0).sqrt()
}

impl Affine {
    /// The identity map.
    pub const IDENTITY: Affine = Affine { matrix: [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]] };

    /// The matrix of a similarity.
    pub fn from_similarity(s: &Similarity) -> Affine {
        let cols = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]].map(|e| s.rotate(e));
        Affine { matrix: std::array::from_fn(|r| [cols[0][r] * s.scale, cols[1][r] * s.scale, cols[2][r] * s.scale, s.translation[r]]) }
    }

    /// The linear part A (left 3 × 3).
    pub fn linear(&self) -> [[f64; 3]; 3] {
        std::array::from_fn(|r| [self.matrix[r][0], self.matrix[r][1], self.matrix[r][2]])
    }

    /// Applies the map to a point.
    pub fn apply_point(&self, p: [f64; 3]) -> [f64; 3] {
        let m = &self.matrix;
        std::array::from_fn(|r| m[r][0] * p[0] + m[r][1] * p[1] + m[r][2] * p[2] + m[r][3])
    }

    /// Applies the linear part to a direction.
    pub fn apply_vector(&self, v: [f64; 3]) -> [f64; 3] {
        let m = &self.matrix;
        std::array::from_fn(|r| m[r][0] * v[0] + m[r][1] * v[1] + m[r][2] * v[2])
    }

    /// Determinant of the linear part (negative: the map mirrors).
    pub fn determinant(&self) -> f64 {
        det3(&self.linear())
    }

    /// The largest singular value of the linear part (never below the true one): the most
    /// the map stretches any length.
    pub fn max_stretch(&self) -> f64 {
        sigma_max(&self.linear())
    }

    /// The cofactor matrix det(A)·A⁻ᵀ: maps a surface's normal times its area element
    /// (Nanson's formula), defined for singular A too.
    pub fn cofactor(&self) -> [[f64; 3]; 3] {
        let m = &self.matrix;
        let col = |c: usize| [m[0][c], m[1][c], m[2][c]];
        // Rows of A⁻¹ are (c1×c2, c2×c0, c0×c1)/det, so column i of det·A⁻ᵀ is row i of det·A⁻¹.
        let (r0, r1, r2) = (cross(col(1), col(2)), cross(col(2), col(0)), cross(col(0), col(1)));
        std::array::from_fn(|k| [r0[k], r1[k], r2[k]])
    }

    /// The inverse map, `None` when the linear part is singular (or not finite).
    pub fn inverse(&self) -> Option<Affine> {
        let det = self.determinant();
        if !(det.is_normal()) {
            return None;
        }
        let cof = self.cofactor();
        // A⁻¹ = cofᵀ / det.
        let inv: [[f64; 3]; 3] = std::array::from_fn(|r| std::array::from_fn(|c| cof[c][r] / det));
        let t = [self.matrix[0][3], self.matrix[1][3], self.matrix[2][3]];
        let m = std::array::from_fn(|r| {
            let ti = -(inv[r][0] * t[0] + inv[r][1] * t[1] + inv[r][2] * t[2]);
            [inv[r][0], inv[r][1], inv[r][2], ti]
        });
        let out = Affine { matrix: m };
        out.matrix.iter().flatten().all(|v| v.is_finite()).then_some(out)
    }

    /// The condition number σ_max / σ_min of the linear part, never below the true one
    /// (infinite when it is singular).
    pub fn condition(&self) -> f64 {
        match self.inverse() {
            Some(inv) => self.max_stretch() * inv.max_stretch(),
            None => f64::INFINITY,
        }
    }

    /// `self ∘ inner`: first `inner`, then `self`.
    pub fn compose(&self, inner: &Affine) -> Affine {
        let a = &self.matrix;
        let b = &inner.matrix;
        Affine {
            matrix: std::array::from_fn(|r| {
                std::array::from_fn(|c| {
                    let lin = a[r][0] * b[0][c] + a[r][1] * b[1][c] + a[r][2] * b[2][c];
                    if c == 3 {
                        lin + a[r][3]
                    } else {
                        lin
                    }
                })
            }),
        }
    }

    /// Why the map cannot be an affine instance (spec §7), or `None` when it can: every entry
    /// finite and at most [`MAX_ENTRY`] in magnitude, a determinant that is a normal number
    /// (non-zero, not subnormal), and a condition number at most [`MAX_CONDITION`].
    pub fn problem(&self) -> Option<String> {
        if !self.matrix.iter().flatten().all(|v| v.is_finite()) {
            return Some(format!("affine transform has non-finite entries: {self}"));
        }
        if self.matrix.iter().flatten().any(|v| v.abs() > MAX_ENTRY) {
            return Some(format!("affine transform has an entry beyond the f32 range: {self}"));
        }
        let det = self.determinant();
        if !det.is_normal() {
            return Some(format!("affine transform is singular (determinant {det}): {self}"));
        }
        let k = self.condition();
        if k.is_nan() || k > MAX_CONDITION {
            return Some(format!("affine transform has condition number {k:.3e}, above the limit {MAX_CONDITION:e}: {self}"));
        }
        None
    }

    /// True when [`Self::problem`] finds nothing.
    pub fn is_valid(&self) -> bool {
        self.problem().is_none()
    }

    /// Whether the map is a similarity within `tol` (relative): AᵀA = s²·I and det > 0.
    /// Such a placement MUST be written as a similarity instance (spec §7).
    pub fn similarity(&self, tol: f64) -> Option<Similarity> {
        let a = self.linear();
        let s: [[f64; 3]; 3] = std::array::from_fn(|i| std::array::from_fn(|j| (0..3).map(|k| a[k][i] * a[k][j]).sum()));
        let s2 = (s[0][0] + s[1][1] + s[2][2]) / 3.0;
        if !(s2 > 0.0 && s2.is_finite()) || self.determinant() <= 0.0 {
            return None;
        }
        for (i, row) in s.iter().enumerate() {
            for (j, v) in row.iter().enumerate() {
                let want = if i == j { s2 } else { 0.0 };
                if (v - want).abs() > tol * s2 {
                    return None;
                }
            }
        }
        let scale = s2.sqrt();
        let r: [[f64; 3]; 3] = std::array::from_fn(|i| std::array::from_fn(|j| a[i][j] / scale));
        let q = quaternion_of(&r);
        let t = [self.matrix[0][3], self.matrix[1][3], self.matrix[2][3]];
        let sim = Similarity { translation: t, rotation: q, scale };
        sim.is_valid(1e-6).then_some(sim)
    }
}

/// The unit quaternion (x, y, z, w) of a rotation matrix (Shepperd's method: the largest
/// diagonal term first, for precision).
fn quaternion_of(r: &[[f64; 3]; 3]) -> [f64; 4] {
    let tr = r[0][0] + r[1][1] + r[2][2];
    let q = if tr > 0.0 {
        let s = (tr + 1.0).sqrt() * 2.0;
        [(r[2][1] - r[1][2]) / s, (r[0][2] - r[2][0]) / s, (r[1][0] - r[0][1]) / s, 0.25 * s]
    } else if r[0][0] > r[1][1] && r[0][0] > r[2][2] {
        let s = (1.0 + r[0][0] - r[1][1] - r[2][2]).sqrt() * 2.0;
        [0.25 * s, (r[0][1] + r[1][0]) / s, (r[0][2] + r[2][0]) / s, (r[2][1] - r[1][2]) / s]
    } else if r[1][1] > r[2][2] {
        let s = (1.0 + r[1][1] - r[0][0] - r[2][2]).sqrt() * 2.0;
        [(r[0][1] + r[1][0]) / s, 0.25 * s, (r[1][2] + r[2][1]) / s, (r[0][2] - r[2][0]) / s]
    } else {
        let s = (1.0 + r[2][2] - r[0][0] - r[1][1]).sqrt() * 2.0;
        [(r[0][2] + r[2][0]) / s, (r[1][2] + r[2][1]) / s, 0.25 * s, (r[1][0] - r[0][1]) / s]
    };
    let len = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    q.map(|v| v / len)
}

/// An affine map with what mapping a node needs computed once: σ_max, the condition number
/// and the cofactor matrix.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AffineMap {
    /// The map.
    pub affine: Affine,
    /// [`Affine::max_stretch`].
    pub stretch: f64,
    /// [`Affine::condition`].
    pub condition: f64,
    /// [`Affine::cofactor`]: det(A)·A⁻ᵀ.
    pub cofactor: [[f64; 3]; 3],
}

impl AffineMap {
    /// Precomputes what [`Self::apply_node`] needs.
    pub fn new(affine: Affine) -> AffineMap {
        AffineMap { affine, stretch: affine.max_stretch(), condition: affine.condition(), cofactor: affine.cofactor() }
    }

    /// The unit normal of a surface whose normal was `n` before the map, and the factor by
    /// which the map multiplies that surface's area (|cof(A)·n| / |n|); `None` without a
    /// usable direction.
    pub fn map_normal(&self, n: [f64; 3]) -> Option<([f64; 3], f64)> {
        let c = &self.cofactor;
        let v: [f64; 3] = std::array::from_fn(|r| c[r][0] * n[0] + c[r][1] * n[1] + c[r][2] * n[2]);
        let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        let nlen = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        // cof(A) = det·A⁻ᵀ: its sign flips the normal of a mirroring map, which is wrong:
        // A⁻ᵀ keeps outward normals outward (n·v > 0 ⇒ (A⁻ᵀn)·(Av) > 0), so divide it out.
        let sign = self.affine.determinant().signum();
        (len > 0.0 && len.is_finite() && nlen > 0.0).then(|| (v.map(|x| sign * x / len), len / nlen))
    }

    /// The cone semi-angle that bounds the mapped normals of a cone of semi-angle `cone`
    /// around the mapped axis: κ·cone, at most π (no angle between two directions grows by
    /// more than the condition number κ under a linear map).
    pub fn map_cone(&self, cone: f32) -> f32 {
        if cone <= 0.0 {
            return cone;
        }
        let c = f64::from(cone) * self.condition;
        if c >= std::f64::consts::PI {
            return std::f32::consts::PI;
        }
        let f = c as f32;
        // Rounded up, so the stored cone still bounds the mapped normals.
        if f64::from(f) < c {
            f.next_up().min(std::f32::consts::PI)
        } else {
            f
        }
    }

    /// Maps a node (spec §7, affine instance; see the module docs): centre mapped, radius ×
    /// σ_max rounded up, axis by the inverse transpose, cone × κ (≤ π), area × |det A|·|A⁻ᵀ n|,
    /// colour unchanged.
    pub fn apply_node(&self, n: &Node) -> Node {
        let center = self.affine.apply_point(n.center.map(f64::from));
        // Widened by the centre's own f32 rounding (≤ ε·max|x|) and rounded up, so
        // containment holds in stored precision too.
        let slack = center.iter().fold(0.0f64, |a, x| a.max(x.abs())) * f64::from(f32::EPSILON);
        let r = f64::from(n.radius) * self.stretch + slack;
        let rf = r as f32;
        let (normal, cone, factor) = match self.map_normal(n.normal.map(f64::from)) {
            Some((v, f)) => (v.map(|x| x as f32), self.map_cone(n.cone), f),
            // No axis (a zero normal): nothing is known of the mapped normals, and the mean
            // area factor |det|^(2/3) keeps totals plausible.
            None => (n.normal, std::f32::consts::PI, self.affine.determinant().abs().powf(2.0 / 3.0)),
        };
        Node {
            center: center.map(|x| x as f32),
            radius: if f64::from(rf) < r { rf.next_up() } else { rf },
            normal,
            cone,
            area: (f64::from(n.area) * factor) as f32,
            color: n.color,
        }
    }
}

/// A world transform: a similarity, or an affine map once an affine instance is on the path.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Transform {
    /// `x' = translation + scale · rotate(rotation, x)`.
    Similarity(Similarity),
    /// A general affine map.
    Affine(AffineMap),
}

impl Default for Transform {
    fn default() -> Self {
        Transform::IDENTITY
    }
}

impl From<Similarity> for Transform {
    fn from(s: Similarity) -> Self {
        Transform::Similarity(s)
    }
}

impl From<Affine> for Transform {
    fn from(a: Affine) -> Self {
        Transform::Affine(AffineMap::new(a))
    }
}

/// For messages: the similarity's or the matrix's own text.
impl std::fmt::Display for Transform {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Transform::Similarity(s) => s.fmt(f),
            Transform::Affine(a) => a.affine.fmt(f),
        }
    }
}

impl PartialEq<Similarity> for Transform {
    fn eq(&self, o: &Similarity) -> bool {
        matches!(self, Transform::Similarity(s) if s == o)
    }
}

impl Transform {
    /// The identity.
    pub const IDENTITY: Transform = Transform::Similarity(Similarity::IDENTITY);

    /// `self ∘ inner`: first `inner`, then `self`. Two similarities compose to a similarity.
    pub fn compose(&self, inner: &Transform) -> Transform {
        match (self, inner) {
            (Transform::Similarity(a), Transform::Similarity(b)) => Transform::Similarity(a.compose(b)),
            _ => Transform::Affine(AffineMap::new(self.matrix().compose(&inner.matrix()))),
        }
    }

    /// The transform as a 3 × 4 matrix.
    pub fn matrix(&self) -> Affine {
        match self {
            Transform::Similarity(s) => Affine::from_similarity(s),
            Transform::Affine(a) => a.affine,
        }
    }

    /// The similarity, if it is one.
    pub fn as_similarity(&self) -> Option<&Similarity> {
        match self {
            Transform::Similarity(s) => Some(s),
            Transform::Affine(_) => None,
        }
    }

    /// Applies the transform to a point.
    pub fn apply_point(&self, p: [f64; 3]) -> [f64; 3] {
        match self {
            Transform::Similarity(s) => s.apply_point(p),
            Transform::Affine(a) => a.affine.apply_point(p),
        }
    }

    /// The most the transform stretches any length (the scale of a similarity, σ_max of an
    /// affine map).
    pub fn max_stretch(&self) -> f64 {
        match self {
            Transform::Similarity(s) => s.scale,
            Transform::Affine(a) => a.stretch,
        }
    }

    /// Maps a node: [`Similarity::apply_node`] or [`AffineMap::apply_node`].
    pub fn apply_node(&self, n: &Node) -> Node {
        match self {
            Transform::Similarity(s) => s.apply_node(n),
            Transform::Affine(a) => a.apply_node(n),
        }
    }
}

#[cfg(test)]
mod tests;
