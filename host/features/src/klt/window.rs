//! The registration window's samples and the normal equations over them, the hot loop of the
//! KLT (docs/VISION.md §5).
//!
//! The model is a pure translation, so every sample of a window has the same sub-pixel
//! fraction: a window inside the image is a bilinear blend of four shifted row slices with
//! four weights, with no per-sample bounds test or `Option`. The rows are padded to a
//! multiple of four samples and the normal equations are accumulated four pixels at a time
//! (`wide::f32x4`), each pixel weighted 1 (used) or 0 (masked, clipped, outside, padding), so
//! the loop has no branch. Per-lane `f32` sums (≤ ¼ of the window each) are added in `f64`.
//! Windows that cross the image border take the per-sample path.

mod fields;

use wide::f32x4;

use super::super::gray::{GrayF32, Mask};
use super::clip::ClipLevel;
use fields::ClipScratch;
pub(super) use fields::Pre;

/// Lanes per accumulation step.
const LANES: usize = 4;

/// One pass over the window at the current parameters (see `accumulate`).
pub(super) struct Normal {
    /// `Σ g gᵀ`, `g = [∂ₓJ, ∂ᵧJ, −I, −1]`.
    pub h: [[f64; 4]; 4],
    /// `−Σ g ρ`.
    pub b: [f64; 4],
    /// `Σ ρ²`.
    pub ssd: f64,
    /// Pixels in the window: used, or censored (they agree with the model, eq. 5.6).
    pub count: usize,
    /// Pixels used, `Σ w` (the censored ones left out).
    pub used: f64,
    /// Template pixels whose live samples left the image.
    pub outside: usize,
    /// `Σ I`, `Σ I²` over the pixels used.
    pub sum_i: f64,
    pub sum_i2: f64,
}

/// The window's buffers, reused across the iterations and levels of one registration.
pub(super) struct Window {
    r: usize,
    side: usize,
    /// Padded row length of the template-sized arrays (a multiple of [`LANES`]).
    pw: usize,
    /// Row length of the live samples: `pw + 4` (a one-sample rim for the gradient, and whole
    /// lanes).
    es: usize,
    /// Template values, `side × pw`, 0 where not valid.
    pub t: Vec<f32>,
    /// Template validity as weights 1 / 0.
    tw: Vec<f32>,
    /// Valid template pixels.
    pub tcount: usize,
    /// Live samples on the window grid and its rim, `(side + 2) × es`, finite (0 outside).
    pub ext: Vec<f32>,
    /// Pixels used: template valid and the five live samples inside the image.
    w: Vec<f32>,
    /// Whether `tw` holds the all-valid weights.
    tw_full: bool,
    /// Whether the live samples leave every template pixel usable (then `w` is stale and
    /// `tw` holds the weights, see [`Window::weights`]).
    live_all: bool,
    /// Whether the camera's clipping reaches the live samples (see `clip`); then `range`
    /// holds the clip levels.
    clip_any: bool,
    range: [f32; 2],
    /// Whether the last [`Window::accumulate`] used the clipped prediction (eq. 5.6): then
    /// `p` holds the prediction and `pa`, `pb` its derivatives in `a` and `b`.
    clip_model: bool,
    p: Vec<f32>,
    pa: Vec<f32>,
    pb: Vec<f32>,
    clip: ClipScratch,
    pub count: usize,
    pub outside: usize,
}

impl Window {
    pub fn new(r: usize) -> Self {
        let side = 2 * r + 1;
        let pw = side.div_ceil(LANES) * LANES;
        // The rim and room to sample whole lanes (see `fill_bilinear`).
        let es = pw + LANES;
        Self {
            r,
            side,
            pw,
            es,
            t: vec![0.0; side * pw],
            tw: vec![0.0; side * pw],
            tcount: 0,
            ext: vec![0.0; (side + 2) * es],
            w: vec![0.0; side * pw],
            tw_full: false,
            live_all: false,
            clip_any: false,
            range: [0.0, 0.0],
            clip_model: false,
            p: vec![0.0; side * pw],
            pa: vec![0.0; side * pw],
            pb: vec![0.0; side * pw],
            clip: ClipScratch::default(),
            count: 0,
            outside: 0,
        }
    }

