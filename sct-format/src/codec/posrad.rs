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
/// Cells per axis of the padded grid (coordinates `-QP - 1..=QP + 1`): every neighbour of a
/// grid point has a cell, so the tie search needs no range tests.
const PAD_SIDE: usize = SIDE + 2;
/// Cells of the padded grid, rounded up to a power of two so that a masked index needs no
/// bounds check.
const CELLS: usize = 4096;
const _: () = assert!(PAD_SIDE * PAD_SIDE * PAD_SIDE <= CELLS);

/// Lookup tables built once.
pub struct Tables {
    /// Per state: offset of the centre in parent radii, and radius coefficient (f32, exactly
    /// what the decoder multiplies with).
    pub offset: Vec<[f32; 3]>,
    /// Radius coefficient `q / 13` per state.
    pub radius: Vec<f32>,
    /// Grid point and radius code per state.
    pub state: Vec<([i8; 3], u8)>,
    /// Per cell of the padded grid (index [`cell_index`]): its legal states.
    cells: Box<[Cell; CELLS]>,
    /// Grid points inside the sphere, for the exhaustive search.
    pub inside: Vec<[i8; 3]>,
}

/// The legal states of one grid point: `first state index << 8 | largest legal q`, where a
/// largest `q` of 0 means none (points outside the sphere and the padding).
#[derive(Clone, Copy, Default)]
struct Cell(u32);

impl Cell {
    fn qmax(self) -> i32 {
        (self.0 & 0xff) as i32
    }

    /// The state of radius code `q` (`1..=qmax`).
    fn state(self, q: i32) -> u16 {
        ((self.0 >> 8) as i32 + q - 1) as u16
    }
}

