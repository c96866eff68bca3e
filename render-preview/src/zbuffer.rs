//! The default (`zbuffer`) method's frame, from splats to pixels: the depth test
//! (translucent splats blended), cracks closed, and `s × s` subpixels resolved into a pixel
//! as the mesh reference resolves its own. The reference draws point clouds through the
//! same steps ([`zbuffer_frame`], over the triangles it drew first), so that a lossless tree of
//! a point cloud matches its reference; the preview draws them tile by tile
//! ([`zbuffer_tiled`]), to the same bytes.

use rayon::prelude::*;

use crate::raster::{blend_over, depth_key, fill_depth_pits, fill_holes, key_depth, rasterize_blended, Frame, Splat};
use crate::shade;

/// Draws `splats` into `sub` (`s × s` subpixels a pixel, already holding what was drawn
/// before them), and returns the resolved frame with its cracks closed: between thin splats
/// at the subpixel level, a pixel wide after resolving (three subpixels wide, past what the
/// first fill closes: 0.05 % of spot's pixels stayed background, costing it 2 dB), and depth
/// pits, where a farther surface shows through a crack of a nearer one (BENCHMARKS.md,
/// "Failure regions of every method"; covered, so the hole fill leaves them).
pub fn zbuffer_frame(mut sub: Frame, splats: &[Splat], s: usize, bg: [u8; 4]) -> Frame {
    rasterize_blended(&mut sub, splats);
    fill_holes(&mut sub);
    let mut frame = if s > 1 {
        let mut frame = resolve(&sub, s, bg);
        fill_holes(&mut frame);
        frame
    } else {
        sub
    };
    fill_depth_pits(&mut frame);
    frame
}

/// One pixel per `s × s` block of `sub` (`s` odd): covered exactly when its middle
/// subpixel, the pixel's centre, is (so silhouettes, coverage, IoU and holes are those of
/// one sample per pixel, a hard edge as the previews draw it), with that subpixel's depth
/// and the mean colour of the block's covered subpixels in linear light; the background
/// elsewhere.
pub fn resolve(sub: &Frame, s: usize, bg: [u8; 4]) -> Frame {
    let (w, h) = (sub.width / s, sub.height / s);
    let lin = shade::srgb_to_linear_lut();
    let mut out = Frame::new(w, h, bg);
    for y in 0..h {
        for x in 0..w {
            let centre = (y * s + s / 2) * sub.width + x * s + s / 2;
            if !sub.depth[centre].is_finite() {
                continue;
            }
            let (mut n, mut sum) = (0usize, [0f32; 3]);
            for sy in 0..s {
                let row = (y * s + sy) * sub.width + x * s;
                for i in row..row + s {
                    if sub.depth[i].is_finite() {
                        n += 1;
                        for (acc, &c) in sum.iter_mut().zip(&sub.color[i][..3]) {
                            *acc += lin[c as usize];
                        }
                    }
                }
            }
            let i = y * w + x;
            out.depth[i] = sub.depth[centre];
            let [r, g, b] = sum.map(|c| shade::linear_to_srgb8(c / n as f32));
            out.color[i] = [r, g, b, 255];
        }
    }
    out
}

/// Output pixels per side of a screen tile of [`zbuffer_tiled`]: at 3 × 3 a tile is 96 × 96
/// subpixels, whose depth keys and splat indices (8 bytes each, with a one-subpixel apron)
/// take 75 KiB and stay in a core's cache while the tile's splats are drawn, blended, filled
/// and resolved.
pub const TILE: usize = 32;

/// Splats binned by one worker at a time.
const BIN_CHUNK: usize = 1 << 16;