    /// The weights (1 used, 0 not) of the pixels, `side × pw`, after [`Window::sample_live`].
    pub fn weights(&self) -> &[f32] {
        if self.live_all { &self.tw } else { &self.w }
    }

    pub fn side(&self) -> usize {
        self.side
    }

    /// Index of pixel `(i, j)` in the template-sized arrays.
    #[inline]
    pub fn at(&self, i: usize, j: usize) -> usize {
        j * self.pw + i
    }

    /// Index of pixel `(i, j)`'s live sample in [`Window::ext`].
    #[inline]
    pub fn ext_at(&self, i: usize, j: usize) -> usize {
        (j + 1) * self.es + i + 1
    }

    /// Row stride of [`Window::ext`].
    pub fn ext_stride(&self) -> usize {
        self.es
    }

    /// The template window centred on the grid point `(gx, gy)`: valid where the image has
    /// it and `mask` is valid for the bilinear sample.
    pub fn sample_template(&mut self, img: &GrayF32, mask: Option<&Mask>, gx: f64, gy: f64) {
        let (ox, oy) = (gx - self.r as f64, gy - self.r as f64);
        let (side, pw) = (self.side, self.pw);
        let inside = fill_bilinear(img, ox, oy, side, side, pw, &mut self.t);
        if inside && mask.is_none_or(|m| mask_all_valid(m, ox, oy, side, side)) {
            // The common case: all valid, no per-pixel test (the weights are refilled only
            // after a window that was not).
            if !self.tw_full {
                for row in self.tw.chunks_exact_mut(pw) {
                    row[..side].fill(1.0);
                    row[side..].fill(0.0);
                }
                self.tw_full = true;
            }
            self.tcount = side * side;
            return;
        }
        self.tw_full = false;
        self.tcount = 0;
        if let (true, Some(m)) = (inside, mask) {
            self.mask_rows(m, ox, oy);
            return;
        }
        for j in 0..side {
            for i in 0..pw {
                let k = j * pw + i;
                let (x, y) = (ox + i as f64, oy + j as f64);
                let mut valid = i < side && mask.is_none_or(|m| m.valid_bilinear(x, y));
                if valid && !inside {
                    match img.sample(x, y) {
                        Some(v) => self.t[k] = v,
                        None => valid = false,
                    }
                }
                if valid {
                    self.tw[k] = 1.0;
                    self.tcount += 1;
                } else {
                    self.tw[k] = 0.0;
                    self.t[k] = 0.0;
                }
            }
        }
    }

    /// The template weights of a window inside the image that the mask covers only in part
    /// (origin `(ox, oy)`): a sample is valid where every pixel it interpolates is
    /// (`Mask::valid_bilinear`), read from whole rows of the mask rather than per sample.
    fn mask_rows(&mut self, m: &Mask, ox: f64, oy: f64) {
        let (side, pw) = (self.side, self.pw);
        let (x0, y0) = (ox.floor(), oy.floor());
        // The right and lower neighbours count only with a fractional offset (`ceil`).
        let (dx, dy) = (usize::from(ox > x0), usize::from(oy > y0));
        let (x0, y0, w) = (x0 as usize, y0 as usize, m.width());
        let data = m.data();
        for (j, (t, tw)) in self
            .t
            .chunks_exact_mut(pw)
            .zip(self.tw.chunks_exact_mut(pw))
            .take(side)
            .enumerate()
        {
            // `fill_bilinear` succeeded: rows `y0 ..= y0 + side` and columns
            // `x0 ..= x0 + side` are inside the image, and the mask has its size.
            let row = |y: usize| data.get(y * w + x0..y * w + x0 + side + dx);
            let (Some(top), Some(bottom)) = (row(y0 + j), row(y0 + j + dy)) else {
                t.fill(0.0);
                tw.fill(0.0);
                continue;
            };
            for (i, (t, tw)) in t.iter_mut().zip(tw.iter_mut()).enumerate() {
                let valid = i < side && top[i] && top[i + dx] && bottom[i] && bottom[i + dx];
                *tw = if valid { 1.0 } else { 0.0 };
                if !valid {
                    *t = 0.0;
                }
                self.tcount += usize::from(valid);
            }
        }
    }

