//! Position + radius of a child relative to its decoded parent (thesis §5.9.1.1, EQ 49–57),
//! shared by the canopy and default profiles.
//!
//! The child is normalised into the parent's unit sphere (offset `v = (c - p) / r_p`, radius
//! coefficient `k = r_c / r_p`), its centre moved to a point `g / QP` of the 13-point grid
//! (`g ∈ {-6..6}³`, `QP = 6`) and its radius coefficient grown by the position error and
//! rounded **up** to `q / QR` (`QR = 13`, `q ≥ 1`), so the decoded sphere contains the
//! original child.
//!
//! # Legal states (the 14-bit index)
//!
//! A state `(g, q)` is legal iff
//! 1. `|g|² ≤ 36`: the grid point lies inside (or on) the unit parent sphere, and
//! 2. `q ≥ 1` and `|g| / 6 + q / 13 ≤ 1 + S` with `S = √3/6 + 1/13 ≈ 0.365598`: the decoded
//!    child sticks out of the decoded parent by at most `S` parent radii. `S` is the thesis's
//!    own worst case: twice the worst grid error `√3/12` (the centre moves by `e`, the radius
//!    grows by `e`) plus one radius step `1/13` from rounding up.
//!
//! States are numbered in the order `i` (x), then `j` (y), then `k` (z), each from -6 to 6,
//! then `q` ascending. This yields **[`STATE_COUNT`] = 6 821** states (fits 13 bits; stored in
//! the thesis's 14-bit field). Eight states lie exactly on the boundary (`g = (±1,±1,±1)`,
//! `q = 14`: `√3/6 + 14/13 = 1 + S`); they are legal, and implementations must compare with a
//! tolerance of 1e-9 (every other state is more than 1e-4 from the boundary).
//!
//! Why not 8 721 (thesis) or 7 621 (QSplat)? Applying rule 2 to *all* 13³ grid points (also
//! the cube corners outside the sphere) with the radius capped at the parent's (`q ≤ 13`)
//! gives exactly 8 721 (checked in a unit test), so that is most likely the thesis's rule.
//! We drop the corners because the thesis's encoder only picks points inside the unit sphere
//! ("nearest legal grid point ... contained by the unit sphere"), and we drop the cap
//! `q ≤ 13` because rounding up a child that coincides with its parent (welded duplicates,
//! f32 rounding in the builder) needs `q = 14`. QSplat quantizes offsets as fractions of the
//! parent's *diameter* and does not publish its validity rule; we could not reproduce 7 621.
//!
//! Because every legal state satisfies rule 2, a decoded child lies inside its decoded parent
//! grown by `S` parent radii whatever the input: that is `CONTAINMENT_SLACK`.
//!
//! # Containment, exactly
//!
//! The encoder evaluates the decoded child exactly as the decoder computes it (f32) and checks
//! `|c_dec - c| + r ≤ r_dec` in f64 on those f32 values, growing `q` until it holds. So the
//! decoded child contains the original child with no tolerance beyond the f64 evaluation of
//! that inequality (≈1e-16 relative).

use std::sync::OnceLock;

/// Grid points either side of the origin per axis (13-point grid).
pub const QP: i32 = 6;
/// Radius steps per parent radius.
pub const QR: i32 = 13;
/// Number of legal states.
pub const STATE_COUNT: usize = 6821;
/// Largest radius code of any legal state.
pub const Q_MAX: i32 = 17;

/// The stick-out bound `S = √3/6 + 1/13` of the legality rule (parent radii).
pub fn stick_out_bound() -> f64 {
    3f64.sqrt() / 6.0 + 1.0 / 13.0
}

/// Number of grid points per axis.
const SIDE: usize = (2 * QP + 1) as usize;
/// Marks a grid point without legal states.
const NONE: u16 = u16::MAX;