/// Index of grid point `g` (each coordinate in `-QP - 1..=QP + 1`) in [`Tables::cells`].
fn cell_index(g: [i32; 3]) -> usize {
    let c = |a: usize| (g[a] + QP + 1) as usize;
    (c(0) * PAD_SIDE + c(1)) * PAD_SIDE + c(2)
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
            cells: Box::new([Cell::default(); CELLS]),
            inside: Vec::new(),
        };
        for i in -QP..=QP {
            for j in -QP..=QP {
                for k in -QP..=QP {
                    let g = [i, j, k];
                    let first = t.state.len() as u32;
                    for q in 1..=Q_MAX + 1 {
                        if !is_legal(g, q) {
                            break;
                        }
                        if q == 1 {
                            t.inside.push([i as i8, j as i8, k as i8]);
                        }
                        t.cells[cell_index(g)] = Cell(first << 8 | q as u32);
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
    /// State index of `(g, q)`, if legal (the reference search's lookup, and the default
    /// encoder's for states near its first choice).
    pub fn index(&self, g: [i32; 3], q: i32) -> Option<u16> {
        if g.iter().any(|&a| !(-QP..=QP).contains(&a)) || q < 1 {
            return None;
        }
        let c = self.cell(cell_index(g));
        (q <= c.qmax()).then(|| c.state(q))
    }

    /// The cell at index `i` (masked: any `i` is safe; the padded grid's are below [`CELLS`]).
    #[inline(always)]
    fn cell(&self, i: usize) -> Cell {
        self.cells[i & (CELLS - 1)]
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
/// sphere contains the child, its state index and the centre error; `None` when that `q` is not
/// legal at `g`.
fn fit(t: &Tables, g: [i32; 3], pc: [f32; 3], pr: f32, cc: [f32; 3], cr: f32) -> Option<(u16, i32, f64)> {
    let dist = dist64(grid_center(g, pc, pr), cc);
    let (s, q) = smallest_containing_code(t.cell(cell_index(g)), pr, dist + cr as f64)?;
    Some((s, q, dist))
}

/// The smallest radius code of `cell` whose decoded radius (f32, as the decoder computes it)
/// is at least `need`, and its state; `None` when no legal code is large enough.
#[inline(always)]
fn smallest_containing_code(cell: Cell, pr: f32, need: f64) -> Option<(u16, i32)> {
    // First guess from the exact ratio; then walk up until the f32 radius really covers it.
    let mut q = first_radius_code(need / pr as f64 * QR as f64)?;
    while q <= cell.qmax() {
        if (pr * radius_coef(q)) as f64 >= need {
            return Some((cell.state(q), q));
        }
        q += 1;
    }
    None
}

/// Where [`smallest_containing_code`] starts walking for the exact ratio `y` (radius codes needed): one below
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

/// Whether some legal state contains the child `(cc, cr)` in decoded parent `(pc, pr)`:
/// exactly `encode_sphere(pc, pr, cc, cr).is_some()`, tried first at the grid point of state
/// `near`. A child moved a little from the sphere of state `near` (a centre offset, a leaf
/// refinement) is mostly contained by a larger radius code there, which costs one distance
/// instead of a search. That test is one of the exhaustive search's own (the same f32 centre
/// and f64 comparison), so a pass there means the search finds a state too.
pub fn encodable_near(near: u16, pc: [f32; 3], pr: f32, cc: [f32; 3], cr: f32) -> bool {
    let t = tables();
    if let Some(&(g, _)) = t.state.get(near as usize) {
        let g = g.map(i32::from);
        let need = dist64(grid_center(g, pc, pr), cc) + cr as f64;
        if smallest_containing_code(t.cell(cell_index(g)), pr, need).is_some() {
            return true;
        }
    }
    search(pc, pr, cc, cr, false).is_some()
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
        let near = Nearest::new([g0, g1, g2], vg, pc, pr, cc);
        let cell = t.cell(near.cell);
        if let Some((s, q)) = smallest_containing_code(cell, pr, near.dist + cr as f64) {
            let mut ties = Ties::one(s);
            if want_ties {
                add_neighbour_ties(t, &near, q, pc, pr, cc, cr, &mut ties);
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

/// The grid point nearest to the child's centre and what the tie search reuses of it.
struct Nearest {
    /// The grid point (each coordinate in `-QP..=QP`).
    g: [i32; 3],
    /// Its cell index.
    cell: usize,
    /// `g - vg` per axis (exact: `|vg - g| ≤ 1/2`, both below 7).
    err: [f64; 3],
    /// Per axis, the f64 square of the decoded centre's offset from the child's centre: the
    /// terms of [`dist64`] of [`grid_center`].
    sq: [f64; 3],
    /// The centre error `dist64(grid_center(g), cc)`.
    dist: f64,
}

impl Nearest {
    #[inline(always)]
    fn new(g: [i32; 3], vg: [f64; 3], pc: [f32; 3], pr: f32, cc: [f32; 3]) -> Nearest {
        let sq = |a: usize| axis_sq(pc[a], pr, g[a], cc[a]);
        let sq = [sq(0), sq(1), sq(2)];
        let err = |a: usize| g[a] as f64 - vg[a];
        Nearest {
            g,
            cell: cell_index(g),
            err: [err(0), err(1), err(2)],
            sq,
            dist: (sq[0] + sq[1] + sq[2]).sqrt(),
        }
    }
}

/// The square (f64) of the offset, on one axis, of grid coordinate `a` (`-QP - 1..=QP + 1`)'s
/// decoded centre from the child's centre `c`: one term of [`dist64`] of [`grid_center`].
#[inline(always)]
fn axis_sq(p: f32, pr: f32, a: i32, c: f32) -> f64 {
    let d = (p + pr * GRID_COORD[(a + QP) as usize & 15]) as f64 - c as f64;
    d * d
}

/// Offset codes 0, 1, 2 (offsets -1, 0, +1) per axis: neighbour `(x, y, z)` is bit
/// `9x + 3y + z` of a candidate mask, so the search's order (x, then y, then z) is bit order.
const CENTRE_BIT: u32 = 1 << 13;

/// Where the tie search finds a candidate's terms: the indices of its x, y and z offsets in
/// [`AxisTerms`] and its cell relative to the cell of offset (-1, -1, -1).
#[derive(Clone, Copy)]
struct Neighbour {
    x: u8,
    y: u8,
    z: u8,
    cell: u16,
}

/// [`Neighbour`] per candidate bit (27 used, padded to 32 so that a masked bit index needs no
/// bounds check).
static NEIGHBOURS: [Neighbour; 32] = {
    let mut t = [Neighbour { x: 0, y: 0, z: 0, cell: 0 }; 32];
    let mut b = 0;
    while b < 27 {
        let (x, y, z) = (b / 9, b / 3 % 3, b % 3);
        let cell = (x * PAD_SIDE + y) * PAD_SIDE + z;
        t[b] = Neighbour { x: x as u8, y: (4 + y) as u8, z: (8 + z) as u8, cell: cell as u16 };
        b += 1;
    }
    t
};

/// Per axis and 3-bit mask of offset codes: the candidate bits whose offset on that axis is in
/// the mask.
static AXIS_CANDIDATES: [[u32; 8]; 3] = {
    let mut t = [[0; 8]; 3];
    let mut b = 0;
    while b < 27 {
        let code = [b / 9, b / 3 % 3, b % 3];
        let mut a = 0;
        while a < 3 {
            let mut m = 0;
            while m < 8 {
                if m >> code[a] & 1 != 0 {
                    t[a][m] |= 1 << b;
                }
                m += 1;
            }
            a += 1;
        }
        b += 1;
    }
    t
};

/// One f64 term per axis and offset code, at index `4·axis + code` (padded to 16 so that a
/// masked index needs no bounds check).
type AxisTerms = [f64; 16];

/// The sum of `terms` at candidate `n`'s offsets, x + y first (as the reference sums).
#[inline(always)]
fn sum_at(terms: &AxisTerms, n: Neighbour) -> f64 {
    let t = |i: u8| terms[i as usize & 15];
    t(n.x) + t(n.y) + t(n.z)
}

/// The 3-bit mask of offset codes `d` for which `fits(d)`.
#[inline(always)]
fn code_mask(fits: impl Fn(usize) -> bool) -> usize {
    fits(0) as usize | (fits(1) as usize) << 1 | (fits(2) as usize) << 2
}

/// Appends to `ties` the states of radius code `q` (the nearest point's) at the grid
/// neighbours of `near` that contain the child (see [`encode_sphere_ties`]), in the order
/// x, y, z offset, each -1, 0, 1.
///
/// A neighbour is tested exactly only when its squared offset from the child's centre, in grid
/// steps, is within a generous room for the centre error (as the search always did; the exact
/// test decides). That sum is rounded, so it is monotone in each term: a neighbour passes only
/// if each of its axis offsets passes with the other axes at their nearest (offset 0, the
/// smallest term since `|g - vg| ≤ 1/2`). Those per-axis masks leave only the few candidates
/// worth summing, and none in the common case.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn add_neighbour_ties(t: &Tables, near: &Nearest, q: i32, pc: [f32; 3], pr: f32, cc: [f32; 3], cr: f32, ties: &mut Ties) {
    let r = pr * radius_coef(q);
    // Room left for the centre error, in grid steps, with a generous margin for the f32
    // rounding of decoded centres.
    let room = (r as f64 - cr as f64) / pr as f64 * QP as f64 * 1.01 + 0.01;
    let room2 = room * room;
    // Squared offset from vg per axis and offset: `(g - vg) ± 1` is the one rounding of
    // `(g ± 1) - vg`.
    let mut e: AxisTerms = [0.0; 16];
    for a in 0..3 {
        let x = near.err[a];
        e[4 * a..4 * a + 3].copy_from_slice(&[x - 1.0, x, x + 1.0].map(|x| x * x));
    }
    // Not `x > room2`, as the reference skips only on `>` (a NaN room tests every neighbour);
    // `partial_cmp` costs 7 instructions per child more here.
    #[allow(clippy::neg_cmp_op_on_partial_ord)]
    let fits = |x: f64| !(x > room2);
    let mx = code_mask(|d| fits(e[d] + e[5] + e[9]));
    let my = code_mask(|d| fits(e[1] + e[4 + d] + e[9]));
    let mz = code_mask(|d| fits(e[1] + e[5] + e[8 + d]));
    let mut bits = AXIS_CANDIDATES[0][mx] & AXIS_CANDIDATES[1][my] & AXIS_CANDIDATES[2][mz] & !CENTRE_BIT;
    if bits == 0 {
        return;
    }
    // Decoded centres' squared offsets per axis and offset.
    let mut sq: AxisTerms = [0.0; 16];
    for a in 0..3 {
        let g = near.g[a];
        sq[4 * a..4 * a + 3].copy_from_slice(&[axis_sq(pc[a], pr, g - 1, cc[a]), near.sq[a], axis_sq(pc[a], pr, g + 1, cc[a])]);
    }
    let (cr, r) = (cr as f64, r as f64);
    // Cell of the neighbour at offsets (-1, -1, -1); the nearest point is inside the padding.
    let corner = near.cell - (PAD_SIDE * PAD_SIDE + PAD_SIDE + 1);
    while bits != 0 {
        let n = NEIGHBOURS[bits.trailing_zeros() as usize & 31];
        bits &= bits - 1;
        if sum_at(&e, n) > room2 {
            continue;
        }
        let cell = t.cell(corner + n.cell as usize);
        // Same radius code, so the decoded radius is `r`.
        if q <= cell.qmax() && sum_at(&sq, n).sqrt() + cr <= r && (ties.len as usize) < MAX_TIES {
            ties.states[ties.len as usize] = cell.state(q);
            ties.len += 1;
        }
    }
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
    /// `encodable_near` answers as `encode_sphere` does, from the state a child was moved from:
    /// children moved from a state's sphere by up to a few radius steps, near the parent's
    /// boundary too, where some are not encodable at all.
    #[test]
    fn encodable_near_matches_search() {
        let t = tables();
        let mut rng = crate::rng::SplitMix64(0x5EED_0E4C_0DAB_1E00);
        let mut rnd = || rng.next_f64();
        let (mut shortcut, mut refused) = (0, 0);
        for n in 0..200_000 {
            let pr = (0.001 + rnd() * if n % 3 == 0 { 1e3 } else { 1.0 }) as f32;
            let pc = [0, 1, 2].map(|_| ((rnd() - 0.5) * if n % 5 == 0 { 1e4 } else { 2.0 }) as f32);
            let s = (rnd() * t.state.len() as f64) as u16;
            let Some((c, r)) = decode_state(t, s as usize, pc, pr) else { continue };
            let shift = pr as f64 * 0.3 * rnd();
            let cc = [0, 1, 2].map(|a| (c[a] as f64 + shift * (2.0 * rnd() - 1.0)) as f32);
            let cr = (r as f64 * (0.8 + 0.3 * rnd())) as f32;
            let want = encode_sphere(pc, pr, cc, cr).is_some();
            assert_eq!(encodable_near(s, pc, pr, cc, cr), want, "{s} {pc:?} {pr} {cc:?} {cr}");
            let g = t.state[s as usize].0.map(i32::from);
            let at_g = smallest_containing_code(t.cell(cell_index(g)), pr, dist64(grid_center(g, pc, pr), cc) + cr as f64).is_some();
            shortcut += at_g as u32;
            refused += !want as u32;
        }
        // Both branches are taken: the shortcut, and the search (which refuses some).
        assert!(shortcut > 50_000 && refused > 5_000, "{shortcut} {refused}");
    }

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

    /// The search finds exactly the states of the reference one for children placed where
    /// its shortcuts could go wrong: on decoded grid centres, half-way between grid points
    /// (rounding ties, cube centres with up to eight equally near corners), with radii on a
    /// decoded radius's boundary (±1 ulp), on and beyond the parent's boundary, for parents
    /// far from the origin relative to their radius, tiny (subnormal) and huge radii, and
    /// with non-finite values; with and without ties.
    #[test]
    fn search_matches_reference_on_special_children() {
        let t = tables();
        let mut rng = crate::rng::SplitMix64(0x0123_4567_89AB_CDEF);
        let mut next = move || rng.next_u64();
        let specials = [0.0f32, -0.0, f32::NAN, f32::INFINITY, f32::NEG_INFINITY, f32::MIN_POSITIVE, 1e-45, f32::MAX];
        let (mut with_ties, mut full, mut exhaustive) = (0, 0, 0);
        for n in 0..400_000u32 {
            let u = |x: u64| (x >> 11) as f64 / (1u64 << 53) as f64;
            let pr = match n % 7 {
                0 => 1e-40f32,
                1 => 3e30,
                2 => (1e-3 + u(next())) as f32,
                _ => (0.01 + u(next()) * 10.0) as f32,
            };
            let scale = [0.0, 1.0, 1e3, 1e7][(n / 7 % 4) as usize];
            let pc = [0, 1, 2].map(|_| ((u(next()) - 0.5) * scale) as f32);
            let g = [0, 1, 2].map(|_| (next() % 13) as i32 - QP);
            let kind = n / 28 % 6;
            let cc = match kind {
                // On the decoded centre of a grid point.
                0 => grid_center(g, pc, pr),
                // Half-way between grid points on a random set of axes.
                1 | 2 => {
                    let half = next();
                    [0, 1, 2].map(|a| {
                        let h = if half >> a & 1 != 0 { 0.5 } else { 0.0 };
                        (pc[a] as f64 + pr as f64 * (g[a] as f64 + h) / QP as f64) as f32
                    })
                }
                // Around the parent's boundary and beyond.
                3 => [0, 1, 2].map(|a| (pc[a] as f64 + pr as f64 * (u(next()) - 0.5) * 3.0) as f32),
                // Anywhere inside.
                _ => [0, 1, 2].map(|a| (pc[a] as f64 + pr as f64 * (u(next()) - 0.5) * 1.6) as f32),
            };
            let mut cr = match n / 168 % 4 {
                0 => 0.0,
                1 => pr,
                _ => (pr as f64 * u(next()) * 0.8) as f32,
            };
            // Put the radius on the boundary of the reference's decoded radius, ±1 ulp.
            if n % 3 == 0 {
                if let Some(r) = search_reference(pc, pr, cc, cr, false) {
                    let s = r.states[0] as usize;
                    let (dc, dr) = decode_state(t, s, pc, pr).unwrap();
                    let edge = (dr as f64 - dist64(dc, cc)) as f32;
                    cr = [edge.next_down(), edge, edge.next_up()][(next() % 3) as usize].max(0.0);
                }
            }
            let (mut pc, mut pr, mut cc) = (pc, pr, cc);
            if n % 997 == 0 {
                let x = specials[(next() % 8) as usize];
                match next() % 4 {
                    0 => pc[(next() % 3) as usize] = x,
                    1 => pr = x,
                    2 => cc[(next() % 3) as usize] = x,
                    _ => cr = x,
                }
            }
            for want_ties in [false, true] {
                let got = search(pc, pr, cc, cr, want_ties);
                assert_eq!(got, search_reference(pc, pr, cc, cr, want_ties), "{pc:?} {pr} {cc:?} {cr} {want_ties}");
                if want_ties {
                    with_ties += got.is_some_and(|t| t.len > 1) as u32;
                    full += got.is_some_and(|t| t.len as usize == MAX_TIES) as u32;
                }
            }
            let fast = [0, 1, 2].map(|a| (cc[a] as f64 - pc[a] as f64) / pr as f64 * QP as f64).map(round_on_grid);
            exhaustive += fast.iter().any(Option::is_none) as u32;
        }
        assert!(with_ties > 20_000 && full > 100 && exhaustive > 10_000, "{with_ties} {full} {exhaustive}");
    }

    /// `Tables::index` (through the padded cells) finds exactly the legal states, anywhere.
    #[test]
    fn index_matches_is_legal() {
        let t = tables();
        for i in -9..=9 {
            for j in -9..=9 {
                for k in -9..=9 {
                    let g = [i, j, k];
                    let on_grid = g.iter().all(|&a: &i32| a.abs() <= QP);
                    for q in -2..=Q_MAX + 3 {
                        let s = t.index(g, q);
                        assert_eq!(s.is_some(), on_grid && is_legal(g, q), "{g:?} {q}");
                        if let Some(s) = s {
                            assert_eq!(t.state[s as usize], (g.map(|a| a as i8), q as u8));
                        }
                    }
                }
            }
        }
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