    /// The live samples for the window centred on `(cx, cy)` (the template grid plus the
    /// displacement), and which pixels they leave usable: those valid in the template whose
    /// five samples are inside the image. `clip`: the level's clip map (see
    /// [`Window::clip_reach`]).
    pub fn sample_live(&mut self, img: &GrayF32, clip: Option<&ClipLevel>, cx: f64, cy: f64) {
        self.fill_live(img, cx, cy);
        self.clip_any = false;
        if let Some(c) = clip {
            self.clip_reach(c, cx, cy);
        }
    }

    /// Whether the camera's clipping reaches any of the window's live samples: a flagged
    /// pixel among the four one interpolates. The block summary skips the windows far from
    /// any clipping.
    fn clip_reach(&mut self, clip: &ClipLevel, cx: f64, cy: f64) {
        let (r, side) = (self.r as f64, self.side);
        let (fx, fy) = ((cx - r).floor(), (cy - r).floor());
        if !(fx.is_finite() && fy.is_finite()) {
            return;
        }
        let (x1, y1) = (fx + side as f64, fy + side as f64);
        if x1 < 0.0 || y1 < 0.0 {
            return;
        }
        let lo = |v: f64| v.max(0.0) as usize;
        if !clip.any_in(lo(fx), lo(fy), x1 as usize, y1 as usize) {
            return;
        }
        let at = |x: f64, y: f64| {
            if x < 0.0 || y < 0.0 {
                0
            } else {
                clip.get(x as usize, y as usize)
            }
        };
        let hit = |j: usize, i: usize| {
            let (x, y) = (fx + i as f64, fy + j as f64);
            at(x, y) | at(x + 1.0, y) | at(x, y + 1.0) | at(x + 1.0, y + 1.0) != 0
        };
        if (0..side).any(|j| (0..side).any(|i| hit(j, i))) {
            self.clip_any = true;
            self.range = clip.range();
        }
    }

    fn fill_live(&mut self, img: &GrayF32, cx: f64, cy: f64) {
        let (r, side, pw, es) = (self.r as f64, self.side, self.pw, self.es);
        let (ox, oy) = (cx - r - 1.0, cy - r - 1.0);
        if fill_bilinear(img, ox, oy, side + 2, side + 2, es, &mut self.ext) {
            // The template's weights are the pixels used: no copy.
            self.live_all = true;
            self.count = self.tcount;
            self.outside = 0;
            return;
        }
        self.live_all = false;
        for j in 0..side + 2 {
            for i in 0..es {
                self.ext[j * es + i] = if i < side + 2 {
                    img.sample(ox + i as f64, oy + j as f64).unwrap_or(f32::NAN)
                } else {
                    0.0
                };
            }
        }
        self.count = 0;
        self.outside = 0;
        for j in 0..side {
            for i in 0..pw {
                let k = j * pw + i;
                if self.tw[k] == 0.0 {
                    self.w[k] = 0.0;
                    continue;
                }
                let e = (j + 1) * es + i + 1;
                let taps = [
                    self.ext[e],
                    self.ext[e - 1],
                    self.ext[e + 1],
                    self.ext[e - es],
                    self.ext[e + es],
                ];
                let usable = !taps.iter().any(|v| v.is_nan());
                self.outside += usize::from(!usable);
                self.w[k] = if usable { 1.0 } else { 0.0 };
                self.count += usize::from(usable);
            }
        }
        // Finite everywhere, so that a weight 0 makes a term 0.
        self.ext
            .iter_mut()
            .filter(|v| v.is_nan())
            .for_each(|v| *v = 0.0);
    }