/// Lookup tables built once.
pub struct Tables {
    /// Per state: offset of the centre in parent radii, and radius coefficient (f32, exactly
    /// what the decoder multiplies with).
    pub offset: Vec<[f32; 3]>,
    /// Radius coefficient `q / 13` per state.
    pub radius: Vec<f32>,
    /// Grid point and radius code per state.
    pub state: Vec<([i8; 3], u8)>,
    /// Per grid point (index `((i+6)·13 + j+6)·13 + k+6`): first state index or `NONE`.
    base: Vec<u16>,
    /// Per grid point: largest legal `q` (0 when none).
    qmax: Vec<u8>,
    /// Grid points inside the sphere, for the exhaustive search.
    pub inside: Vec<[i8; 3]>,
}

fn grid_index(g: [i32; 3]) -> usize {
    (((g[0] + QP) as usize * SIDE) + (g[1] + QP) as usize) * SIDE + (g[2] + QP) as usize
}

/// Whether `(g, q)` is legal (see the module docs). f64 with a 1e-9 tolerance that admits the
/// eight exact-equality states; every other state is > 1e-4 from the boundary (unit test), so
/// any IEEE double implementation agrees.
pub fn is_legal(g: [i32; 3], q: i32) -> bool {
    let n2 = g[0] * g[0] + g[1] * g[1] + g[2] * g[2];
    q >= 1 && n2 <= QP * QP && (n2 as f64).sqrt() / QP as f64 + q as f64 / QR as f64 <= 1.0 + stick_out_bound() + 1e-9
}

/// The tables (built on first use).
pub fn tables() -> &'static Tables {
    static T: OnceLock<Tables> = OnceLock::new();
    T.get_or_init(|| {
        let mut t = Tables {
            offset: Vec::with_capacity(STATE_COUNT),
            radius: Vec::with_capacity(STATE_COUNT),
            state: Vec::with_capacity(STATE_COUNT),
            base: vec![NONE; SIDE * SIDE * SIDE],
            qmax: vec![0; SIDE * SIDE * SIDE],
            inside: Vec::new(),
        };
        for i in -QP..=QP {
            for j in -QP..=QP {
                for k in -QP..=QP {
                    let g = [i, j, k];
                    let gi = grid_index(g);
                    for q in 1..=Q_MAX + 1 {
                        if !is_legal(g, q) {
                            break;
                        }
                        if q == 1 {
                            t.base[gi] = t.state.len() as u16;
                            t.inside.push([i as i8, j as i8, k as i8]);
                        }
                        t.qmax[gi] = q as u8;
                        let f = |a: i32| a as f32 / QP as f32;
                        t.offset.push([f(i), f(j), f(k)]);
                        t.radius.push(q as f32 / QR as f32);
                        t.state.push(([i as i8, j as i8, k as i8], q as u8));
                    }
                }
            }
        }
        t
    })
}

impl Tables {
    /// State index of `(g, q)`, if legal.
    pub fn index(&self, g: [i32; 3], q: i32) -> Option<u16> {
        if g.iter().any(|&a| !(-QP..=QP).contains(&a)) || q < 1 {
            return None;
        }
        let gi = grid_index(g);
        if q > self.qmax[gi] as i32 {
            return None;
        }
        Some(self.base[gi] + (q - 1) as u16)
    }
}

/// The decoded child sphere of state `s` in decoded parent `(pc, pr)`: the single definition
/// both encoder and decoder use, so they agree bit for bit.
#[inline]
pub fn decode_state(t: &Tables, s: usize, pc: [f32; 3], pr: f32) -> Option<([f32; 3], f32)> {
    let o = t.offset.get(s)?;
    let k = *t.radius.get(s)?;
    Some(([pc[0] + pr * o[0], pc[1] + pr * o[1], pc[2] + pr * o[2]], pr * k))
}

fn dist64(a: [f32; 3], b: [f32; 3]) -> f64 {
    let d = |i: usize| a[i] as f64 - b[i] as f64;
    (d(0) * d(0) + d(1) * d(1) + d(2) * d(2)).sqrt()
}

