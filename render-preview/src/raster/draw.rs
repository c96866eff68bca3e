//! Drawing splats into a frame: workers draw chunks of splats into private layers of
//! depth-and-index candidates, merged band by band; translucent splats blended on top.

use rayon::prelude::*;

use super::{alpha_passes, Frame, Splat, BAND};

/// Splats handed to a worker at a time: workers take chunks from a shared counter, so a
/// chunk of large splats on one core does not leave the other idle.
const CHUNK: usize = 16384;

/// Per-pixel candidate of a worker's layer: `!(depth key << 32 | splat index)`, 0 for none.
/// Inverted so that the nearest (then earliest) splat is the *largest* value and an empty
/// layer is all zeros: a fresh layer is a zeroed allocation the kernel maps lazily.
type Cand = u64;

/// A worker's private full-frame layer of candidates, plus which bands it wrote.
#[derive(Default)]
struct Layer {
    /// All zero between calls: the merge resets what it reads, so a reused layer needs no
    /// clearing pass.
    cand: Vec<Cand>,
    /// Bands of [`BAND`] rows holding candidates, so that the merge skips the rest.
    touched: Vec<bool>,
}

/// Layers kept between calls (at most [`KEEP_BYTES`] of them): reallocating two 7 MiB
/// layers per 1280×720 frame costs a page fault per 4 KiB touched.
static SCRATCH: std::sync::Mutex<Vec<Layer>> = std::sync::Mutex::new(Vec::new());
/// The splats' colours (`u32` per splat) kept between calls like the layers: written as the
/// splats are drawn, so that the merge looks a winner's colour up in an array a tenth the
/// size of the splats' (a random access per covered pixel).
static COLORS: std::sync::Mutex<Vec<u32>> = std::sync::Mutex::new(Vec::new());
const KEEP_BYTES: usize = 256 << 20;

/// Order-preserving map of a depth to `u32` (`a < b` ⇔ `key(a) < key(b)` for non-NaN
/// depths, with −0 and +0 equal like the float comparison).
#[inline(always)]
pub(crate) fn depth_key(z: f32) -> u32 {
    // `+ 0.0` turns −0 into +0 (and is not folded away for that reason).
    // Negative depths flip all bits, others the sign bit (branch-free).
    let b = (z + 0.0).to_bits();
    b ^ (((b as i32) >> 31) as u32 | 0x8000_0000)
}

#[inline(always)]
pub(crate) fn key_depth(k: u32) -> f32 {
    f32::from_bits(if k >> 31 == 1 { k & 0x7fff_ffff } else { !k })
}

/// Rasterizes `splats` into `frame` (depth-tested against what the frame holds). Each pixel
/// keeps the nearest splat; ties go to the earliest splat, then to what the frame held.
///
/// Preview splats mostly hold one or two pixel centres, so sorting them to screen regions
/// first costs more than drawing them: instead each worker draws whole chunks of splats
/// into its own full-frame layer, where a candidate is the depth and splat index packed in
/// one integer (the depth test and the write are one max and one store), and a parallel
/// pass over bands keeps each pixel's best candidate of all layers. The best candidate is a
/// total order over (depth, index), so the image does not depend on the thread count or on
/// which worker drew which chunk.
pub fn rasterize(frame: &mut Frame, splats: &[Splat]) {
    // Splat indices are 32-bit in a candidate: more splats than that go in sequential
    // parts, which keeps "earliest wins" because a later part only replaces nearer depths.
    for part in splats.chunks(u32::MAX as usize) {
        rasterize_part(frame, part, true);
    }
}

