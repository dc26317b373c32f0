//! Gaussian image pyramids (factor 2) for coarse-to-fine registration, the matching validity
//! mask pyramid, and the blur applied to the rendering against aliasing (docs/VISION.md §2).
//!
//! Level `k + 1` is level `k` smoothed with the 5-tap binomial kernel `[1 4 6 4 1] / 16` and
//! sampled at its even pixels (as OpenCV's `pyrDown`). With integer pixel centres this makes
//! level-`k` coordinates exactly level-0 coordinates divided by `2^k`.

use wide::f32x8;

use super::gray::{GrayF32, ImageError, Mask};
use super::klt::clip::ClipMap;

pub mod reference;
mod support;

use support::{Rect, blur_within, erode_within, image_support, mask_support};

/// No level smaller than this on either side is built (a registration window would not fit).
pub const MIN_LEVEL_SIDE: usize = 8;

/// Reflect-101 border index (`… 2 1 | 0 1 2 … n−1 | n−2 …`), as OpenCV's default border.
#[inline]
pub(crate) fn reflect101(i: isize, n: usize) -> usize {
    if n == 1 {
        return 0;
    }
    let n = n as isize;
    let mut i = i;
    // Loops only for kernels wider than the image; bounded by the kernel radius.
    while i < 0 || i >= n {
        i = if i < 0 { -i } else { 2 * n - 2 - i };
    }
    i as usize
}

/// Lanes of the vectorised passes: two SSE2 registers (one AVX register where enabled), so
/// that each tap is two independent multiply-adds.
const LANES: usize = 8;

/// Widest kernel radius the vectorised passes take (σ ≤ 5.33 px); wider ones run
/// [`reference`], which gives the same values.
const MAX_RADIUS: usize = 16;

/// Eight values from `s[i..]` (the only bounds check of the load).
#[inline(always)]
fn load(s: &[f32], i: usize) -> f32x8 {
    let a: [f32; LANES] = s[i..i + LANES].try_into().expect("8 values");
    f32x8::new(a)
}

/// Stores eight values at `out[i..]`.
#[inline(always)]
fn store(out: &mut [f32], i: usize, v: f32x8) {
    out[i..i + LANES].copy_from_slice(&v.to_array());
}

/// One output of a horizontal pass at column `x`, reflect-101 indices:
/// `kernel[0]·row[x] + Σ_k kernel[k]·(row[x−k] + row[x+k])`, summed in this order, which is the
/// order of every pass here and in [`reference`] (so the values agree to the last bit).
#[inline]
fn tap_at(row: &[f32], kernel: &[f32], x: usize) -> f32 {
    let w = row.len();
    let mut acc = kernel[0] * row[x];
    for (k, &wk) in kernel.iter().enumerate().skip(1) {
        let k = k as isize;
        acc += wk * (row[reflect101(x as isize - k, w)] + row[reflect101(x as isize + k, w)]);
    }
    acc
}

/// Horizontal pass at every column: reflect-101 at the `r` columns of each border, eight
/// outputs at a time in between (the last chunk overlaps the one before it rather than
/// leaving a scalar tail; the overlapped outputs are computed twice, identically).
#[inline(always)]
fn blur_row(row: &[f32], kernel: &[f32], kv: &[f32x8], out: &mut [f32]) {
    match kernel.len() - 1 {
        1 => blur_row_impl(row, kernel, kv, out, 1),
        2 => blur_row_impl(row, kernel, kv, out, 2),
        3 => blur_row_impl(row, kernel, kv, out, 3),
        4 => blur_row_impl(row, kernel, kv, out, 4),
        5 => blur_row_impl(row, kernel, kv, out, 5),
        6 => blur_row_impl(row, kernel, kv, out, 6),
        r => blur_row_impl(row, kernel, kv, out, r),
    }
}