/// [`zbuffer_frame`] of a frame holding only the background, `sub_w × sub_h` subpixels
/// (`s × s` a pixel), drawn tile by tile: the same image, byte for byte, for any number of
/// threads.
///
/// Why: the whole-frame steps touch every subpixel of a 3 × 3 frame (8.3 M at 1280 × 720,
/// 66 MB of colour and depth plus 66 MB of candidates per raster worker) several times, and
/// most of that time went to page faults on the fresh buffers and to passes over memory. Here
/// the splats are binned to [`TILE`]-pixel screen tiles, and each tile's subpixels (with a
/// one-subpixel apron, what the subpixel hole fill reads) are drawn, blended, filled and
/// resolved in a small buffer before the next tile; tiles no splat reaches stay background
/// untouched. The steps are those of [`rasterize_blended`], [`fill_holes`] and [`resolve`]
/// with the same arithmetic. A subpixel keeps the nearest splat and, on a tie, the earliest,
/// as the whole-frame rasterizer does: a tile draws its splats in input order, so a strict
/// test of a 32-bit depth key keeps the earliest (the whole-frame rasterizer's workers, each
/// drawing some chunk, compare depth and index packed in 64 bits, which baseline x86-64 has
/// no vector compare for).
///
/// At 1280 × 720 and 3 × 3 this takes a quarter of the whole-frame steps' time (BENCHMARKS.md,
/// "Render preview"). Most of the gain is memory: on DamagedHelmet's 0.85 M splats (one
/// thread, callgrind) the instructions only fell from 1.60 G to 1.04 G, most of them now
/// the subpixel tests themselves.
pub fn zbuffer_tiled(sub_w: usize, sub_h: usize, splats: &[Splat], s: usize, bg: [u8; 4]) -> Frame {
    let s = s.max(1);
    let (w, h) = (sub_w / s, sub_h / s);
    // Indices are 32-bit in a candidate; the whole-frame path draws more in parts.
    if w == 0 || h == 0 || splats.len() > u32::MAX as usize || sub_w > i32::MAX as usize || sub_h > i32::MAX as usize {
        return zbuffer_frame(Frame::new(sub_w, sub_h, bg), splats, s, bg);
    }
    let geo = Geometry { sub_w, sub_h, s, ts: TILE * s, tiles_x: w.div_ceil(TILE), tiles_y: h.div_ceil(TILE) };
    let bins: Vec<Bins> = splats.par_chunks(BIN_CHUNK).enumerate().map(|(c, chunk)| Bins::new(chunk, (c * BIN_CHUNK) as u32, &geo)).collect();
    let mut out = Frame::new(w, h, bg);
    let lin = shade::srgb_to_linear_lut();
    out.color.par_chunks_mut(TILE * w).zip(out.depth.par_chunks_mut(TILE * w)).enumerate().for_each_init(Scratch::default, |scratch, (ty, (color, depth))| {
        for tx in 0..geo.tiles_x {
            draw_tile(&geo, splats, &bins, (tx, ty), scratch, lin, bg, (color, depth, w));
        }
    });
    if s > 1 {
        fill_holes(&mut out);
    }
    fill_depth_pits(&mut out);
    out
}

/// The subframe and its tiles.
struct Geometry {
    sub_w: usize,
    sub_h: usize,
    s: usize,
    /// Subpixels per tile side.
    ts: usize,
    tiles_x: usize,
    tiles_y: usize,
}

impl Geometry {
    /// The splat's box clipped to the subframe, `[x0, x1, y0, y1]` inclusive, as the
    /// rasterizer clips it; `None` when it draws nothing (an empty box, or a NaN or infinite
    /// depth, which never passes a depth test).
    #[inline(always)]
    fn clip(&self, sp: &Splat) -> Option<[i32; 4]> {
        if sp.z.is_nan() || sp.z == f32::INFINITY {
            return None;
        }
        let [x0, x1, y0, y1] = sp.bounds.map(i32::from);
        let b = [x0.max(0), x1.min(self.sub_w as i32 - 1), y0.max(0), y1.min(self.sub_h as i32 - 1)];
        (b[0] <= b[1] && b[2] <= b[3]).then_some(b)
    }