/// `door`: splats with alpha < 255 are drawn through the screen door; otherwise as opaque,
/// their colour keeping its alpha.
fn rasterize_part(frame: &mut Frame, splats: &[Splat], door: bool) {
    let (w, h) = (frame.width, frame.height);
    let px = w * h;
    if px == 0 || splats.is_empty() || frame.color.len() != px || frame.depth.len() != px {
        return;
    }
    let nbands = h.div_ceil(BAND);
    let workers = rayon::current_num_threads().clamp(1, splats.len().div_ceil(CHUNK));
    let mut layers = SCRATCH.lock().map(|mut g| std::mem::take(&mut *g)).unwrap_or_else(|e| std::mem::take(&mut *e.into_inner()));
    layers.resize_with(workers.max(layers.len()), Layer::default);
    for l in &mut layers[..workers] {
        // Entries past `px` are zero too, so a larger layer is used as it is.
        if l.cand.len() < px {
            l.cand = vec![0; px];
        }
        l.touched.clear();
        l.touched.resize(nbands, false);
    }

    let mut colors = COLORS.lock().map(|mut g| std::mem::take(&mut *g)).unwrap_or_else(|e| std::mem::take(&mut *e.into_inner()));
    if colors.len() < splats.len() {
        colors.resize(splats.len(), 0);
    }
    // Chunk `i` of the colours, for the worker that draws chunk `i` of the splats.
    let parts: Vec<std::sync::Mutex<&mut [u32]>> = colors[..splats.len()].chunks_mut(CHUNK).map(std::sync::Mutex::new).collect();
    let next = std::sync::atomic::AtomicUsize::new(0);
    layers[..workers].par_iter_mut().for_each(|l| loop {
        let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let start = i.saturating_mul(CHUNK);
        let Some(Ok(mut col)) = parts.get(i).map(|p| p.lock()) else { break };
        let end = (start + CHUNK).min(splats.len());
        draw_chunk(&splats[start..end], start as u32, &mut l.cand[..px], &mut l.touched, &mut col, (w, h), door);
    });
    drop(parts);
    let colors_of = &colors[..];

    // Each band's slices of the layers that wrote to it.
    let band_px = BAND * w;
    let mut srcs: Vec<Vec<&mut [Cand]>> = (0..nbands).map(|_| Vec::with_capacity(workers)).collect();
    for l in &mut layers[..workers] {
        for ((band, c), &t) in srcs.iter_mut().zip(l.cand[..px].chunks_mut(band_px)).zip(&l.touched) {
            if t {
                band.push(c);
            }
        }
    }
    frame.color.par_chunks_mut(band_px).zip(frame.depth.par_chunks_mut(band_px)).zip(srcs).for_each(|((color, depth), mut src)| {
        let mut put = |i: usize, c: Cand| {
            let c = !c;
            let z = key_depth((c >> 32) as u32);
            if let (Some(d), Some(col), Some(s)) = (depth.get_mut(i), color.get_mut(i), colors_of.get(c as u32 as usize)) {
                if z < *d {
                    *d = z;
                    *col = s.to_ne_bytes();
                }
            }
        };
        match src.as_mut_slice() {
            [] => {}
            [a] => {
                for (i, c) in a.iter_mut().enumerate() {
                    if *c != 0 {
                        put(i, *c);
                        *c = 0;
                    }
                }
            }
            [a, rest @ ..] => {
                for i in 0..a.len() {
                    let mut best = std::mem::take(&mut a[i]);
                    for r in rest.iter_mut() {
                        if let Some(c) = r.get_mut(i) {
                            best = best.max(std::mem::take(c));
                        }
                    }
                    if best != 0 {
                        put(i, best);
                    }
                }
            }
        }
    });

    if colors.len() * 4 <= KEEP_BYTES {
        if let Ok(mut g) = COLORS.lock() {
            if g.is_empty() {
                *g = colors;
            }
        }
    }
    let kept: usize = layers.iter().map(|l| l.cand.len() * std::mem::size_of::<Cand>()).sum();
    if kept <= KEEP_BYTES {
        if let Ok(mut g) = SCRATCH.lock() {
            if g.is_empty() {
                *g = layers;
            }
        }
    }
}