/// [`blur_row`] for radius `r`; inlined into each arm of its `match`, so that the common radii
/// are constants there and the tap loop unrolls.
#[inline(always)]
fn blur_row_impl(row: &[f32], kernel: &[f32], kv: &[f32x8], out: &mut [f32], r: usize) {
    let w = row.len();
    let kv = &kv[..=r];
    if w < 2 * r + LANES {
        for (x, o) in out.iter_mut().enumerate() {
            *o = tap_at(row, kernel, x);
        }
        return;
    }
    for x in (0..r).chain(w - r..w) {
        out[x] = tap_at(row, kernel, x);
    }
    let last = w - r - LANES;
    let mut x = r;
    loop {
        let xs = x.min(last);
        let mut acc = kv[0] * load(row, xs);
        for (k, &wk) in kv.iter().enumerate().skip(1) {
            acc += wk * (load(row, xs - k) + load(row, xs + k));
        }
        store(out, xs, acc);
        if xs == last {
            break;
        }
        x += LANES;
    }
}

/// Vertical pass over whole rows: `rows` are the `2r + 1` (horizontally filtered) rows around
/// the output row, top first; `out[x] = kernel[0]·rows[r][x] + Σ_k kernel[k]·(rows[r−k][x] +
/// rows[r+k][x])`, eight columns at a time.
#[inline(always)]
fn column_pass(rows: &[&[f32]], kernel: &[f32], kv: &[f32x8], out: &mut [f32]) {
    match kernel.len() - 1 {
        1 => column_pass_impl(rows, kernel, kv, out, 1),
        2 => column_pass_impl(rows, kernel, kv, out, 2),
        3 => column_pass_impl(rows, kernel, kv, out, 3),
        4 => column_pass_impl(rows, kernel, kv, out, 4),
        5 => column_pass_impl(rows, kernel, kv, out, 5),
        6 => column_pass_impl(rows, kernel, kv, out, 6),
        r => column_pass_impl(rows, kernel, kv, out, r),
    }
}

/// [`column_pass`] for radius `r` (a constant in the common arms, as [`blur_row_impl`]); the
/// row slices are cut to the output's width once, so the loads need no further checks.
#[inline(always)]
fn column_pass_impl(rows: &[&[f32]], kernel: &[f32], kv: &[f32x8], out: &mut [f32], r: usize) {
    let w = out.len();
    let kv = &kv[..=r];
    let mut cut: RingRows = [&[]; 2 * MAX_RADIUS + 1];
    for (c, row) in cut.iter_mut().zip(&rows[..=2 * r]) {
        *c = &row[..w];
    }
    let rows = &cut[..=2 * r];
    if w < LANES {
        for (x, o) in out.iter_mut().enumerate() {
            let mut acc = kernel[0] * rows[r][x];
            for (k, &wk) in kernel.iter().enumerate().skip(1) {
                acc += wk * (rows[r - k][x] + rows[r + k][x]);
            }
            *o = acc;
        }
        return;
    }
    let last = w - LANES;
    let mut x = 0;
    loop {
        let xs = x.min(last);
        let mut acc = kv[0] * load(rows[r], xs);
        for (k, &wk) in kv.iter().enumerate().skip(1) {
            acc += wk * (load(rows[r - k], xs) + load(rows[r + k], xs));
        }
        store(out, xs, acc);
        if xs == last {
            break;
        }
        x += LANES;
    }
}

/// The `2r + 1` rows of `ring` (slot of source row `j`: `j mod (2r + 1)`) around output row
/// `y`, reflect-101, top first. The ring holds every row the window needs: reflect-101 indices
/// of `y − r ..= y + r` stay within that range.
#[inline(always)]
fn ring_rows<'a>(ring: &'a [f32], w: usize, h: usize, y: usize, r: usize) -> RingRows<'a> {
    let n = 2 * r + 1;
    let mut rows: RingRows<'a> = [&[]; 2 * MAX_RADIUS + 1];
    for (k, slot) in rows.iter_mut().take(n).enumerate() {
        let j = reflect101(y as isize + k as isize - r as isize, h) % n;
        *slot = &ring[j * w..(j + 1) * w];
    }
    rows
}

/// Row slices of a ring buffer (only the first `2r + 1` are used).
type RingRows<'a> = [&'a [f32]; 2 * MAX_RADIUS + 1];