    /// Accumulates the normal equations for `α = [d₁, d₂, a, b]`, the residual
    /// `ρ = J(m + d) − a I(m) − b` (docs/VISION.md §5; the module documentation of `klt`
    /// says why the residual is in live-image units). Where the camera's clipping reaches the
    /// window and the prediction passes a clip level, the prediction is clipped (eq. 5.6, see
    /// [`Window::clipped_prediction`]; `pre` as there).
    pub fn accumulate(&mut self, a: f64, b: f64, pre: Option<Pre<'_>>) -> Normal {
        let (side, pw, es) = (self.side, self.pw, self.es);
        let (av, bv) = (a as f32, b as f32);
        self.clip_model = match pre {
            Some(pre) if self.clip_any => self.clipped_prediction(a, b, pre),
            _ => false,
        };
        if self.clip_model {
            return self.accumulate_clipped();
        }
        let v = sums(&self.ext, &self.t, self.weights(), [side, pw, es], av, bv);
        // Every pixel used: Σ w, Σ I and Σ I² are the Jacobian's own sums.
        self.normal(&v, v[9], v[8], v[7])
    }

    /// Whether the last [`Window::accumulate`] used the clipped prediction.
    pub fn clip_model(&self) -> bool {
        self.clip_model
    }

    /// The derivatives of the prediction in `a` and `b` at pixel `k`: `(I, 1)`, or those of
    /// the clipped prediction (eq. 5.6) if the last [`Window::accumulate`] used it.
    #[inline]
    pub fn ab_jacobian(&self, k: usize) -> (f32, f32) {
        if self.clip_model {
            (self.pa[k], self.pb[k])
        } else {
            (self.t[k], 1.0)
        }
    }

    /// The clipped prediction `P = D G ⊛ clip(a I₀ + b)` of eq. 5.6 in `p` with its
    /// derivatives `pa = D G ⊛ (I₀ · 1[inside])`, `pb = D G ⊛ 1[inside]` (`ClipScratch::fields`),
    /// when it differs from `a I + b`: `a I₀ + b` passes a clip level by more than one
    /// quantisation step somewhere in the window's support (eq. 5.7, on `I₀`'s extremes over
    /// the level's supports, `support_extremes`). The smoothed window's extremes fall short of
    /// those (smoothing and reduction shrink them): checked on them, 2.5J − 60 failed on 5.6 %
    /// instead of 0.0 % (`tests/features_klt.rs`). `I₀` is the template before its smoothing
    /// `G` (`pre`).
    fn clipped_prediction(&mut self, a: f64, b: f64, pre: Pre<'_>) -> bool {
        let (side, pw) = (self.side, self.pw);
        let [lo, hi] = self.range;
        let (af, bf) = (a as f32, b as f32);
        self.clip.prepare(&pre, self.r);
        let [imin, imax] = self.clip.extremes;
        let (p0, p1) = (af * imin + bf, af * imax + bf);
        if !(p0.max(p1) > hi + 1.0 || p0.min(p1) < lo - 1.0) {
            return false;
        }
        let origin = [pre.gx - self.r as f64, pre.gy - self.r as f64];
        let out = [&mut self.p[..], &mut self.pa[..], &mut self.pb[..]];
        self.clip
            .fields(&pre, origin, side, [af, bf], self.range, out, pw)
    }