    /// Tiles `[x0, x1, y0, y1]` (inclusive) whose subpixels or apron the clipped box `b`
    /// reaches (`None` for a box past the last tile's apron, in the columns or rows beyond
    /// the last whole pixel).
    #[inline(always)]
    fn tiles(&self, b: [i32; 4]) -> Option<[usize; 4]> {
        let t = |lo: i32, hi: i32, n: usize| ((lo - 1).max(0) as usize / self.ts, ((hi + 1) as usize / self.ts).min(n - 1));
        let (x0, x1) = t(b[0], b[1], self.tiles_x);
        let (y0, y1) = t(b[2], b[3], self.tiles_y);
        (x0 <= x1 && y0 <= y1).then_some([x0, x1, y0, y1])
    }
}

/// The indices of one chunk of splats, grouped by tile (a splat in every tile it reaches).
struct Bins {
    /// Start of each tile's indices in `index`, and the end.
    start: Vec<u32>,
    index: Vec<u32>,
}

impl Bins {
    #[inline(never)]
    fn new(chunk: &[Splat], base: u32, g: &Geometry) -> Bins {
        let n = g.tiles_x * g.tiles_y;
        let mut start = vec![0u32; n + 1];
        // Each splat's tiles, found once for both passes (none: `u32::MAX` first).
        let mut rects = Vec::with_capacity(chunk.len());
        for sp in chunk {
            let rect = g.clip(sp).and_then(|b| g.tiles(b)).map_or([u32::MAX; 4], |r| r.map(|v| v as u32));
            if rect[0] != u32::MAX {
                let [x0, x1, y0, y1] = rect.map(|v| v as usize);
                for ty in y0..=y1 {
                    for c in &mut start[ty * g.tiles_x + x0 + 1..=ty * g.tiles_x + x1 + 1] {
                        *c += 1;
                    }
                }
            }
            rects.push(rect);
        }
        for i in 0..n {
            start[i + 1] += start[i];
        }
        let mut next = start.clone();
        let mut index = vec![0u32; start[n] as usize];
        for (k, rect) in rects.iter().enumerate() {
            if rect[0] != u32::MAX {
                let [x0, x1, y0, y1] = rect.map(|v| v as usize);
                for ty in y0..=y1 {
                    for at in &mut next[ty * g.tiles_x + x0..=ty * g.tiles_x + x1] {
                        if let Some(slot) = index.get_mut(*at as usize) {
                            *slot = base + k as u32;
                        }
                        *at += 1;
                    }
                }
            }
        }
        Bins { start, index }
    }

    fn of(&self, tile: usize) -> &[u32] {
        match (self.start.get(tile), self.start.get(tile + 1)) {
            (Some(&a), Some(&b)) => self.index.get(a as usize..b as usize).unwrap_or(&[]),
            _ => &[],
        }
    }
}

/// A worker's tile buffers, reused from tile to tile.
#[derive(Default)]
struct Scratch {
    /// The opaque splats and the translucent ones.
    opaque: Layer,
    clear: Layer,
    depth: Vec<f32>,
    color: Vec<[u8; 4]>,
}

/// A tile's nearest splat per subpixel so far: its depth key and index.
#[derive(Default)]
struct Layer {
    /// [`depth_key`] of the depth at the subpixel with its top bit flipped, so that keys
    /// compare as signed integers (the one 32-bit vector compare of SSE2); `i32::MAX` for
    /// none.
    key: Vec<i32>,
    index: Vec<u32>,
}

/// The signed form of [`depth_key`] that [`Layer::key`] holds.
#[inline(always)]
fn signed_key(z: f32) -> i32 {
    (depth_key(z) ^ 0x8000_0000) as i32
}

impl Layer {
    fn reset(&mut self, n: usize) {
        self.key.clear();
        self.key.resize(n, i32::MAX);
        self.index.clear();
        self.index.resize(n, 0);
    }

    /// The depth and colour of the splat kept at subpixel `i`, as the whole-frame
    /// rasterizer writes it over the background: none where no splat, or one at a NaN
    /// depth, won. (The largest key is a NaN depth too, so a splat there drawing nothing is
    /// no loss.)
    #[inline(always)]
    fn winner(&self, i: usize, splats: &[Splat]) -> Option<(f32, [u8; 4])> {
        let k = *self.key.get(i)?;
        if k == i32::MAX {
            return None;
        }
        let z = key_depth(k as u32 ^ 0x8000_0000);
        let col = splats.get(*self.index.get(i)? as usize)?.color;
        (z < f32::INFINITY).then_some((z, col))
    }
}