isa::dispatch! {
    /// Separable blur in place (rows, then columns, as [`reference::gaussian_blur`]): each source
    /// row is filtered horizontally into a ring of `2r + 1` rows (a few kB, stays in L1) just
    /// before the first output row that needs it; output row `y` overwrites source row `y`, which
    /// is already in the ring.
    fn blur_in_place(data: &mut [f32], w: usize, h: usize, kernel: &[f32]) {
        let r = kernel.len() - 1;
        let n = 2 * r + 1;
        let kv: Vec<f32x8> = kernel.iter().map(|&k| f32x8::splat(k)).collect();
        let mut ring = vec![0f32; n * w];
        let mut next = 0;
        for y in 0..h {
            while next <= (y + r).min(h - 1) {
                let slot = next % n;
                blur_row(
                    &data[next * w..(next + 1) * w],
                    kernel,
                    &kv,
                    &mut ring[slot * w..(slot + 1) * w],
                );
                next += 1;
            }
            let rows = ring_rows(&ring, w, h, y, r);
            column_pass(&rows[..n], kernel, &kv, &mut data[y * w..(y + 1) * w]);
        }
    }
}

/// Gaussian blur with standard deviation `sigma` (px), kernel radius `ceil(3σ)`; `sigma ≤ 0`
/// or non-finite returns a copy.
pub fn gaussian_blur(img: &GrayF32, sigma: f32) -> GrayF32 {
    let mut out = img.clone();
    blur_image_in_place(&mut out, sigma);
    out
}

/// [`gaussian_blur`] without a copy (the pyramid owns its base image).
fn blur_image_in_place(img: &mut GrayF32, sigma: f32) {
    match gaussian_kernel(sigma) {
        Some(kernel) if kernel.len() <= MAX_RADIUS + 1 => {
            let (w, h) = (img.width(), img.height());
            blur_in_place(img.data_mut(), w, h, &kernel);
        }
        Some(_) => *img = reference::gaussian_blur(img, sigma),
        None => {}
    }
}

/// The normalised half kernel of [`gaussian_blur`] (`kernel[0]` is the centre tap, radius
/// `ceil(3σ)`); `None` for `sigma ≤ 0` or non-finite.
pub fn gaussian_kernel(sigma: f32) -> Option<Vec<f32>> {
    if !(sigma.is_finite() && sigma > 0.0) {
        return None;
    }
    let r = (3.0 * sigma).ceil().max(1.0) as usize;
    let mut kernel: Vec<f32> = (0..=r)
        .map(|k| (-((k * k) as f32) / (2.0 * sigma * sigma)).exp())
        .collect();
    let sum = kernel[0] + 2.0 * kernel[1..].iter().sum::<f32>();
    kernel.iter_mut().for_each(|v| *v /= sum);
    Some(kernel)
}

/// The blur of the rendered image against aliasing (docs/VISION.md §2): the rendering has hard,
/// aliased texture and silhouette edges the optics of the live camera never produce.
pub fn antialias(rendered: &GrayF32, sigma: f32) -> GrayF32 {
    gaussian_blur(rendered, sigma)
}

/// The pyramid's binomial half kernel `[6 4 1] / 16` (centre first).
const BINOMIAL: [f32; 3] = [6.0 / 16.0, 4.0 / 16.0, 1.0 / 16.0];

/// Horizontal binomial pass at the even columns only (`out[i]` at column `2i`). With the row
/// split into its even `E` and odd `O` samples, `out[i] = k₀·E[i] + k₁·(O[i−1] + O[i]) +
/// k₂·(E[i−1] + E[i+1])`: the terms of [`reference::pyr_down`] in its order, from contiguous
/// loads. `even`, `odd`: scratch of `⌈w/2⌉` and `⌊w/2⌋` values.
#[inline(always)]
fn pyr_row(row: &[f32], kv: &[f32x8; 3], even: &mut [f32], odd: &mut [f32], out: &mut [f32]) {
    let w = row.len();
    let w2 = out.len();
    // Interior: the columns 2i with 2 ≤ 2i ≤ w − 3 (all five taps inside the row).
    let first = 1.min(w2);
    let end = if w > 2 {
        (w - 2).div_ceil(2).clamp(first, w2)
    } else {
        first
    };
    if end - first < LANES {
        for (i, o) in out.iter_mut().enumerate() {
            *o = tap_at(row, &BINOMIAL, 2 * i);
        }
        return;
    }
    for ((p, e), o) in row.chunks_exact(2).zip(even.iter_mut()).zip(odd.iter_mut()) {
        *e = p[0];
        *o = p[1];
    }
    if w % 2 == 1 {
        even[w2 - 1] = row[w - 1];
    }
    out[0] = tap_at(row, &BINOMIAL, 0);
    for (i, o) in out.iter_mut().enumerate().skip(end) {
        *o = tap_at(row, &BINOMIAL, 2 * i);
    }
    let last = end - LANES;
    let mut i = first;
    loop {
        let is = i.min(last);
        let acc = kv[0] * load(even, is)
            + kv[1] * (load(odd, is - 1) + load(odd, is))
            + kv[2] * (load(even, is - 1) + load(even, is + 1));
        store(out, is, acc);
        if is == last {
            break;
        }
        i += LANES;
    }
}

