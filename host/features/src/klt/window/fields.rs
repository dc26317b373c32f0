//! The clipped prediction's three fields (docs/VISION.md §5, eqs. 5.6, 5.7): the unsmoothed
//! template sampled where a window grid's points fall at level 0, clipped as the camera clips,
//! then smoothed and reduced as the pyramid was, for [`super::Window`]'s normal
//! equations where the live image is clipped.

use wide::f32x4;

use super::{LANES, fill_bilinear, v4};
use crate::gray::GrayF32;
use crate::pyramid::reflect101;

/// The template's level 0 before its smoothing, for the clipped prediction (eq. 5.6).
#[derive(Clone, Copy)]
pub(crate) struct Pre<'a> {
    /// The unsmoothed image.
    pub img: &'a GrayF32,
    /// The smoothing's half kernel (`gaussian_kernel`).
    pub kernel: &'a [f32],
    /// The pyramid level of the window.
    pub level: usize,
    /// The template grid's centre, px of that level.
    pub gx: f64,
    pub gy: f64,
}

/// The level-0 support of an `n`-point window grid from `origin` (one axis, px of pyramid
/// level `level`): its first sample position and its number of samples, at unit spacing. Pixel
/// `X` of a level is the binomial over `2X − 2 ..= 2X + 2` of the one below, then the
/// Gaussian's radius `rr`. `None` for levels too deep to be real.
fn support(origin: f64, n: usize, level: usize, rr: usize) -> Option<(f64, usize)> {
    let s = 1usize
        .checked_shl(u32::try_from(level).ok()?)
        .filter(|&s| s <= 1 << 12)?;
    let start = s as f64 * origin - 2.0 * (s - 1) as f64 - rr as f64;
    Some((start, s * n.checked_sub(1)? + 4 * (s - 1) + 2 * rr + 1))
}

/// The 1-D kernel of `D_k G` (the Gaussian with half kernel `half`, then `level` binomials each
/// followed by dropping every second pixel): output `X` of level `level` is
/// `Σ_t K[t] v[2^level X + t]` along each axis of the samples `v` of the support. The
/// reduction is linear and separable, so one kernel with stride `2^level` gives what the
/// pyramid's cascade gives, computing only the window's pixels of each stage's output.
fn level_kernel(half: &[f32], level: usize) -> Vec<f32> {
    let rr = half.len().saturating_sub(1);
    let mut k: Vec<f32> = (0..=2 * rr).map(|t| half[t.abs_diff(rr)]).collect();
    let binomial = [1.0 / 16.0, 4.0 / 16.0, 6.0 / 16.0, 4.0 / 16.0, 1.0 / 16.0];
    for i in 0..level {
        let gap = 1 << i;
        let mut next = vec![0f32; k.len() + 4 * gap];
        for (l, &bl) in binomial.iter().enumerate() {
            for (o, &v) in next[l * gap..].iter_mut().zip(&k) {
                *o += bl * v;
            }
        }
        k = next;
    }
    k
}

/// The clipped prediction's buffers and the per-level values it needs (eqs. 5.6, 5.7), kept
/// across the iterations of one registration.
#[derive(Default)]
pub(super) struct ClipScratch {
    /// The level and the rounded grid centre the kernel and extremes belong to.
    key: Option<(usize, [f64; 2])>,
    /// [`level_kernel`] of that level.
    kernel: Vec<f32>,
    /// `[min, max]` of `I₀` over the supports of every window grid of the level (eq. 5.7).
    pub(super) extremes: [f32; 2],
    /// `I₀` sampled on the support.
    v: Vec<f32>,
    /// One support row of each of the three fields.
    rows: [Vec<f32>; 3],
    /// The fields after the vertical pass: `n` rows of the support's width.
    cols: [Vec<f32>; 3],
}

impl ClipScratch {
    /// Sets the kernel and `I₀`'s extremes for the level of `pre` (once per level).
    pub(super) fn prepare(&mut self, pre: &Pre<'_>, r: usize) {
        let centre = [pre.gx.round(), pre.gy.round()];
        if self.key == Some((pre.level, centre)) {
            return;
        }
        self.key = Some((pre.level, centre));
        self.kernel = level_kernel(pre.kernel, pre.level);
        self.extremes =
            support_extremes(pre, centre, r).unwrap_or([f32::INFINITY, f32::NEG_INFINITY]);
    }