    /// [`Window::accumulate`] with the clipped prediction `p` and its derivatives `pa`, `pb`
    /// (eq. 5.6): `g = [∂ₓJ, ∂ᵧJ, −pa, −pb]`, `ρ = J − p`.
    fn accumulate_clipped(&self) -> Normal {
        let (side, pw, es) = (self.side, self.pw, self.es);
        let half = f32x4::splat(0.5);
        // Σ gx², gx gy, gx pa, gx pb, gy², gy pa, gy pb, pa², pa pb, pb², gx ρ, gy ρ, pa ρ,
        // pb ρ, ρ², n, I, I².
        let mut s = [f32x4::ZERO; 18];
        let weights = self.weights();
        for j in 0..side {
            let e0 = (j + 1) * es + 1;
            for c in (0..pw).step_by(LANES) {
                let at = |r: &[f32], o: usize| v4(&r[o + c..o + c + LANES]);
                let o = j * pw;
                let wv = at(weights, o);
                let gx = (at(&self.ext, e0 + 1) - at(&self.ext, e0 - 1)) * half * wv;
                let gy = (at(&self.ext, e0 + es) - at(&self.ext, e0 - es)) * half * wv;
                let res = (at(&self.ext, e0) - at(&self.p, o)) * wv;
                let (pa, pb) = (at(&self.pa, o), at(&self.pb, o));
                let (paw, pbw) = (pa * wv, pb * wv);
                let iw = at(&self.t, o) * wv;
                s[0] += gx * gx;
                s[1] += gx * gy;
                s[2] += gx * paw;
                s[3] += gx * pbw;
                s[4] += gy * gy;
                s[5] += gy * paw;
                s[6] += gy * pbw;
                s[7] += paw * pa;
                s[8] += paw * pb;
                s[9] += pbw * pb;
                s[10] += gx * res;
                s[11] += gy * res;
                s[12] += paw * res;
                s[13] += pbw * res;
                s[14] += res * res;
                s[15] += wv;
                s[16] += iw;
                s[17] += iw * at(&self.t, o);
            }
        }
        let v = s.map(sum);
        self.normal(&v, v[15], v[16], v[17])
    }

    /// The normal equations from the window's sums `v` (`Σ g gᵀ` in `v[0..10]`, `−Σ g ρ` in
    /// `v[10..14]`, `Σ ρ²` in `v[14]`; `g = [gx, gy, −I, −1]`, whose last two entries the
    /// clipped prediction replaces, eq. 5.6) and the pixels used with their `Σ I`, `Σ I²`.
    fn normal(&self, v: &[f64], used: f64, sum_i: f64, sum_i2: f64) -> Normal {
        Normal {
            h: [
                [v[0], v[1], -v[2], -v[3]],
                [v[1], v[4], -v[5], -v[6]],
                [-v[2], -v[5], v[7], v[8]],
                [-v[3], -v[6], v[8], v[9]],
            ],
            b: [-v[10], -v[11], v[12], v[13]],
            ssd: v[14],
            count: self.count,
            used,
            outside: self.outside,
            sum_i,
            sum_i2,
        }
    }

    /// `λ = σ_I / σ_J`, `δ = Ī − λ J̄` over the pixels used (the paper's initialisation from
    /// the windows' means and standard deviations).
    pub fn init_photometric(&self) -> Option<(f64, f64)> {
        let (side, pw, es) = (self.side, self.pw, self.es);
        let mut s = [f32x4::ZERO; 5];
        let weights = self.weights();
        for j in 0..side {
            let e0 = (j + 1) * es + 1;
            let live = self.ext[e0..e0 + pw].chunks_exact(LANES);
            let t = self.t[j * pw..(j + 1) * pw].chunks_exact(LANES);
            let w = weights[j * pw..(j + 1) * pw].chunks_exact(LANES);
            for ((jv, iv), wv) in live.zip(t).zip(w) {
                let wv = v4(wv);
                let iv = v4(iv) * wv;
                let jv = v4(jv) * wv;
                s[0] += wv;
                s[1] += iv;
                s[2] += iv * iv;
                s[3] += jv;
                s[4] += jv * jv;
            }
        }
        let [n, si, si2, sj, sj2] = s.map(sum);
        if n < 2.0 {
            return None;
        }
        let (mi, mj) = (si / n, sj / n);
        let (vi, vj) = ((si2 / n - mi * mi).max(0.0), (sj2 / n - mj * mj).max(0.0));
        // A flat live window says nothing about contrast: keep λ = 1 and match the means.
        let lambda = if vj > 1e-6 && vi > 1e-6 {
            (vi / vj).sqrt()
        } else {
            1.0
        };
        Some((lambda, mi - lambda * mj))
    }
}