isa::dispatch! {
    /// One pyramid step: binomial smoothing and every second pixel; size `⌈w/2⌉ × ⌈h/2⌉`.
    ///
    /// Only the kept samples are computed: the horizontal pass at the even columns of every row
    /// (into a ring of five rows), the vertical pass at the even rows, both vectorised across the
    /// row; the same sums in the same order as [`reference::pyr_down`].
    pub fn pyr_down(img: &GrayF32) -> GrayF32 {
        let (w, h) = (img.width(), img.height());
        let (w2, h2) = (w.div_ceil(2), h.div_ceil(2));
        let src = img.data();
        let kv = BINOMIAL.map(f32x8::splat);
        let (mut even, mut odd) = (vec![0f32; w2], vec![0f32; w / 2]);
        let mut ring = vec![0f32; 5 * w2];
        let mut out = vec![0f32; w2 * h2];
        let mut next = 0;
        for (y2, o) in out.chunks_exact_mut(w2).enumerate() {
            let y = 2 * y2;
            while next <= (y + 2).min(h - 1) {
                let slot = next % 5;
                pyr_row(
                    &src[next * w..(next + 1) * w],
                    &kv,
                    &mut even,
                    &mut odd,
                    &mut ring[slot * w2..(slot + 1) * w2],
                );
                next += 1;
            }
            let rows = ring_rows(&ring, w2, h, y, 2);
            column_pass(&rows[..5], &BINOMIAL, &kv, o);
        }
        GrayF32::new(w2, h2, out).unwrap_or_else(|_| img.clone())
    }
}

/// A Gaussian pyramid; level 0 is the input, or the input smoothed (see
/// [`Pyramid::build_smoothed`]).
#[derive(Debug, Clone)]
pub struct Pyramid {
    levels: Vec<GrayF32>,
    smoothing: f32,
    /// Where the raw image's clipping reaches the levels (live images, see
    /// [`Pyramid::with_clip`]).
    clip: Option<ClipMap>,
    /// Level 0 before its smoothing and the smoothing's half kernel (templates, see
    /// [`Pyramid::build_keeping_unsmoothed`]).
    unsmoothed: Option<(GrayF32, Vec<f32>)>,
}

impl Pyramid {
    /// Builds up to `levels` levels (at least 1), stopping before a level would be smaller
    /// than [`MIN_LEVEL_SIDE`] on a side.
    pub fn build(base: GrayF32, levels: usize) -> Self {
        Self::build_smoothed(base, levels, 0.0)
    }

    /// As [`Pyramid::build`], with level 0 the input blurred by a Gaussian of `sigma` px
    /// (none for `sigma ≤ 0`). The pyramid remembers `sigma`: the registration's covariance
    /// accounts for the noise correlation the blur introduces.
    pub fn build_smoothed(base: GrayF32, levels: usize, sigma: f32) -> Self {
        let smoothing = if sigma.is_finite() && sigma > 0.0 {
            sigma
        } else {
            0.0
        };
        let mut base = base;
        if smoothing > 0.0 {
            blur_image_in_place(&mut base, smoothing);
        }
        let whole = Rect::whole(base.width(), base.height());
        Self {
            smoothing,
            ..Self::build_within(base, levels, whole)
        }
    }