/// Draws, blends, fills and resolves tile `(tx, ty)` into its pixels of a band of output
/// rows (`out`: colour, depth and the output width).
#[allow(clippy::too_many_arguments)]
#[inline(never)]
fn draw_tile(g: &Geometry, splats: &[Splat], bins: &[Bins], (tx, ty): (usize, usize), scr: &mut Scratch, lin: &[f32; 256], bg: [u8; 4], out: (&mut [[u8; 4]], &mut [f32], usize)) {
    let tile = ty * g.tiles_x + tx;
    if bins.iter().all(|b| b.of(tile).is_empty()) {
        return;
    }
    let (w, h) = (g.sub_w / g.s, g.sub_h / g.s);
    // The tile's subpixels, then with the apron (clipped to the subframe).
    let (cx0, cx1) = (tx * g.ts, ((tx + 1) * g.ts).min(w * g.s));
    let (cy0, cy1) = (ty * g.ts, ((ty + 1) * g.ts).min(h * g.s));
    let (ex0, ex1) = (cx0.saturating_sub(1), (cx1 + 1).min(g.sub_w));
    let (ey0, ey1) = (cy0.saturating_sub(1), (cy1 + 1).min(g.sub_h));
    // Rows padded for `draw`'s last run of lanes.
    let ew = ex1 - ex0 + LANES - 1;
    let n = ew * (ey1 - ey0);
    let area = Area { x0: ex0 as i32, x1: ex1 as i32 - 1, y0: ey0 as i32, y1: ey1 as i32 - 1, w: ew };
    scr.opaque.reset(n);
    let mut any_clear = false;
    for b in bins {
        for &i in b.of(tile) {
            let Some(sp) = splats.get(i as usize) else { continue };
            let Some(clip) = g.clip(sp) else { continue };
            if sp.color[3] == 255 {
                draw(sp, i, clip, &mut scr.opaque, &area);
            } else {
                if !any_clear {
                    scr.clear.reset(n);
                    any_clear = true;
                }
                draw(sp, i, clip, &mut scr.clear, &area);
            }
        }
    }
    scr.depth.clear();
    scr.color.clear();
    for i in 0..n {
        let (z, col) = scr.opaque.winner(i, splats).unwrap_or((f32::INFINITY, bg));
        scr.depth.push(z);
        scr.color.push(col);
    }
    if any_clear {
        // `rasterize_blended`: the nearest translucent splat over the opaque surface.
        for i in 0..n {
            let Some((tz, t)) = scr.clear.winner(i, splats) else { continue };
            let (Some(c), Some(z)) = (scr.color.get_mut(i), scr.depth.get_mut(i)) else { break };
            blend_over(c, z, t, tz, lin, (ex0 + i % ew, ey0 + i / ew));
        }
    }
    // `fill_holes` on the subframe, then `resolve`, for the tile's pixels.
    let fill = Fill { depth: &scr.depth, color: &scr.color, w: ew, sub_w: g.sub_w, sub_h: g.sub_h };
    let (color, depth, w) = out;
    let s = g.s;
    for py in cy0 / s..cy1 / s {
        for px in cx0 / s..cx1 / s {
            let o = (py - ty * TILE) * w + px;
            // Subpixel (x, y) of the subframe in the tile's buffer.
            let at = |x: usize, y: usize| ((y - ey0) * ew + x - ex0, x, y);
            if s == 1 {
                let (i, x, y) = at(px, py);
                let v = fill.get(i, x, y).or_else(|| Some((*fill.depth.get(i)?, *fill.color.get(i)?)));
                if let (Some((z, c)), Some(od), Some(oc)) = (v, depth.get_mut(o), color.get_mut(o)) {
                    (*od, *oc) = (z, c);
                }
                continue;
            }
            let (i, x, y) = at(px * s + s / 2, py * s + s / 2);
            let Some((zc, _)) = fill.get(i, x, y) else { continue };
            let (mut n, mut sum) = (0usize, [0f32; 3]);
            for sy in 0..s {
                for sx in 0..s {
                    let (i, x, y) = at(px * s + sx, py * s + sy);
                    if let Some((_, c)) = fill.get(i, x, y) {
                        n += 1;
                        for (acc, &c) in sum.iter_mut().zip(&c[..3]) {
                            *acc += lin[c as usize];
                        }
                    }
                }
            }
            let [r, g, b] = sum.map(|c| shade::linear_to_srgb8(c / n as f32));
            if let (Some(od), Some(oc)) = (depth.get_mut(o), color.get_mut(o)) {
                (*od, *oc) = (zc, [r, g, b, 255]);
            }
        }
    }
}