/// [`rasterize`] with translucent splats blended rather than screen-doored: the opaque
/// splats are depth-tested as by [`rasterize`], then the nearest translucent splat in front
/// of them is blended over them in linear light (`alpha · splat + (1 − alpha) · behind`).
/// Where nothing opaque lies behind, the translucent splat covers the pixel through the
/// screen door, unblended.
///
/// Why: the screen door dithers a translucent surface pixel by pixel, so a decal's
/// antialiased edge or a half-transparent panel reads as a checkerboard of full-contrast
/// pixels, each off by half the contrast; the mesh reference averages its subpixels and
/// shows the blend. One translucent layer is kept per pixel, so overlapping splats of one
/// surface do not compound its alpha; a second translucent surface behind the first is lost.
pub fn rasterize_blended(frame: &mut Frame, splats: &[Splat]) {
    if splats.iter().all(|s| s.color[3] == 255) {
        rasterize(frame, splats);
        return;
    }
    let (opaque, clear): (Vec<Splat>, Vec<Splat>) = splats.iter().partition(|s| s.color[3] == 255);
    rasterize(frame, &opaque);
    drop(opaque);
    let (w, h) = (frame.width, frame.height);
    let mut top = Frame::new(w, h, [0; 4]);
    for part in clear.chunks(u32::MAX as usize) {
        rasterize_part(&mut top, part, false);
    }
    let lin = crate::shade::srgb_to_linear_lut();
    for (i, (t, &tz)) in top.color.iter().zip(&top.depth).enumerate() {
        let (Some(c), Some(z)) = (frame.color.get_mut(i), frame.depth.get_mut(i)) else { break };
        blend_over(c, z, *t, tz, lin, (i % w, i / w));
    }
}

/// The nearest translucent splat's colour `t` at depth `tz` over the opaque pixel `c` at
/// depth `z` (pixel `(x, y)` of the screen door): blended in linear light over an opaque
/// surface; where nothing opaque lies behind, it covers through the screen door, unblended,
/// as the mesh reference does. Behind the opaque surface, at a NaN depth or fully
/// transparent, nothing changes. `lin` is [`crate::shade::srgb_to_linear_lut`].
#[inline]
pub(crate) fn blend_over(c: &mut [u8; 4], z: &mut f32, t: [u8; 4], tz: f32, lin: &[f32; 256], (x, y): (usize, usize)) {
    if tz.is_nan() || tz >= *z || t[3] == 0 {
        return;
    }
    if z.is_finite() {
        let a = f32::from(t[3]) / 255.0;
        for k in 0..3 {
            c[k] = crate::shade::linear_to_srgb8(a * lin[t[k] as usize] + (1.0 - a) * lin[c[k] as usize]);
        }
    } else if alpha_passes(t[3], x, y) {
        *c = [t[0], t[1], t[2], 255];
    } else {
        return;
    }
    *z = tz;
}

/// Splats drawn as one batch by [`draw_batch`].
const BATCH: usize = 64;

/// Draws the splats of one chunk (`base`: index of its first splat) into a worker's layer.
#[inline(never)]
fn draw_chunk(splats: &[Splat], base: u32, cand: &mut [Cand], touched: &mut [bool], colors: &mut [u32], (w, h): (usize, usize), door: bool) {
    let batches = splats.chunks_exact(BATCH);
    let rest = batches.remainder();
    // First rows of the batches' boxes: a superset of the rows `draw_batch` writes itself
    // (rows `y0` and `y0 + 1` of a box), marked in `touched` once per chunk.
    let (mut lo, mut hi) = (i32::MAX, i32::MIN);
    for (g, (batch, col)) in batches.zip(colors.chunks_exact_mut(BATCH)).enumerate() {
        if let (Ok(batch), Ok(col)) = (<&[Splat; BATCH]>::try_from(batch), <&mut [u32; BATCH]>::try_from(col)) {
            draw_batch(batch, base + (g * BATCH) as u32, cand, touched, col, (w, h), door, (&mut lo, &mut hi));
        }
    }
    if lo <= hi {
        let (lo, hi) = (lo.clamp(0, h as i32 - 1) as usize, (hi + 1).clamp(0, h as i32 - 1) as usize);
        for t in touched.iter_mut().take(hi / BAND + 1).skip(lo / BAND) {
            *t = true;
        }
    }
    let first = base + (splats.len() - rest.len()) as u32;
    for (j, (s, c)) in rest.iter().zip(colors.iter_mut().skip(splats.len() - rest.len())).enumerate() {
        *c = u32::from_ne_bytes(s.color);
        draw_any(s, first + j as u32, cand, touched, (w, h), door);
    }
}