    /// As [`Pyramid::build`] for a base that is zero outside `support`: each level is
    /// computed only where it can be nonzero ([`support`]), with the same values.
    fn build_within(base: GrayF32, levels: usize, support: Option<Rect>) -> Self {
        let mut support = support;
        let mut out = vec![base];
        while out.len() < levels.max(1) {
            let last = &out[out.len() - 1];
            if last.width().div_ceil(2) < MIN_LEVEL_SIDE
                || last.height().div_ceil(2) < MIN_LEVEL_SIDE
            {
                break;
            }
            let (next, below) = support::pyr_down_within(last, support);
            support = below;
            out.push(next);
        }
        Self {
            levels: out,
            smoothing: 0.0,
            clip: None,
            unsmoothed: None,
        }
    }

    /// As [`Pyramid::build_smoothed`], keeping level 0 before the smoothing: the KLT then
    /// predicts a clipping live camera's smoothed image exactly (docs/VISION.md §5, eq. 5.6).
    pub fn build_keeping_unsmoothed(base: GrayF32, levels: usize, sigma: f32) -> Self {
        let kept = base.clone();
        let mut out = Self::build_smoothed(base, levels, sigma);
        out.unsmoothed = gaussian_kernel(out.smoothing).map(|k| (kept, k));
        out
    }

    /// Level 0 before its smoothing and the smoothing's half kernel, if kept (see
    /// [`Pyramid::build_keeping_unsmoothed`]).
    pub fn unsmoothed(&self) -> Option<(&GrayF32, &[f32])> {
        self.unsmoothed.as_ref().map(|(i, k)| (i, k.as_slice()))
    }

    /// The pyramid with the map of where the raw image's clipped pixels reach its levels
    /// (`None`: no clipped pixel). Built by `KltConfig::target_pyramid`.
    pub fn with_clip(mut self, clip: Option<ClipMap>) -> Self {
        self.clip = clip.filter(|c| {
            self.levels.iter().enumerate().all(|(k, l)| {
                c.level(k)
                    .is_some_and(|m| (m.width(), m.height()) == (l.width(), l.height()))
            })
        });
        self
    }

    /// The clip map given to [`Pyramid::with_clip`].
    pub fn clip(&self) -> Option<&ClipMap> {
        self.clip.as_ref()
    }

    /// The Gaussian σ (px) level 0 was smoothed with; 0 for none.
    pub fn smoothing(&self) -> f32 {
        self.smoothing
    }

    /// Number of levels built.
    pub fn len(&self) -> usize {
        self.levels.len()
    }

    /// Never empty; present for API completeness.
    pub fn is_empty(&self) -> bool {
        self.levels.is_empty()
    }

    /// Level `k` (0 = full resolution).
    pub fn level(&self, k: usize) -> Option<&GrayF32> {
        self.levels.get(k)
    }

    /// All levels, finest first.
    pub fn levels(&self) -> &[GrayF32] {
        &self.levels
    }
}

/// Validity masks matching a [`Pyramid`]: a coarse pixel is valid only if every fine pixel
/// of its 5×5 smoothing support is valid, so that no background leaks into a coarse template.
#[derive(Debug, Clone)]
pub struct MaskPyramid {
    levels: Vec<Mask>,
}

impl MaskPyramid {
    /// Builds `levels` levels (at least 1) with the sizes [`Pyramid::build`] gives.
    pub fn build(base: Mask, levels: usize) -> Self {
        let whole = Rect::whole(base.width(), base.height());
        Self::build_within(base, levels, whole)
    }

    /// As [`MaskPyramid::build`] for a base that is invalid outside `support`, each level
    /// computed only where it can be valid ([`support`]).
    fn build_within(base: Mask, levels: usize, support: Option<Rect>) -> Self {
        let mut support = support;
        let mut out = vec![base];
        while out.len() < levels.max(1) {
            let last = &out[out.len() - 1];
            let (w, h) = (last.width(), last.height());
            let (w2, h2) = (w.div_ceil(2), h.div_ceil(2));
            if w2 < MIN_LEVEL_SIDE || h2 < MIN_LEVEL_SIDE {
                break;
            }
            match support::mask_pyr_down_within(last, support) {
                Some((m, below)) => {
                    support = below;
                    out.push(m);
                }
                None => break,
            }
        }
        Self { levels: out }
    }