isa::dispatch! {
    /// The sums of [`Window::accumulate`] over the window (`dims`: side, template row length,
    /// live row length), in `f64`: Σ gx², gx gy, gx I, gx, gy², gy I, gy, I², I, n, gx ρ,
    /// gy ρ, I ρ, ρ, ρ².
    fn sums(
        ext: &[f32],
        t: &[f32],
        weights: &[f32],
        dims: [usize; 3],
        a: f32,
        b: f32,
    ) -> [f64; 15] {
        let [side, pw, es] = dims;
        let (av, bv) = (f32x4::splat(a), f32x4::splat(b));
        let half = f32x4::splat(0.5);
        let mut s = [f32x4::ZERO; 15];
        for j in 0..side {
            let e0 = (j + 1) * es + 1;
            let rows = [
                &ext[e0..e0 + pw],
                &ext[e0 - 1..e0 - 1 + pw],
                &ext[e0 + 1..e0 + 1 + pw],
                &ext[e0 - es..e0 - es + pw],
                &ext[e0 + es..e0 + es + pw],
                &t[j * pw..(j + 1) * pw],
                &weights[j * pw..(j + 1) * pw],
            ];
            // The default window (15 px, rows of 16) with the row's four steps unrolled.
            match rows.map(<&[f32; 16]>::try_from) {
                [Ok(jc), Ok(jl), Ok(jr), Ok(ju), Ok(jd), Ok(t), Ok(w)] => {
                    for c in 0..16 / LANES {
                        let at = |r: &[f32; 16]| v4(&r[c * LANES..(c + 1) * LANES]);
                        let v = [at(jc), at(jl), at(jr), at(ju), at(jd), at(t), at(w)];
                        accumulate_lanes(&mut s, v, av, bv, half);
                    }
                }
                _ => {
                    for c in (0..pw).step_by(LANES) {
                        let v = rows.map(|r| v4(&r[c..c + LANES]));
                        accumulate_lanes(&mut s, v, av, bv, half);
                    }
                }
            }
        }
        s.map(sum)
    }
}

/// One step of [`Window::accumulate`]: four pixels' live samples (centre, left, right, up,
/// down), template values and weights.
#[inline(always)]
fn accumulate_lanes(s: &mut [f32x4; 15], v: [f32x4; 7], av: f32x4, bv: f32x4, half: f32x4) {
    let [jc, jl, jr, ju, jd, iv, wv] = v;
    let gx = (jr - jl) * half * wv;
    let gy = (jd - ju) * half * wv;
    let res = (jc - av * iv - bv) * wv;
    let ivw = iv * wv;
    s[0] += gx * gx;
    s[1] += gx * gy;
    s[2] += gx * ivw;
    s[3] += gx;
    s[4] += gy * gy;
    s[5] += gy * ivw;
    s[6] += gy;
    s[7] += ivw * iv;
    s[8] += ivw;
    s[9] += wv;
    s[10] += gx * res;
    s[11] += gy * res;
    s[12] += ivw * res;
    s[13] += res;
    s[14] += res * res;
}

/// A chunk of [`LANES`] values (from `chunks_exact`, so the conversion cannot fail).
#[inline(always)]
fn v4(c: &[f32]) -> f32x4 {
    f32x4::new(c.try_into().unwrap_or_default())
}