#[cfg(test)]
/// True when sphere `(c_out, r_out)` contains `(c_in, r_in)` evaluated in f64 on the f32 values.
#[inline]
pub fn contains(c_out: [f32; 3], r_out: f32, c_in: [f32; 3], r_in: f32) -> bool {
    dist64(c_out, c_in) + r_in as f64 <= r_out as f64
}

/// `a / QP` (f32) at index `a + QP`, for `a` from `-QP` to 9 (the grid uses `-QP..=QP`; the
/// table is padded to 16 entries so that a masked index needs no bounds check): the tables'
/// offsets, built at compile time (IEEE division, the same values as at run time; checked in a
/// test) so that no division lies on the search's dependency chain.
static GRID_COORD: [f32; 16] = {
    let mut t = [0f32; 16];
    let mut i = 0;
    while i < t.len() {
        t[i] = (i as i32 - QP) as f32 / QP as f32;
        i += 1;
    }
    t
};

/// `q / QR` (f32) for `q` in `0..32` (radius codes are at most `Q_MAX + 1`; padded as
/// [`GRID_COORD`]).
static RADIUS_COEF: [f32; 32] = {
    let mut t = [0f32; 32];
    let mut q = 0;
    while q < t.len() {
        t[q] = q as f32 / QR as f32;
        q += 1;
    }
    t
};

/// The decoded centre of grid point `g` (each coordinate in `-QP..=QP`) in parent `(pc, pr)`:
/// the same f32 operations as [`decode_state`] on the table's offset `g / QP`.
#[inline]
fn grid_center(g: [i32; 3], pc: [f32; 3], pr: f32) -> [f32; 3] {
    let f = |a: usize| pc[a] + pr * GRID_COORD[(g[a] + QP) as usize & 15];
    [f(0), f(1), f(2)]
}

/// Decoded radius coefficient of radius code `q` (`0..=Q_MAX + 1`): the table's `q / QR`.
#[inline]
fn radius_coef(q: i32) -> f32 {
    RADIUS_COEF[q as usize & 31]
}

/// Smallest radius code `q` at grid point `g` (each coordinate in `-QP..=QP`) whose decoded
/// sphere contains the child, and its state index; `None` when that `q` is not legal at `g`.
#[inline]
fn fit(t: &Tables, g: [i32; 3], pc: [f32; 3], pr: f32, cc: [f32; 3], cr: f32) -> Option<(u16, i32, f64)> {
    let gi = grid_index(g);
    let (base, qmax) = (*t.base.get(gi)?, *t.qmax.get(gi)? as i32);
    if base == NONE {
        return None;
    }
    let dist = dist64(grid_center(g, pc, pr), cc);
    let need = dist + cr as f64;
    // First guess from the exact ratio; then walk up until the f32 radius really covers it.
    let mut q = first_radius_code(need / pr as f64 * QR as f64)?;
    while q <= qmax {
        if (pr * radius_coef(q)) as f64 >= need {
            return Some((base + (q - 1) as u16, q, dist));
        }
        q += 1;
    }
    None
}

/// Where [`fit`] starts walking for the exact ratio `y` (radius codes needed): one below
/// `⌈y⌉`, in case the f32 product rounds above the exact ratio, and at least 1; `None` when
/// `⌈y⌉ > Q_MAX + 1` or `y` is not finite. The same codes as [`fit_reference`]'s `ceil_f64` and
/// float tests, from one truncation: `⌈y⌉ = t + (t < y)` with `t = trunc(y)` (y ≤ 18 here).
#[inline(always)]
fn first_radius_code(y: f64) -> Option<i32> {
    // Also catches NaN; ⌈y⌉ > 18 iff y > 18.
    if !(y <= (Q_MAX + 1) as f64 && y > f64::NEG_INFINITY) {
        return None;
    }
    let t = y as i32;
    let c = t + ((t as f64) < y) as i32;
    Some(if c > 1 { c - 1 } else { 1 })
}