    /// The three fields of the clipped prediction (eq. 5.6) on the `n × n` window grid from
    /// `origin` (px of pyramid level `pre.level`) into `out` (rows of `stride`): `clip(a I₀ + b)`,
    /// `I₀ · 1[inside]` and `1[inside]` on the unsmoothed template sampled (bilinearly) where
    /// the grid's points fall at level 0, then smoothed and reduced as the pyramid was
    /// ([`level_kernel`]). The clip acts on the template at the live pixels' sub-pixel
    /// positions, as the camera's does on the scene; beyond the image border, the pyramid's
    /// reflect-101 border. `false` for a position far outside. Call [`ClipScratch::prepare`]
    /// first.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn fields(
        &mut self,
        pre: &Pre<'_>,
        origin: [f64; 2],
        n: usize,
        ab: [f32; 2],
        range: [f32; 2],
        out: [&mut [f32]; 3],
        stride: usize,
    ) -> bool {
        let rr = pre.kernel.len().saturating_sub(1);
        let (Some((x0, pn)), Some((y0, _))) = (
            support(origin[0], n, pre.level, rr),
            support(origin[1], n, pre.level, rr),
        ) else {
            return false;
        };
        let kl = self.kernel.len();
        let step = 1usize << pre.level;
        if kl == 0 || step * (n - 1) + kl != pn || out.iter().any(|o| o.len() < n * stride) {
            return false;
        }
        self.v.resize(pn * pn, 0.0);
        if !fill_bilinear(pre.img, x0, y0, pn, pn, pn, &mut self.v)
            && !fill_reflected(pre.img, x0, y0, pn, &mut self.v)
        {
            return false;
        }
        for f in &mut self.rows {
            f.resize(pn, 0.0);
        }
        for c in &mut self.cols {
            c.clear();
            c.resize(n * pn, 0.0);
        }
        let [r0, r1, r2] = &mut self.rows;
        for (y, vrow) in self.v.chunks_exact(pn).enumerate() {
            field_row(vrow, [&mut r0[..], &mut r1[..], &mut r2[..]], ab, range);
            // The vertical pass: the outputs `Y` whose kernel covers row `y`,
            // `step·Y ≤ y < step·Y + kl`.
            let last = (y / step).min(n - 1);
            let first = (y + 1).saturating_sub(kl).div_ceil(step);
            for yy in first..=last {
                let w = self.kernel[y - step * yy];
                for (c, row) in self.cols.iter_mut().zip([&*r0, &*r1, &*r2]) {
                    for (o, &v) in c[yy * pn..(yy + 1) * pn].iter_mut().zip(row) {
                        *o += w * v;
                    }
                }
            }
        }
        // The horizontal pass.
        for (c, o) in self.cols.iter().zip(out) {
            for (crow, orow) in c.chunks_exact(pn).zip(o.chunks_exact_mut(stride)) {
                for (x, ov) in orow[..n].iter_mut().enumerate() {
                    *ov = dot(&self.kernel, &crow[step * x..step * x + kl]);
                }
            }
        }
        true
    }
}

/// One support row `x` of the three fields of [`ClipScratch::fields`] into `out`:
/// `clip(a x + b)`, `x · 1[inside]`, `1[inside]`, four samples at a time without branches.
fn field_row(x: &[f32], out: [&mut [f32]; 3], ab: [f32; 2], range: [f32; 2]) {
    let ([a, b], [lo, hi]) = (ab, range);
    let [f0, f1, f2] = out;
    let (av, bv) = (f32x4::splat(a), f32x4::splat(b));
    let (lov, hiv) = (f32x4::splat(lo), f32x4::splat(hi));
    let mut xs = x.chunks_exact(LANES);
    let (mut o0, mut o1, mut o2) = (
        f0.chunks_exact_mut(LANES),
        f1.chunks_exact_mut(LANES),
        f2.chunks_exact_mut(LANES),
    );
    for (((xc, c0), c1), c2) in (&mut xs).zip(&mut o0).zip(&mut o1).zip(&mut o2) {
        let xv = v4(xc);
        let q = av * xv + bv;
        // All bits set where inside: `&` keeps `x` (or 1) there and gives 0 elsewhere.
        let inside = q.simd_gt(lov) & q.simd_lt(hiv);
        c0.copy_from_slice(&q.max(lov).min(hiv).to_array());
        c1.copy_from_slice(&(inside & xv).to_array());
        c2.copy_from_slice(&(inside & f32x4::ONE).to_array());
    }
    let rest = o0.into_remainder().iter_mut();
    let rest = rest.zip(o1.into_remainder()).zip(o2.into_remainder());
    for (&x, ((c0, c1), c2)) in xs.remainder().iter().zip(rest) {
        let q = a * x + b;
        let inside = q > lo && q < hi;
        // max/min rather than `clamp`, which panics on a reversed range.
        *c0 = q.max(lo).min(hi);
        *c1 = if inside { x } else { 0.0 };
        *c2 = if inside { 1.0 } else { 0.0 };
    }
}