    /// Number of levels built.
    pub fn len(&self) -> usize {
        self.levels.len()
    }

    /// Never empty; present for API completeness.
    pub fn is_empty(&self) -> bool {
        self.levels.is_empty()
    }

    /// Level `k`.
    pub fn level(&self, k: usize) -> Option<&Mask> {
        self.levels.get(k)
    }
}

/// A rendering prepared for registration: blurred against aliasing, its pyramid and the
/// mask pyramid from the depth buffer.
#[derive(Debug, Clone)]
pub struct TemplatePyramid {
    /// Intensities.
    pub image: Pyramid,
    /// Where the model was rendered.
    pub mask: MaskPyramid,
}

impl TemplatePyramid {
    /// Blurs `rendered` with `blur_sigma` and builds `levels` levels of image and mask.
    pub fn build(
        rendered: GrayF32,
        mask: Mask,
        levels: usize,
        blur_sigma: f32,
    ) -> Result<Self, ImageError> {
        Self::build_blurred(rendered, mask, levels, [blur_sigma, 0.0], false)
    }

    /// As [`TemplatePyramid::build`], blurred in two steps: the anti-aliasing `antialias`
    /// (the camera's optics, before its clipping), then the registration's `smoothing` (the
    /// live image's, after it). The image between them is kept: the KLT predicts a clipping
    /// live camera from it (docs/VISION.md §5, eq. 5.6; [`Pyramid::build_keeping_unsmoothed`]).
    pub fn build_keeping_unsmoothed(
        rendered: GrayF32,
        mask: Mask,
        levels: usize,
        antialias: f32,
        smoothing: f32,
    ) -> Result<Self, ImageError> {
        Self::build_blurred(rendered, mask, levels, [antialias, smoothing], true)
    }

    /// The template blurred by `blurs` in turn (Gaussians add in variance), keeping the image
    /// after the first where `keep` is set.
    fn build_blurred(
        rendered: GrayF32,
        mask: Mask,
        levels: usize,
        blurs: [f32; 2],
        keep: bool,
    ) -> Result<Self, ImageError> {
        let sigma = |s: f32| if s.is_finite() && s > 0.0 { s } else { 0.0 };
        let [first, second] = blurs.map(sigma);
        let blur_sigma = (first * first + second * second).sqrt();
        if (rendered.width(), rendered.height()) != (mask.width(), mask.height()) {
            return Err(ImageError::SizeMismatch {
                a: (rendered.width(), rendered.height()),
                b: (mask.width(), mask.height()),
            });
        }
        // The blur mixes background into pixels near the silhouette: shrink the mask by the
        // blur's reach (2σ) so that those pixels count as background too.
        let reach = if blur_sigma.is_finite() && blur_sigma > 0.0 {
            (2.0 * blur_sigma).ceil() as usize
        } else {
            0
        };
        // Image and mask are independent: built side by side (rayon). The rendering is
        // blurred in place (`antialias` without its copy). Both are zero where the model is
        // not (16 % of the pipeline bench's image is model), so every pass runs only over the
        // model's rectangle and the kernels' reach around it ([`support`]).
        let (image, mask) = rayon::join(
            || {
                let mut rendered = rendered;
                let support = image_support(&rendered);
                let support = blur_within(&mut rendered, first, support);
                let kept = keep.then(|| rendered.clone());
                let support = blur_within(&mut rendered, second, support);
                let mut pyramid = Pyramid::build_within(rendered, levels, support);
                pyramid.unsmoothed = kept.zip(gaussian_kernel(second));
                pyramid
            },
            || {
                let support = mask_support(&mask);
                MaskPyramid::build_within(erode_within(&mask, reach, support), levels, support)
            },
        );
        Ok(Self { image, mask })
    }
}