/// Encodes a child sphere `(cc, cr)` against decoded parent `(pc, pr)`: the legal state of
/// smallest decoded radius (ties: smallest centre error) whose decoded sphere contains the
/// child. The caller checks finiteness and `pr > 0`. `None` when no legal state contains it
/// (the child lies too far outside the parent).
pub fn encode_sphere(pc: [f32; 3], pr: f32, cc: [f32; 3], cr: f32) -> Option<u16> {
    search(pc, pr, cc, cr, false).map(|t| t.states[0])
}

/// Most equally tight states [`encode_sphere_ties`] reports.
pub const MAX_TIES: usize = 8;

/// The states that contain a child with the smallest decoded radius the reference encoder
/// finds: `states[0]` is [`encode_sphere`]'s choice, the others (grid neighbours of it with
/// the same radius code that also contain the child) follow in a fixed order.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Ties {
    /// Number of valid entries of `states` (≥ 1).
    pub len: u8,
    /// The states.
    pub states: [u16; MAX_TIES],
}

impl Ties {
    fn one(s: u16) -> Ties {
        let mut states = [0; MAX_TIES];
        states[0] = s;
        Ties { len: 1, states }
    }

    /// The valid states.
    pub fn as_slice(&self) -> &[u16] {
        &self.states[..self.len as usize]
    }
}

/// [`encode_sphere`]'s state and, when it came from the nearest grid point, every other state
/// of the same radius code at a neighbouring grid point (±1 per axis) that also contains the
/// child (evaluated exactly as [`fit`] does). Any of them is equally tight (same decoded
/// radius); they differ only in centre error, which stays below the decoded radius minus the
/// child's. Only neighbours can qualify: the same radius code allows a centre error of at
/// most the nearest point's error (≤ √3/2 grid steps) plus one radius step (6/13 grid steps),
/// < 1.5 grid steps, and every grid point two steps away on some axis is farther than that.
pub fn encode_sphere_ties(pc: [f32; 3], pr: f32, cc: [f32; 3], cr: f32) -> Option<Ties> {
    search(pc, pr, cc, cr, true)
}

/// `x.round()` (half away from zero) as an integer when it lies in `-QP..=QP`, i.e. when
/// `-6.5 < x < 6.5` (`None` otherwise, NaN included): the same grid point as
/// `round_f64(x)` and its `|·| <= QP` test, without the float round trip.
#[inline]
fn round_on_grid(x: f64) -> Option<i32> {
    if !(x > -(QP as f64 + 0.5) && x < QP as f64 + 0.5) {
        return None;
    }
    let t = x as i32;
    // Exact: |x| < 7, so x - t is exact (Sterbenz / integer part).
    let f = x - t as f64;
    Some(t + (f >= 0.5) as i32 - (f <= -0.5) as i32)
}