/// `Σ a b` in four partial sums, so that it vectorises.
pub(super) fn dot(a: &[f32], b: &[f32]) -> f32 {
    let mut s = f32x4::ZERO;
    let (ac, bc) = (a.chunks_exact(LANES), b.chunks_exact(LANES));
    let tail: f32 = ac
        .remainder()
        .iter()
        .zip(bc.remainder())
        .map(|(x, y)| x * y)
        .sum();
    for (x, y) in ac.zip(bc) {
        s += v4(x) * v4(y);
    }
    s.reduce_add() + tail
}

/// `[min, max]` of `I₀` (`pre.img`) over the supports of every window grid of the level whose
/// rounded centre is `centre`: every grid lies within 0.375 px of it (`symmetric_grid` with the
/// anchor of `anchor`), so a margin of 0.5 px of the level covers them. Bilinear samples
/// and the kernel's weighted means stay within the pixels' extremes; the box is cut to the
/// image (the reflect-101 border repeats pixels near the border). `None` if nothing is left.
fn support_extremes(pre: &Pre<'_>, centre: [f64; 2], r: usize) -> Option<[f32; 2]> {
    let rr = pre.kernel.len().saturating_sub(1);
    let n = 2 * r + 1;
    let (w, h) = (pre.img.width(), pre.img.height());
    let span = |c: f64, len: usize| -> Option<(usize, usize)> {
        let (first, side) = support(c - r as f64 - 0.5, n, pre.level, rr)?;
        let last_start = support(c - r as f64 + 0.5, n, pre.level, rr)?.0;
        let (a, b) = (
            first.floor(),
            (last_start + (side - 1) as f64).floor() + 1.0,
        );
        if !(a.is_finite() && b.is_finite()) || b < 0.0 || a > (len - 1) as f64 {
            return None;
        }
        Some((a.max(0.0) as usize, (b as usize).min(len - 1)))
    };
    let ((xa, xb), (ya, yb)) = (span(centre[0], w)?, span(centre[1], h)?);
    let data = pre.img.data();
    let mut e = [f32::INFINITY, f32::NEG_INFINITY];
    for y in ya..=yb {
        for &v in &data[y * w + xa..=y * w + xb] {
            e = [e[0].min(v), e[1].max(v)];
        }
    }
    Some(e)
}

/// Bilinear samples of `img` at `(x0 + i, y0 + j)`, `i, j < side`, into `out` (rows of
/// `side`), the pyramid's reflect-101 border beyond the image. `false` for a position far
/// outside.
fn fill_reflected(img: &GrayF32, x0: f64, y0: f64, side: usize, out: &mut [f32]) -> bool {
    let (fx, fy) = (x0.floor(), y0.floor());
    let limit = 4.0 * (img.width() + img.height()) as f64;
    if !(fx.abs() < limit && fy.abs() < limit) || out.len() < side * side {
        return false;
    }
    let (tx, ty) = ((x0 - fx) as f32, (y0 - fy) as f32);
    let (w, h, data) = (img.width(), img.height(), img.data());
    // The reflected columns and rows once, not per sample.
    let index = |f: f64, n: usize| -> Vec<usize> {
        (0..=side as isize)
            .map(|k| reflect101(f as isize + k, n))
            .collect()
    };
    let (cols, rows) = (index(fx, w), index(fy, h));
    for (row, r) in out.chunks_exact_mut(side).zip(rows.windows(2)) {
        let (above, below) = (
            &data[r[0] * w..(r[0] + 1) * w],
            &data[r[1] * w..(r[1] + 1) * w],
        );
        for (o, c) in row.iter_mut().zip(cols.windows(2)) {
            let top = above[c[0]] + tx * (above[c[1]] - above[c[0]]);
            let bottom = below[c[0]] + tx * (below[c[1]] - below[c[0]]);
            *o = top + ty * (bottom - top);
        }
    }
    true
}