/// The candidate of splat `index` at depth `z`.
#[inline(always)]
fn key(z: f32, index: u32) -> Cand {
    !(((depth_key(z) as u64) << 32) | index as u64)
}

/// Draws a batch of consecutive splats (`base`: index of the first); `rows` takes the
/// minimum and maximum of their boxes' first rows.
///
/// Boxes of at most 2×2 pixel centres away from the right and bottom edges are all of a
/// preview's splats but a few. The four centre tests, masks and keys of all the batch's
/// splats are computed first, in a loop the compiler vectorises (four splats a step, one
/// per lane), and without branches: whether a splat hits a centre is a coin toss
/// the branch predictor loses, so the candidates of pixels that fail are rewritten
/// unchanged. The arithmetic is that of [`draw_any`], which draws the other splats, so
/// both draw the same pixels.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn draw_batch(q: &[Splat; BATCH], base: u32, cand: &mut [Cand], touched: &mut [bool], col: &mut [u32; BATCH], (w, h): (usize, usize), door: bool, rows: (&mut i32, &mut i32)) {
    // Per splat: the candidates offered to its four centres (zero where it misses one)
    // and whether the fast path draws it.
    let mut m = [[0u32; BATCH]; 4];
    let mut nk = [[0u32; BATCH]; 4];
    let mut ok = [0u32; BATCH];
    let (wl, hl) = (w as u32 - 1, h as u32 - 1);
    let (mut lo, mut hi) = (*rows.0, *rows.1);
    let mut all = 1;
    for k in 0..BATCH {
        let s = &q[k];
        let (x0, y0) = (s.bounds[0] as i32, s.bounds[2] as i32);
        let (ex, ey) = (s.bounds[1] as i32 - x0, s.bounds[3] as i32 - y0);
        let fx = x0 as f32 + 0.5 - s.x;
        let fx1 = fx + 1.0;
        let fy = y0 as f32 + 0.5 - s.y;
        let fy1 = (y0 + 1) as f32 + 0.5 - s.y;
        let (ux, uy, ia, ib) = (s.ux, s.uy, s.inv_a2, s.inv_b2);
        let q = |dx: f32, dy: f32| {
            let (a, b) = (dx * ux + dy * uy, dy * ux - dx * uy);
            a * a * ia + b * b * ib
        };
        let hit = |q: f32| 0u32.wrapping_sub((q <= 1.0) as u32);
        // Centres (0,0), (1,0), (0,1), (1,1) inside the box; none for an empty box.
        let (c0, c1, r0, r1) = (!(ex >> 31) as u32, !((ex - 1) >> 31) as u32, !(ey >> 31) as u32, !((ey - 1) >> 31) as u32);
        let qs = [q(fx, fy), q(fx1, fy), q(fx, fy1), q(fx1, fy1)];
        for (j, qj) in qs.into_iter().enumerate() {
            nk[j][k] = !depth_key(s.z + s.rim * qj);
        }
        m[0][k] = hit(qs[0]) & c0 & r0;
        m[1][k] = hit(qs[1]) & c1 & r0;
        m[2][k] = hit(qs[2]) & c0 & r1;
        m[3][k] = hit(qs[3]) & c1 & r1;
        // A negative coordinate fails the unsigned comparison. NaN and +inf depths never
        // pass a depth test; `draw_any` drops them.
        ok[k] = ((ex <= 1) & (ey <= 1) & ((x0 as u32) < wl) & ((y0 as u32) < hl) & (s.color[3] == 255 || !door) & (s.z < f32::INFINITY)) as u32;
        all &= ok[k];
        lo = lo.min(y0);
        hi = hi.max(y0);
    }
    (*rows.0, *rows.1) = (lo, hi);
    let at = |s: &Splat| s.bounds[2] as i32 as usize * w + s.bounds[0] as i32 as usize;
    let cands = |k: usize| {
        let idx = !(base + k as u32) as u64;
        let pick = |j: usize| (((nk[j][k] as u64) << 32) | idx) & (m[j][k] as i32 as i64 as u64);
        [pick(0), pick(1), pick(2), pick(3)]
    };
    if all != 0 {
        // The usual case, without a branch per splat.
        for k in 0..BATCH {
            put_quad(cand, at(&q[k]), w, cands(k));
            col[k] = u32::from_ne_bytes(q[k].color);
        }
    } else {
        for k in 0..BATCH {
            col[k] = u32::from_ne_bytes(q[k].color);
            if ok[k] != 0 {
                put_quad(cand, at(&q[k]), w, cands(k));
            } else {
                draw_any(&q[k], base + k as u32, cand, touched, (w, h), door);
            }
        }
    }
}