fn search(pc: [f32; 3], pr: f32, cc: [f32; 3], cr: f32, want_ties: bool) -> Option<Ties> {
    let t = tables();
    let v = |i: usize| (cc[i] as f64 - pc[i] as f64) / pr as f64 * QP as f64;
    let vg = [v(0), v(1), v(2)];
    // Fast path: the nearest grid point overall minimises the error, hence the radius.
    if let [Some(g0), Some(g1), Some(g2)] = vg.map(round_on_grid) {
        let g = [g0, g1, g2];
        if let Some((s, q, _)) = fit(t, g, pc, pr, cc, cr) {
            let mut ties = Ties::one(s);
            if !want_ties {
                return Some(ties);
            }
            let r = pr * radius_coef(q);
            // Room left for the centre error, in grid steps, with a generous margin for the f32
            // rounding of decoded centres: the exact test below decides.
            let room = (r as f64 - cr as f64) / pr as f64 * QP as f64 * 1.01 + 0.01;
            let room2 = room * room;
            // Squared offset from v per axis for the neighbour offsets -1, 0, 1 (the same f64
            // values the sum below always used); an axis offset is worth trying only if it
            // fits with the others at their nearest (offset 0, since g is the nearest point).
            // `g - vg` is exact (|vg - g| ≤ 1/2, both below 7), so `(g - vg) ± 1` is the one
            // rounding of the same value as `(g ± 1) - vg`.
            let sq = |a: usize| {
                let e = g[a] as f64 - vg[a];
                [e - 1.0, e, e + 1.0].map(|e| e * e)
            };
            let (s0, s1, s2) = (sq(0), sq(1), sq(2));
            // No neighbour can fit when moving any one axis to its nearer neighbour already
            // leaves no room (rounded sums are monotone and every neighbour moves some axis):
            // the common case, decided without the loops below.
            let near = |e: [f64; 3]| e[0].min(e[2]);
            if near(s0) + s1[1] + s2[1] > room2 && s0[1] + near(s1) + s2[1] > room2 && s0[1] + s1[1] + near(s2) > room2 {
                return Some(ties);
            }
            for (di, &e0) in s0.iter().enumerate() {
                if e0 + s1[1] + s2[1] > room2 {
                    continue;
                }
                for (dj, &e1) in s1.iter().enumerate() {
                    if e0 + e1 + s2[1] > room2 {
                        continue;
                    }
                    for (dk, &e2) in s2.iter().enumerate() {
                        if (di, dj, dk) == (1, 1, 1) || e0 + e1 + e2 > room2 {
                            continue;
                        }
                        let g2 = [g[0] + di as i32 - 1, g[1] + dj as i32 - 1, g[2] + dk as i32 - 1];
                        let Some(s2) = t.index(g2, q) else { continue };
                        // Same radius code, so the decoded radius is `r`.
                        if dist64(grid_center(g2, pc, pr), cc) + cr as f64 <= r as f64 && (ties.len as usize) < MAX_TIES {
                            ties.states[ties.len as usize] = s2;
                            ties.len += 1;
                        }
                    }
                }
            }
            return Some(ties);
        }
    }
    // Near or outside the boundary: exhaustive search over the 925 grid points.
    let mut best: Option<(u16, i32, f64)> = None;
    for g in &t.inside {
        let g = [g[0] as i32, g[1] as i32, g[2] as i32];
        if let Some(c) = fit(t, g, pc, pr, cc, cr) {
            if best.is_none_or(|b| (c.1, c.2) < (b.1, b.2)) {
                best = Some(c);
            }
        }
    }
    best.map(|b| Ties::one(b.0))
}

/// [`fit`] as first written (table lookups per step), kept for [`search_reference`].
#[cfg(test)]
fn fit_reference(t: &Tables, g: [i32; 3], pc: [f32; 3], pr: f32, cc: [f32; 3], cr: f32) -> Option<(u16, i32, f64)> {
    let s1 = t.index(g, 1)? as usize;
    let (dc, _) = decode_state(t, s1, pc, pr)?;
    let dist = dist64(dc, cc);
    let need = dist + cr as f64;
    // First guess from the exact ratio; then walk up until the f32 radius really covers it.
    let guess = super::rounding::ceil_f64(need / pr as f64 * QR as f64);
    if !guess.is_finite() || guess > (Q_MAX + 1) as f64 {
        return None;
    }
    let mut q = (guess as i32).max(1);
    // One step down too, in case the f32 product rounds above the exact ratio.
    if q > 1 {
        q -= 1;
    }
    loop {
        let s = t.index(g, q)?;
        let r = pr * t.radius[s as usize];
        if (r as f64) >= need {
            return Some((s, q, dist));
        }
        q += 1;
    }
}