/// A tile's buffer area in subframe subpixels, inclusive, and its row width.
struct Area {
    x0: i32,
    x1: i32,
    y0: i32,
    y1: i32,
    w: usize,
}

/// Draws a splat (`clip`: its box clipped to the subframe) into a tile's layer, where it
/// replaces strictly farther splats, with the arithmetic of the whole-frame rasterizer:
/// offsets from the clipped box's first pixel, so that a subpixel's test and depth do not
/// depend on the tile. Drawn in strips of up to [`STRIP`] columns (a subpixel's test does
/// not depend on its neighbours').
#[inline(always)]
fn draw(sp: &Splat, index: u32, [xa, xb, ya, yb]: [i32; 4], layer: &mut Layer, a: &Area) {
    let (x0, x1, y0, y1) = (xa.max(a.x0), xb.min(a.x1), ya.max(a.y0), yb.min(a.y1));
    if x0 > x1 || y0 > y1 {
        return;
    }
    let mut x = x0;
    while x <= x1 {
        let last = x1.min(x + STRIP as i32 - 1);
        let strip = [xa, x, last, y0, y1];
        match (last - x) as usize / LANES {
            0 => draw_strip::<1>(sp, index, strip, layer, a),
            1 => draw_strip::<2>(sp, index, strip, layer, a),
            2 => draw_strip::<3>(sp, index, strip, layer, a),
            _ => draw_strip::<4>(sp, index, strip, layer, a),
        }
        x += STRIP as i32;
    }
}

/// Subpixels of a row tested at a time (an SSE2 vector).
const LANES: usize = 4;
/// Columns of a strip: four runs of lanes.
const STRIP: usize = 4 * LANES;