/// Offers candidates `k` to the 2×2 pixels from `i` (row width `w`), in the order (0,0),
/// (1,0), (0,1), (1,1); zero candidates leave a pixel as it was.
#[inline(always)]
fn put_quad(cand: &mut [Cand], i: usize, w: usize, k: [Cand; 4]) {
    // One slice from the pixel to the one below its right neighbour.
    if let Some((a, r)) = cand.get_mut(i..i + w + 2).and_then(|r| r.split_first_chunk_mut::<2>()) {
        if let Some((_, b)) = r.split_last_chunk_mut::<2>() {
            a[0] = a[0].max(k[0]);
            a[1] = a[1].max(k[1]);
            b[0] = b[0].max(k[2]);
            b[1] = b[1].max(k[3]);
        }
    }
}

/// Draws splat `index` of any size, clipped to the frame, into a worker's layer.
#[inline(never)]
fn draw_any(s: &Splat, index: u32, cand: &mut [Cand], touched: &mut [bool], (w, h): (usize, usize), door: bool) {
    // NaN and +inf depths never pass a depth test.
    let finite = s.z < f32::INFINITY;
    if !finite {
        return;
    }
    let [x0, x1, y0, y1] = s.bounds.map(i32::from);
    let (xa, xb, ya, yb) = (x0.max(0), x1.min(w as i32 - 1), y0.max(0), y1.min(h as i32 - 1));
    if xa > xb || ya > yb {
        return;
    }
    let opaque = s.color[3] == 255 || !door;
    let x0f = xa as f32 + 0.5 - s.x;
    for py in ya..=yb {
        let dy = py as f32 + 0.5 - s.y;
        let (ay, by) = (dy * s.uy, dy * s.ux);
        let row = py as usize * w;
        // Row slices: no per-pixel bounds checks.
        let Some(crow) = cand.get_mut(row + xa as usize..=row + xb as usize) else { continue };
        if opaque {
            // Without a branch per pixel: a supersampled preview's splats span a few pixels,
            // and whether one holds a pixel is a coin toss at its rim.
            for (k, c) in crow.iter_mut().enumerate() {
                let dx = x0f + k as f32;
                let (a, b) = (dx * s.ux + ay, by - dx * s.uy);
                let q = a * a * s.inv_a2 + b * b * s.inv_b2;
                let m = 0u64.wrapping_sub((q <= 1.0) as u64);
                *c = (*c).max(key(s.z + s.rim * q, index) & m);
            }
            continue;
        }
        for (k, c) in crow.iter_mut().enumerate() {
            let dx = x0f + k as f32;
            let (a, b) = (dx * s.ux + ay, by - dx * s.uy);
            let q = a * a * s.inv_a2 + b * b * s.inv_b2;
            if q <= 1.0 && alpha_passes(s.color[3], xa as usize + k, py as usize) {
                *c = (*c).max(key(s.z + s.rim * q, index));
            }
        }
    }
    for t in touched.iter_mut().take(yb as usize / BAND + 1).skip(ya as usize / BAND) {
        *t = true;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::raster::tests::xorshift;

    /// A half-transparent splat over an opaque one shows their mix in linear light, over
    /// nothing it covers through the screen door unblended, and two overlapping splats of
    /// one translucent surface do not compound their alpha.
    #[test]
    fn translucent_splats_blend_over_the_opaque_surface_once() {
        let lin = crate::shade::srgb_to_linear_lut();
        let (red, blue) = ([255, 0, 0, 255], [0, 0, 255, 128]);
        let mut f = Frame::new(16, 8, [0, 0, 0, 255]);
        let splats = [
            Splat::disc(4.0, 4.0, 2.0, 3.0, red),
            Splat::disc(4.0, 4.0, 1.0, 3.0, blue),
            Splat::disc(4.5, 4.0, 1.0, 3.0, blue),
            Splat::disc(12.0, 4.0, 1.0, 3.0, blue),
        ];
        rasterize_blended(&mut f, &splats);
        let a = 128.0 / 255.0;
        let want = [crate::shade::linear_to_srgb8((1.0 - a) * lin[255]), 0, crate::shade::linear_to_srgb8(a * lin[255])];
        let c = f.color[4 * 16 + 4];
        assert_eq!([c[0], c[1], c[2]], want, "blended once, in linear light");
        assert_eq!(f.depth[4 * 16 + 4], 1.0);
        // Over the background: the pixels the screen door passes, in the splat's colour.
        let (mut shown, mut pixels) = (0, 0);
        Splat::disc(12.0, 4.0, 1.0, 3.0, blue).for_each_pixel(16, 8, |i| {
            pixels += 1;
            if f.depth[i].is_finite() {
                shown += 1;
                assert_eq!(f.color[i], [0, 0, 255, 255]);
            } else {
                assert_eq!(f.color[i], [0, 0, 0, 255]);
            }
        });
        assert!(shown > pixels / 4 && shown < pixels * 3 / 4, "{shown} of {pixels}");
        // Opaque splats alone draw as `rasterize` draws them.
        let mut g = Frame::new(16, 8, [0, 0, 0, 255]);
        let mut h = g.clone();
        rasterize_blended(&mut g, &splats[..1]);
        rasterize(&mut h, &splats[..1]);
        assert_eq!(g, h);
    }

    /// Two coplanar overlapping discs split their overlap at the bisector (each pixel goes
    /// to the nearer centre) instead of the first drawn taking all of it.
    #[test]
    fn coplanar_splats_split_their_overlap_by_the_rim_depth() {
        for first in [0usize, 1] {
            let mut f = Frame::new(16, 4, [0; 4]);
            let mut s = [Splat::disc(5.0, 2.0, 1.0, 4.0, [1, 0, 0, 255]), Splat::disc(11.0, 2.0, 1.0, 4.0, [2, 0, 0, 255])];
            for sp in &mut s {
                sp.rim = 0.01;
            }
            if first == 1 {
                s.swap(0, 1);
            }
            rasterize(&mut f, &s);
            for x in 2..14 {
                let want = if (x as f32 + 0.5) < 8.0 { 1 } else { 2 };
                assert_eq!(f.color[16 + x][0], want, "pixel {x}, drawn first: {first}");
            }
        }
    }

    #[test]
    fn nearest_wins_and_ties_keep_first() {
        let mut f = Frame::new(8, 8, [0; 4]);
        rasterize(
            &mut f,
            &[
                Splat::disc(4.0, 4.0, 2.0, 2.0, [1, 0, 0, 255]),
                Splat::disc(4.0, 4.0, 1.0, 1.0, [2, 0, 0, 255]),
                Splat::disc(4.0, 4.0, 1.0, 1.0, [3, 0, 0, 255]),
            ],
        );
        assert_eq!(f.color[4 * 8 + 4][0], 2);
        assert_eq!(f.color[2 * 8 + 4][0], 1);
    }

    /// The rasterizer's contract drawn the plain way: splat after splat, every pixel centre
    /// of the clipped box tested, strictly nearer wins.
    fn naive(f: &mut Frame, splats: &[Splat]) {
        for s in splats {
            let [x0, x1, y0, y1] = s.bounds.map(i32::from);
            let (xa, xb, ya, yb) = (x0.max(0), x1.min(f.width as i32 - 1), y0.max(0), y1.min(f.height as i32 - 1));
            for py in ya..=yb {
                let dy = py as f32 + 0.5 - s.y;
                for (k, px) in (xa..=xb).enumerate() {
                    let dx = (xa as f32 + 0.5 - s.x) + k as f32;
                    let (a, b) = (dx * s.ux + dy * s.uy, dy * s.ux - dx * s.uy);
                    let i = py as usize * f.width + px as usize;
                    if a * a * s.inv_a2 + b * b * s.inv_b2 <= 1.0 && s.z < f.depth[i] && alpha_passes(s.color[3], px as usize, py as usize) {
                        f.depth[i] = s.z;
                        f.color[i] = s.color;
                    }
                }
            }
        }
    }

    #[test]
    fn matches_the_plain_drawing_on_every_path() {
        let mut rnd = xorshift(777);
        // Mostly sub-2-pixel splats (the fast path), some large, thin, translucent, off the
        // edges, with tied and special depths, over a frame that already holds some depth.
        let mut splats = Vec::new();
        for i in 0..60_000u32 {
            let (x, y) = (rnd() * 70.0 - 5.0, rnd() * 50.0 - 5.0);
            let z = match i % 97 {
                0 => f32::NAN,
                1 => f32::INFINITY,
                2 => -0.0,
                3 => -1.0,
                _ => (rnd() * 6.0).floor(),
            };
            let r = if i % 50 == 0 { rnd() * 6.0 } else { rnd() * 1.2 };
            let a = if i % 7 == 0 { (rnd() * 255.0) as u8 } else { 255 };
            let c = [(i % 251) as u8, (i / 251 % 251) as u8, (i % 13) as u8, a];
            let t = rnd() * 6.3;
            splats.push(if i % 3 == 0 { Splat::ellipse(x, y, z, r, r * rnd(), t.cos(), t.sin(), c) } else { Splat::disc(x, y, z, r, c) });
        }
        let mut want = Frame::new(64, 40, [1, 2, 3, 255]);
        for i in (0..want.depth.len()).step_by(5) {
            want.depth[i] = (i % 4) as f32;
        }
        let mut got = want.clone();
        naive(&mut want, &splats);
        rasterize(&mut got, &splats);
        assert!(want.covered() > 1000);
        assert_eq!(got, want);
        // Again, reusing the kept layers, on a frame of another size.
        let (mut want, mut got) = (Frame::new(33, 71, [0; 4]), Frame::new(33, 71, [0; 4]));
        naive(&mut want, &splats);
        rasterize(&mut got, &splats);
        assert_eq!(got, want);
    }

    #[test]
    fn kept_buffers_do_not_leak_into_the_next_frame() {
        // Colours and layers are kept between calls: a smaller set of splats with other
        // colours, then the first again, must each draw exactly their own image.
        let mut rnd = xorshift(99);
        let big: Vec<Splat> = (0..20_000).map(|i| Splat::disc(rnd() * 40.0, rnd() * 30.0, (rnd() * 4.0).floor(), rnd() * 1.5, [1, (i % 200) as u8, 3, 255])).collect();
        let small: Vec<Splat> = big.iter().take(5_001).map(|s| Splat { color: [9, s.color[1], 9, 255], ..*s }).collect();
        for splats in [&big, &small, &big] {
            let (mut want, mut got) = (Frame::new(40, 30, [0; 4]), Frame::new(40, 30, [0; 4]));
            naive(&mut want, splats);
            rasterize(&mut got, splats);
            assert_eq!(got, want);
        }
    }

    #[test]
    fn splats_across_tiles_and_clipping_are_deterministic() {
        let mut splats = Vec::new();
        let mut rnd = xorshift(12345);
        for i in 0..50_000 {
            let c = [(i % 251) as u8, (i % 13) as u8, 7, 255];
            splats.push(Splat::disc(rnd() * 120.0 - 10.0, rnd() * 90.0 - 10.0, (rnd() * 8.0).floor(), rnd() * 4.0, c));
        }
        let mut a = Frame::new(100, 70, [0; 4]);
        rasterize(&mut a, &splats);
        let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
        let mut b = Frame::new(100, 70, [0; 4]);
        pool.install(|| rasterize(&mut b, &splats));
        assert_eq!(a, b);
    }
}