/// The search as first written (`round_f64` and a float range test), kept as a reference.
#[cfg(test)]
fn search_reference(pc: [f32; 3], pr: f32, cc: [f32; 3], cr: f32, want_ties: bool) -> Option<Ties> {
    let t = tables();
    let v = |i: usize| (cc[i] as f64 - pc[i] as f64) / pr as f64 * QP as f64;
    let vg = [v(0), v(1), v(2)];
    let g0 = vg.map(super::rounding::round_f64);
    // Fast path: the nearest grid point overall minimises the error, hence the radius.
    if g0.iter().all(|a| a.abs() <= QP as f64) {
        let g = [g0[0] as i32, g0[1] as i32, g0[2] as i32];
        if let Some((s, q, _)) = fit_reference(t, g, pc, pr, cc, cr) {
            let mut ties = Ties::one(s);
            if !want_ties {
                return Some(ties);
            }
            let r = pr * t.radius[s as usize];
            // Room left for the centre error, in grid steps, with a generous margin for the f32
            // rounding of decoded centres: the exact test below decides.
            let room = (r as f64 - cr as f64) / pr as f64 * QP as f64 * 1.01 + 0.01;
            let room2 = room * room;
            // Squared offset from v per axis for the neighbour offsets -1, 0, 1 (the same f64
            // values the sum below always used); an axis offset is worth trying only if it
            // fits with the others at their nearest (offset 0, since g is the nearest point).
            // `g - vg` is exact (|vg - g| ≤ 1/2, both below 7), so `(g - vg) ± 1` is the one
            // rounding of the same value as `(g ± 1) - vg`.
            let sq = |a: usize| {
                let e = g[a] as f64 - vg[a];
                [e - 1.0, e, e + 1.0].map(|e| e * e)
            };
            let (s0, s1, s2) = (sq(0), sq(1), sq(2));
            for (di, &e0) in s0.iter().enumerate() {
                if e0 + s1[1] + s2[1] > room2 {
                    continue;
                }
                for (dj, &e1) in s1.iter().enumerate() {
                    if e0 + e1 + s2[1] > room2 {
                        continue;
                    }
                    for (dk, &e2) in s2.iter().enumerate() {
                        if (di, dj, dk) == (1, 1, 1) || e0 + e1 + e2 > room2 {
                            continue;
                        }
                        let g2 = [g[0] + di as i32 - 1, g[1] + dj as i32 - 1, g[2] + dk as i32 - 1];
                        let Some(s2) = t.index(g2, q) else { continue };
                        let Some((dc, dr)) = decode_state(t, s2 as usize, pc, pr) else { continue };
                        if dist64(dc, cc) + cr as f64 <= dr as f64 && (ties.len as usize) < MAX_TIES {
                            ties.states[ties.len as usize] = s2;
                            ties.len += 1;
                        }
                    }
                }
            }
            return Some(ties);
        }
    }
    // Near or outside the boundary: exhaustive search over the 925 grid points.
    let mut best: Option<(u16, i32, f64)> = None;
    for g in &t.inside {
        let g = [g[0] as i32, g[1] as i32, g[2] as i32];
        if let Some(c) = fit_reference(t, g, pc, pr, cc, cr) {
            if best.is_none_or(|b| (c.1, c.2) < (b.1, b.2)) {
                best = Some(c);
            }
        }
    }
    best.map(|b| Ties::one(b.0))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn state_count_and_inverse() {
        let t = tables();
        assert_eq!(t.state.len(), STATE_COUNT);
        assert_eq!(t.inside.len(), 925);
        const { assert!(STATE_COUNT < 1 << 14) };
        let mut maxq = 0;
        for (s, &(g, q)) in t.state.iter().enumerate() {
            let g = [g[0] as i32, g[1] as i32, g[2] as i32];
            assert_eq!(t.index(g, q as i32), Some(s as u16));
            maxq = maxq.max(q as i32);
        }
        assert_eq!(maxq, Q_MAX);
        assert_eq!(t.index([0, 0, 0], Q_MAX + 1), None);
        assert_eq!(t.index([6, 6, 6], 1), None);
    }

    /// The compile-time coordinate and radius tables hold what run-time division gives, and
    /// what the state tables hold.
    #[test]
    fn const_tables_match_run_time() {
        let qp = std::hint::black_box(QP as f32);
        let qr = std::hint::black_box(QR as f32);
        for a in -QP..=QP {
            assert_eq!(GRID_COORD[(a + QP) as usize].to_bits(), (a as f32 / qp).to_bits(), "{a}");
        }
        const { assert!(Q_MAX + 1 < 32) };
        for q in 0..=Q_MAX + 1 {
            assert_eq!(radius_coef(q).to_bits(), (q as f32 / qr).to_bits(), "{q}");
        }
        let t = tables();
        for (s, &(g, q)) in t.state.iter().enumerate() {
            let g = [g[0] as i32, g[1] as i32, g[2] as i32];
            assert_eq!(t.offset[s].map(f32::to_bits), g.map(|a| GRID_COORD[(a + QP) as usize].to_bits()));
            assert_eq!(t.radius[s].to_bits(), radius_coef(q as i32).to_bits());
        }
    }

    /// The thesis's 8 721: same stick-out rule over all 13³ points with `q ≤ 13`.
    #[test]
    fn thesis_count_reproduced() {
        let mut n = 0;
        for i in -6i32..=6 {
            for j in -6i32..=6 {
                for k in -6i32..=6 {
                    let d = ((i * i + j * j + k * k) as f64).sqrt() / 6.0;
                    n += (1..=13).filter(|&q| d + q as f64 / 13.0 <= 1.0 + stick_out_bound()).count();
                }
            }
        }
        assert_eq!(n, 8721);
    }

    /// No state is within 1e-4 of the legality boundary, so the set is robust to rounding.
    #[test]
    fn legality_margin() {
        let s = stick_out_bound();
        for i in -6i32..=6 {
            for j in -6i32..=6 {
                for k in -6i32..=6 {
                    let d = ((i * i + j * j + k * k) as f64).sqrt() / 6.0;
                    for q in 1..=20 {
                        let m = (d + q as f64 / 13.0 - 1.0 - s).abs();
                        let on_boundary = i.abs() == 1 && j.abs() == 1 && k.abs() == 1 && q == 14;
                        assert!(m > 1e-4 || (on_boundary && m < 1e-12), "{i} {j} {k} {q}");
                    }
                }
            }
        }
    }

    #[test]
    fn coincident_child_needs_no_more_than_q14() {
        let s = encode_sphere([1.0, 2.0, 3.0], 0.5, [1.0, 2.0, 3.0], 0.5).unwrap();
        let (dc, dr) = decode_state(tables(), s as usize, [1.0, 2.0, 3.0], 0.5).unwrap();
        assert!(contains(dc, dr, [1.0, 2.0, 3.0], 0.5));
        assert!(tables().state[s as usize].1 <= 14);
    }

    /// Every tie contains the child with the same radius code as the reference choice, the
    /// reference choice comes first, and ties do occur.
    #[test]
    fn ties_are_equally_tight_and_contain_the_child() {
        let t = tables();
        let mut rng = crate::rng::SplitMix64(0x9E37_79B9_7F4A_7C15);
        let mut rnd = || rng.next_f64();
        let (pc, pr) = ([0.3f32, -1.2, 2.0], 0.75f32);
        let mut with_ties = 0;
        for _ in 0..20_000 {
            let cr = (pr as f64 * (0.2 + 0.6 * rnd())) as f32;
            let reach = (pr - cr) as f64;
            let cc = [0, 1, 2].map(|i| (pc[i] as f64 + reach * (2.0 * rnd() - 1.0) * 0.57) as f32);
            let Some(ties) = encode_sphere_ties(pc, pr, cc, cr) else { continue };
            assert_eq!(Some(ties.states[0]), encode_sphere(pc, pr, cc, cr));
            let q0 = t.state[ties.states[0] as usize].1;
            for &s in ties.as_slice() {
                assert_eq!(t.state[s as usize].1, q0);
                let (dc, dr) = decode_state(t, s as usize, pc, pr).unwrap();
                assert!(contains(dc, dr, cc, cr));
            }
            with_ties += (ties.len > 1) as u32;
        }
        assert!(with_ties > 1000, "{with_ties}");
    }

    #[test]
    fn far_child_is_refused() {
        assert!(encode_sphere([0.0; 3], 1.0, [5.0, 0.0, 0.0], 0.1).is_none());
        assert!(encode_sphere([0.0; 3], 1.0, [0.0; 3], 1.5).is_none());
    }

    /// The search finds exactly the states of the reference one.
    #[test]
    fn ties_match_reference() {
        let mut rng = crate::rng::SplitMix64(0x9E37_79B9_7F4A_7C15);
        let mut rnd = || rng.next_f64();
        let mut with_ties = 0;
        for n in 0..300_000 {
            let pr = (0.001 + rnd() * if n % 3 == 0 { 1e3 } else { 1.0 }) as f32;
            let pc = [0, 1, 2].map(|_| ((rnd() - 0.5) * if n % 5 == 0 { 1e4 } else { 2.0 }) as f32);
            let cr = (pr as f64 * (0.05 + 0.9 * rnd())) as f32;
            let reach = (pr - cr) as f64;
            let cc = [0, 1, 2].map(|i| (pc[i] as f64 + reach * (2.0 * rnd() - 1.0) * 0.7) as f32);
            let got = search(pc, pr, cc, cr, true);
            assert_eq!(got, search_reference(pc, pr, cc, cr, true), "{pc:?} {pr} {cc:?} {cr}");
            with_ties += got.is_some_and(|t| t.len > 1) as u32;
        }
        assert!(with_ties > 10_000, "{with_ties}");
    }

    /// `first_radius_code` agrees with the `ceil_f64` form of `fit_reference`, around every
    /// integer, at the limits and at random.
    #[test]
    fn first_radius_code_matches_ceil() {
        let want = |y: f64| {
            let guess = crate::codec::rounding::ceil_f64(y);
            if !guess.is_finite() || guess > (Q_MAX + 1) as f64 {
                return None;
            }
            let q = (guess as i32).max(1);
            Some(if q > 1 { q - 1 } else { q })
        };
        let mut ys = vec![f64::NAN, f64::INFINITY, f64::NEG_INFINITY, 0.0, -0.0, -1e300, 1e300, f64::MIN_POSITIVE, -3e9];
        for k in -30..=30 {
            let h = k as f64;
            let (mut up, mut down) = (h, h);
            for _ in 0..4 {
                ys.extend([up, down, h + 0.5]);
                up = up.next_up();
                down = down.next_down();
            }
        }
        let mut rng = crate::rng::SplitMix64(0x5DEE_CE66_D1CE_4E5B);
        ys.extend((0..1_000_000).map(|_| rng.next_f64() * 40.0 - 10.0));
        for y in ys {
            assert_eq!(first_radius_code(y), want(y), "{y}");
        }
    }

    /// `round_on_grid` agrees with `round_f64` and the `|g| <= 6` test, around every
    /// half-integer and at random.
    #[test]
    fn round_on_grid_matches_round() {
        let want = |x: f64| {
            let r = crate::codec::rounding::round_f64(x);
            (r.abs() <= QP as f64).then_some(r as i32)
        };
        let mut xs = vec![f64::NAN, f64::INFINITY, f64::NEG_INFINITY, 0.0, -0.0, 1e300, -1e300];
        for k in -20..=20 {
            let h = k as f64 * 0.5;
            let mut up = h;
            let mut down = h;
            for _ in 0..4 {
                xs.extend([up, down]);
                up = f64::from_bits(up.to_bits() + 1).max(up.next_up());
                down = down.next_down();
            }
        }
        for i in 0..200_000 {
            xs.push((i as f64 / 200_000.0 - 0.5) * 16.0);
        }
        for x in xs {
            assert_eq!(round_on_grid(x), want(x), "{x}");
        }
    }
}