/// [`reference`]'s line erosion on bytes (0 or 1): `out[x]` = all of `line[x − r ..= x + r]`
/// (clipped to the line), as shifted ANDs over whole slices. Bytes rather than `bool`s because
/// the byte AND is what vectorises (the mask's `bool`s are read as their bytes).
#[inline]
fn erode_line(line: &[u8], r: usize, out: &mut [u8]) {
    let w = line.len();
    out.copy_from_slice(line);
    for k in 1..=r.min(w.saturating_sub(1)) {
        for (o, &v) in out[k..].iter_mut().zip(&line[..w - k]) {
            *o &= v;
        }
        for (o, &v) in out[..w - k].iter_mut().zip(&line[k..]) {
            *o &= v;
        }
    }
}

/// The rows `lo ..= hi` of a ring of `n` eroded lines (slot of line `j`: `j mod n`) ANDed into
/// `out`, whole rows at a time.
fn and_rows(ring: &[u8], w: usize, n: usize, lo: usize, hi: usize, out: &mut [u8]) {
    let row = |j: usize| &ring[(j % n) * w..(j % n + 1) * w];
    out.copy_from_slice(row(lo));
    for j in lo + 1..=hi {
        for (o, &v) in out.iter_mut().zip(row(j)) {
            *o &= v;
        }
    }
}

/// Rows `lo ..= hi` of `mask` eroded (radius `r`) into their ring slots, from `*next` on.
fn fill_ring(
    src: &[u8],
    w: usize,
    r: usize,
    n: usize,
    hi: usize,
    next: &mut usize,
    ring: &mut [u8],
) {
    while *next <= hi {
        let slot = *next % n;
        erode_line(
            &src[*next * w..(*next + 1) * w],
            r,
            &mut ring[slot * w..(slot + 1) * w],
        );
        *next += 1;
    }
}

/// One level of [`MaskPyramid`]: a coarse pixel is the AND over its 5×5 support. Reflect-101
/// only repeats pixels of that (symmetric) support, so this is the radius-2 erosion with the
/// window clipped at the borders, taken at the even pixels: the rows eroded into a ring of five
/// lines, the columns ANDed at the even rows over the whole width, then every second value
/// kept (as [`reference::mask_pyr_down`]).
fn mask_pyr_down(last: &Mask) -> Option<Mask> {
    let (w, h) = (last.width(), last.height());
    let (w2, h2) = (w.div_ceil(2), h.div_ceil(2));
    let src: &[u8] = bytemuck::cast_slice(last.data());
    let mut ring = vec![0u8; 5 * w];
    let mut column = vec![0u8; w];
    let mut data = Vec::with_capacity(w2 * h2);
    let mut next = 0;
    for y in (0..h2).map(|y2| 2 * y2) {
        let (lo, hi) = (y.saturating_sub(2), (y + 2).min(h - 1));
        fill_ring(src, w, 2, 5, hi, &mut next, &mut ring);
        and_rows(&ring, w, 5, lo, hi, &mut column);
        data.extend(column.iter().step_by(2).map(|&v| v != 0));
    }
    Mask::new(w2, h2, data).ok()
}

/// Square erosion of radius `r` (separable: rows, then columns); outside the image is valid,
/// so only background shrinks the mask. The rows are eroded into a ring of `2r + 1` lines just
/// before the first output row that needs them, as [`reference::erode`] without its full-size
/// intermediate.
pub fn erode(mask: &Mask, r: usize) -> Mask {
    if r == 0 {
        return mask.clone();
    }
    let (w, h) = (mask.width(), mask.height());
    let src: &[u8] = bytemuck::cast_slice(mask.data());
    let n = 2 * r + 1;
    let mut ring = vec![0u8; n * w];
    let mut column = vec![0u8; w];
    let mut out = Vec::with_capacity(w * h);
    let mut next = 0;
    for y in 0..h {
        let (lo, hi) = (y.saturating_sub(r), (y + r).min(h - 1));
        fill_ring(src, w, r, n, hi, &mut next, &mut ring);
        and_rows(&ring, w, n, lo, hi, &mut column);
        out.extend(column.iter().map(|&v| v != 0));
    }
    Mask::new(w, h, out).unwrap_or_else(|_| mask.clone())
}

#[cfg(test)]
mod tests;