/// The lanes' sum in `f64`.
#[inline(always)]
fn sum(v: f32x4) -> f64 {
    v.to_array().iter().map(|&x| x as f64).sum()
}

isa::dispatch! {
    /// Bilinear samples of `img` at `(ox + i, oy + j)`, `i < cols`, `j < rows`, into rows of
    /// `stride` values of `out`, if every sample's four pixels are inside the image (returns
    /// `false` and leaves `out` to the caller otherwise). Same arithmetic as `GrayF32::sample`.
    fn fill_bilinear(
        img: &GrayF32,
        ox: f64,
        oy: f64,
        cols: usize,
        rows: usize,
        stride: usize,
        out: &mut [f32],
    ) -> bool {
        let (w, h) = (img.width(), img.height());
        if !(ox >= 0.0 && oy >= 0.0) {
            return false;
        }
        let (x0, y0) = (ox.floor(), oy.floor());
        let (x0, y0) = (x0 as usize, y0 as usize);
        // The last sample's right and lower neighbours must exist.
        if x0 + cols >= w || y0 + rows >= h || out.len() < rows * stride {
            return false;
        }
        let fx = (ox - x0 as f64) as f32;
        let fy = (oy - y0 as f64) as f32;
        let data = img.data();
        // Whole lanes where the rows and the image have room: the extra samples land in the
        // rows' padding, which carries weight 0.
        let lanes = cols.div_ceil(LANES) * LANES;
        if lanes <= stride && x0 + lanes < w {
            let (vx, vy) = (f32x4::splat(fx), f32x4::splat(fy));
            for (j, o) in out.chunks_exact_mut(stride).take(rows).enumerate() {
                let at = (y0 + j) * w + x0;
                let row = |from: usize| data[from..from + lanes].chunks_exact(LANES);
                let top = row(at).zip(row(at + 1));
                let bottom = row(at + w).zip(row(at + w + 1));
                let chunks = o[..lanes].chunks_exact_mut(LANES).zip(top.zip(bottom));
            for (o, ((a, b), (c, d))) in chunks {
                    let (a, c) = (v4(a), v4(c));
                    let t = a + vx * (v4(b) - a);
                    let u = c + vx * (v4(d) - c);
                    o.copy_from_slice(&(t + vy * (u - t)).to_array());
                }
            }
            return true;
        }
        for (j, o) in out.chunks_exact_mut(stride).take(rows).enumerate() {
            let at = (y0 + j) * w + x0;
            let (a, b) = (&data[at..at + cols], &data[at + 1..at + 1 + cols]);
            let (c, d) = (
                &data[at + w..at + w + cols],
                &data[at + w + 1..at + w + 1 + cols],
            );
            let o = &mut o[..cols];
            for i in 0..cols {
                let top = a[i] + fx * (b[i] - a[i]);
                let bottom = c[i] + fx * (d[i] - c[i]);
                o[i] = top + fy * (bottom - top);
            }
        }
        true
    }
}

/// Whether `m` is valid for every bilinear sample at `(ox + i, oy + j)`, `i < cols`,
/// `j < rows`: all pixels of the rectangle the samples touch.
fn mask_all_valid(m: &Mask, ox: f64, oy: f64, cols: usize, rows: usize) -> bool {
    if !(ox >= 0.0 && oy >= 0.0) {
        return false;
    }
    let (x0, y0) = (ox.floor() as usize, oy.floor() as usize);
    let (x1, y1) = (
        (ox + (cols - 1) as f64).ceil() as usize,
        (oy + (rows - 1) as f64).ceil() as usize,
    );
    if x1 >= m.width() || y1 >= m.height() {
        return false;
    }
    let w = m.width();
    (y0..=y1).all(|y| m.data()[y * w + x0..=y * w + x1].iter().all(|&v| v))
}

#[cfg(test)]
mod tests;