/// Draws columns `x0..=x1` (at most `N` runs of [`LANES`]) of rows `y0..=y1` of a splat whose
/// clipped box starts at column `xa`. What does not change down a column (the offset from
/// the centre times the axis, the lanes past `x1`) is computed once; each row then takes a
/// few vector operations a run, and both arrays are stored whether or not the splat wins
/// (selects by mask: whether a subpixel lies in the splat is a coin toss at its rim, and
/// the compiler otherwise branches per lane).
#[inline(always)]
fn draw_strip<const N: usize>(sp: &Splat, index: u32, [xa, x0, x1, y0, y1]: [i32; 5], layer: &mut Layer, a: &Area) {
    let x0f = xa as f32 + 0.5 - sp.x;
    let (mut pux, mut puy, mut live) = ([[0f32; LANES]; N], [[0f32; LANES]; N], [[0i32; LANES]; N]);
    for r in 0..N {
        for l in 0..LANES {
            let k = x0 - xa + (r * LANES + l) as i32;
            let dx = x0f + k as f32;
            pux[r][l] = dx * sp.ux;
            puy[r][l] = dx * sp.uy;
            live[r][l] = -((xa + k <= x1) as i32);
        }
    }
    let (ia, ib, z, rim) = (sp.inv_a2, sp.inv_b2, sp.z, sp.rim);
    for py in y0..=y1 {
        let dy = py as f32 + 0.5 - sp.y;
        let (ay, by) = (dy * sp.uy, dy * sp.ux);
        let at = (py - a.y0) as usize * a.w + (x0 - a.x0) as usize;
        let (Some(keys), Some(idx)) = (layer.key.get_mut(at..at + N * LANES), layer.index.get_mut(at..at + N * LANES)) else { return };
        for r in 0..N {
            let (Some(keys), Some(idx)) = (keys.get_mut(r * LANES..(r + 1) * LANES), idx.get_mut(r * LANES..(r + 1) * LANES)) else { return };
            let (Ok(keys), Ok(idx)) = (<&mut [i32; LANES]>::try_from(keys), <&mut [u32; LANES]>::try_from(idx)) else { return };
            // In steps over all lanes, each of which the compiler vectorises.
            let (mut a, mut b, mut q) = ([0f32; LANES], [0f32; LANES], [0f32; LANES]);
            for l in 0..LANES {
                a[l] = pux[r][l] + ay;
            }
            for l in 0..LANES {
                b[l] = by - puy[r][l];
            }
            for l in 0..LANES {
                q[l] = a[l] * a[l] * ia + b[l] * b[l] * ib;
            }
            let mut m = [0i32; LANES];
            for l in 0..LANES {
                let d = signed_key(z + rim * q[l]);
                let old = keys[l];
                m[l] = -((q[l] <= 1.0) as i32) & -((d < old) as i32) & live[r][l];
                keys[l] = old ^ ((old ^ d) & m[l]);
            }
            for l in 0..LANES {
                idx[l] ^= (idx[l] ^ index) & m[l] as u32;
            }
        }
    }
}

/// A tile's drawn subpixels read as [`fill_holes`] leaves them.
struct Fill<'a> {
    depth: &'a [f32],
    color: &'a [[u8; 4]],
    /// Row width of the buffers.
    w: usize,
    sub_w: usize,
    sub_h: usize,
}

impl Fill<'_> {
    /// Depth and colour of buffer subpixel `i` (subframe `(x, y)`) after the hole fill, or
    /// `None` when it stays uncovered: a covered subpixel as drawn; an uncovered one inside
    /// the subframe's border with at least three of four edge neighbours and seven of eight
    /// covered takes its nearest edge neighbour's (the first of left, right, up, down on a
    /// tie). The caller keeps `(x, y)` off the buffer's apron, so every neighbour is there.
    #[inline(always)]
    fn get(&self, i: usize, x: usize, y: usize) -> Option<(f32, [u8; 4])> {
        let d = |j: usize| self.depth.get(j).copied().unwrap_or(f32::INFINITY);
        let own = d(i);
        if own.is_finite() {
            return Some((own, *self.color.get(i)?));
        }
        if x == 0 || y == 0 || x + 1 >= self.sub_w || y + 1 >= self.sub_h {
            return None;
        }
        let w = self.w;
        let mut n = 0;
        let mut best = usize::MAX;
        for j in [i - 1, i + 1, i - w, i + w] {
            if d(j).is_finite() {
                n += 1;
                if best == usize::MAX || d(j) < d(best) {
                    best = j;
                }
            }
        }
        if n >= 3 && n + [i - w - 1, i - w + 1, i + w - 1, i + w + 1].iter().filter(|&&j| d(j).is_finite()).count() >= 7 {
            return Some((d(best), *self.color.get(best)?));
        }
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::raster::tests::xorshift;

    /// Splats of every kind the tiled path must draw as the whole-frame steps do, over a
    /// `w × h` subframe: mostly a few subpixels across with rims, some large or thin, across
    /// tile borders and the frame's edges, translucent (some fully transparent), tied in
    /// depth, and at NaN, infinite, negative and signed-zero depths.
    fn splats(n: u32, w: f32, h: f32, seed: u32) -> Vec<Splat> {
        let mut rnd = xorshift(seed);
        (0..n)
            .map(|i| {
                let (x, y) = (rnd() * (w + 20.0) - 10.0, rnd() * (h + 20.0) - 10.0);
                let z = match i % 101 {
                    0 => f32::NAN,
                    1 => f32::INFINITY,
                    2 => -0.0,
                    3 => -1.0,
                    4 => f32::NEG_INFINITY,
                    _ => 1.0 + (rnd() * 8.0).floor() * 0.25,
                };
                let r = if i % 40 == 0 { rnd() * 30.0 } else { rnd() * 3.5 };
                let a = match i % 9 {
                    0 => (rnd() * 255.0) as u8,
                    1 => 0,
                    _ => 255,
                };
                let c = [(i % 251) as u8, (i / 251 % 251) as u8, (i % 13) as u8 * 19, a];
                let t = rnd() * 6.3;
                let mut s = if i % 3 == 0 { Splat::ellipse(x, y, z, r, r * rnd(), t.cos(), t.sin(), c) } else { Splat::disc(x, y, z, r, c) };
                s.rim = if i % 5 == 0 { 0.0 } else { rnd() * 0.3 };
                s
            })
            .collect()
    }

    /// The tiled frame is the whole-frame steps' frame, byte for byte, at one, three and five
    /// subpixels a side, on frames that are no whole number of tiles (with leftover
    /// subpixel columns and rows past the last whole pixel), with opaque splats alone and with
    /// translucent ones, on one thread or several.
    #[test]
    fn tiled_frame_matches_the_whole_frame_steps() {
        let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
        let bg = [10, 20, 30, 255];
        for (s, sub_w, sub_h, seed) in [(3, 3 * 75, 3 * 41, 1), (3, 3 * 70 + 2, 3 * 33 + 1, 2), (1, 101, 67, 3), (5, 5 * 37, 5 * 35, 4), (3, 3 * 32, 3 * 32, 5)] {
            let all = splats(40_000, sub_w as f32, sub_h as f32, seed);
            let opaque: Vec<Splat> = all.iter().map(|sp| Splat { color: [sp.color[0], sp.color[1], sp.color[2], 255], ..*sp }).collect();
            for set in [&all, &opaque] {
                let want = zbuffer_frame(Frame::new(sub_w, sub_h, bg), set, s, bg);
                assert!(want.covered() > want.width * want.height / 4, "a frame worth comparing");
                let got = zbuffer_tiled(sub_w, sub_h, set, s, bg);
                assert_eq!(got, want, "{s}×{s}, {sub_w}×{sub_h}");
                let single = one.install(|| zbuffer_tiled(sub_w, sub_h, set, s, bg));
                assert_eq!(single, want, "one thread, {s}×{s}, {sub_w}×{sub_h}");
            }
        }
    }

    /// Coplanar splats tied everywhere (equal depth, no rim): the earliest in the input keeps
    /// every subpixel it covers, as in the whole-frame rasterizer, though the tile draws
    /// them after binning.
    #[test]
    fn ties_go_to_the_earliest_splat() {
        let bg = [0, 0, 0, 255];
        let mut rnd = xorshift(9);
        let set: Vec<Splat> = (0..5000).map(|i| Splat::disc(rnd() * 300.0, rnd() * 200.0, 1.0, 2.0 + rnd() * 6.0, [(i % 256) as u8, (i / 256) as u8, 7, 255])).collect();
        let want = zbuffer_frame(Frame::new(300, 201, bg), &set, 3, bg);
        assert_eq!(zbuffer_tiled(300, 201, &set, 3, bg), want);
        let mut reversed = set.clone();
        reversed.reverse();
        assert_ne!(zbuffer_tiled(300, 201, &reversed, 3, bg), want, "the order decides ties");
    }

    /// No splats, or none on screen: the background, as the whole-frame steps leave it.
    #[test]
    fn empty_frames_stay_background() {
        let bg = [1, 2, 3, 255];
        let off = [Splat::disc(-50.0, -50.0, 1.0, 3.0, [9, 9, 9, 255])];
        for set in [&[][..], &off[..]] {
            assert_eq!(zbuffer_tiled(99, 60, set, 3, bg), zbuffer_frame(Frame::new(99, 60, bg), set, 3, bg));
        }
    }
}
